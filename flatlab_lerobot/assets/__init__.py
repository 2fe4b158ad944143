"""Object geometry: one builder per geometry family, producing the MJCF of a catalog object.

Families: ``slab`` (a box: books, boxes, boards), ``sheet`` (a MuJoCo flex cloth grid).
"""

from __future__ import annotations

import numpy as np

from flatlab_lerobot.catalog import ObjectSpec
from flatlab_lerobot.sim.robot import BIT_LEFT, BIT_OBJECT, BIT_RIGHT, BIT_TABLE

OBJECT_BODY = "object"


def _fmt(v) -> str:
    return " ".join(f"{float(x):.6g}" for x in np.atleast_1d(v))


def object_xml(obj: ObjectSpec, table_height: float) -> str:
    """MJCF ``<body>`` for ``obj``, resting at the table centre (the env moves it at reset).

    Rigid objects are one free body named ``object``; deformable sheets are a flexcomp named
    ``cloth`` under a static body named ``object``.  Collision bits: see ``sim.robot``.
    """
    mask = f'contype="{BIT_OBJECT}" conaffinity="{BIT_TABLE | BIT_OBJECT | BIT_LEFT | BIT_RIGHT}"'
    sx, sy, sz = obj.size
    top = table_height
    if obj.shape == "slab":
        com = _fmt(obj.com_offset)
        return f"""
    <body name="{OBJECT_BODY}" pos="0 0 {top + sz / 2 + 0.0005:.6g}">
      <freejoint name="object_free"/>
      <inertial pos="{com}" mass="{obj.mass:.6g}" diaginertia="{_fmt(_box_inertia(obj.mass, obj.size))}"/>
      <geom name="object_geom" type="box" size="{_fmt(np.array(obj.size) / 2)}" rgba="{_fmt(obj.rgba)}"
            friction="{obj.friction:.6g} 0.005 0.0001" condim="4" {mask}/>
    </body>"""
    if obj.shape == "sheet":
        f = obj.flex
        nx, ny = f.count
        spacing = (sx / (nx - 1), sy / (ny - 1))
        return f"""
    <body name="{OBJECT_BODY}" pos="0 0 {top + f.radius + 0.001:.6g}">
      <flexcomp name="cloth" type="grid" dim="2" count="{nx} {ny} 1" spacing="{spacing[0]:.6g} {spacing[1]:.6g} 0.05"
                radius="{f.radius:.6g}" mass="{obj.mass:.6g}" rgba="{_fmt(obj.rgba)}">
        <contact condim="3" friction="{obj.friction:.6g} 0.005 0.0001" solref="{f.solref_timeconst:.6g} 1"
                 selfcollide="none" {mask}/>
        <edge equality="false"/>
        <elasticity young="{f.young:.6g}" poisson="{f.poisson:.6g}" thickness="{f.thickness:.6g}"
                    damping="{f.damping:.6g}" elastic2d="both"/>
      </flexcomp>
    </body>"""
    raise ValueError(f"object '{obj.id}': unknown shape {obj.shape!r}")


def _box_inertia(mass, size):
    x, y, z = size
    return mass / 12.0 * np.array([y * y + z * z, x * x + z * z, x * x + y * y])
