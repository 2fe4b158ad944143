"""Names and numbers shared across layers (a leaf: imports nothing from the package).

The catalog, the asset builders and the simulation all need a few of the same names; they live
here so that no lower layer has to import a higher one for them (``assets`` used to import the
collision bits from ``sim.robot``, ``catalog`` the prop names from ``sim.room``).
"""

from __future__ import annotations

# Collision bit masks: an arm never collides with itself, does collide with the other arm, the
# table and the objects.  (contype_a & conaffinity_b) or (contype_b & conaffinity_a).
BIT_TABLE, BIT_OBJECT, BIT_LEFT, BIT_RIGHT = 1, 2, 4, 16

OBJECT_BODY = "object"
"""Name of the object's body in an object's MJCF (``assets.object_xml``) and in the cell."""

PROP_NAMES: tuple[str, ...] = (
    "bed", "lamp", "mirror", "wardrobe", "stool", "stools", "cabinets", "sink", "chair", "chairs",
    "fruit_bowl", "washer", "dryer", "basket", "shelf", "detergent", "sofa", "armchair", "rug", "tv",
    "plant", "bookshelf", "monitor", "pallet", "shelving", "boxes", "tape_dispenser", "conveyor",
)  # fmt: skip
"""Every prop name a scene may list (``envs/scenes/*.yaml`` field ``props``); ``sim.room.PROPS``
holds one builder for each (checked when ``sim.room`` is imported)."""
