"""Typed, validated specs of the benchmark's world, loaded from ``envs/`` YAML.

Every loading error is a :class:`CatalogError` whose message names the file, the object and
the field, e.g. ``envs/objects/reference.yaml: object 'ref_book': field 'mass': must be > 0``.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import yaml

from flatlab_lerobot.paths import ENVS_DIR

STRATEGIES = ("A", "B", "C")
MATERIALS = ("rigid", "deformable")
SHAPES = ("slab", "sheet")


class CatalogError(ValueError):
    """A malformed catalog file; the message names file, entry and field."""


@dataclass(frozen=True)
class FlexSpec:
    """MuJoCo flex (cloth) settings of a deformable sheet.

    count: grid vertices along x and y (resolution).  young / poisson: membrane elasticity (Pa, -).
    thickness: shell thickness (m), sets the bending stiffness.  damping: elastic damping (s).
    radius: collision radius of the sheet (m).  solref_timeconst: contact stiffness time constant (s).
    """

    count: tuple[int, int] = (15, 15)
    young: float = 1e6
    poisson: float = 0.2
    thickness: float = 0.002
    damping: float = 0.01
    radius: float = 0.003
    solref_timeconst: float = 0.002


@dataclass(frozen=True)
class ObjectSpec:
    """One flat object of the catalog.

    size: extent along the object's x, y, z in metres (z = thickness).  mass in kg.
    com_offset: centre of mass relative to the geometric centre (m).  friction: sliding
    friction coefficient against other surfaces.  rgba: colour.  strategy: the label (A|B|C).
    """

    id: str
    category: str
    split: str
    material: str
    shape: str
    size: tuple[float, float, float]
    mass: float
    strategy: str
    friction: float = 0.4
    com_offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rgba: tuple[float, float, float, float] = (0.6, 0.3, 0.2, 1.0)
    flex: FlexSpec | None = None
    source: str = ""

    @property
    def deformable(self) -> bool:
        return self.material == "deformable"


def _err(source: str, entry: str, fld: str, msg: str) -> CatalogError:
    return CatalogError(f"{source}: object '{entry}': field '{fld}': {msg}")


def _number(src, oid, name, value, lo=None, hi=None, integer=False):
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise _err(src, oid, name, f"must be a number, got {value!r}")
    if integer and int(value) != value:
        raise _err(src, oid, name, f"must be an integer, got {value!r}")
    if lo is not None and value <= lo:
        raise _err(src, oid, name, f"must be > {lo}, got {value!r}")
    if hi is not None and value > hi:
        raise _err(src, oid, name, f"must be <= {hi}, got {value!r}")
    return int(value) if integer else float(value)


def _vector(src, oid, name, value, n, lo=None, hi=None, signed=False):
    if not isinstance(value, (list, tuple)) or len(value) != n:
        raise _err(src, oid, name, f"must be a list of {n} numbers, got {value!r}")
    out = []
    for i, v in enumerate(value):
        out.append(_number(src, oid, f"{name}[{i}]", v, None if signed else lo, hi))
    return tuple(out)


def _choice(src, oid, name, value, choices):
    if value not in choices:
        raise _err(src, oid, name, f"must be one of {list(choices)}, got {value!r}")
    return value


def parse_object(raw: dict[str, Any], source: str) -> ObjectSpec:
    """Validate one raw YAML mapping into an :class:`ObjectSpec`."""
    if not isinstance(raw, dict):
        raise CatalogError(f"{source}: each object must be a mapping, got {raw!r}")
    oid = raw.get("id")
    if not isinstance(oid, str) or not oid:
        raise CatalogError(f"{source}: object {raw!r}: field 'id': missing or not a string")
    known = {f.name for f in fields(ObjectSpec)} - {"source"}
    for key in raw:
        if key not in known:
            raise _err(source, oid, key, f"unknown field (known: {sorted(known)})")
    for key in ("category", "split", "material", "shape", "size", "mass", "strategy"):
        if key not in raw:
            raise _err(source, oid, key, "missing")
    material = _choice(source, oid, "material", raw["material"], MATERIALS)
    shape = _choice(source, oid, "shape", raw["shape"], SHAPES)
    flex = None
    if material == "deformable":
        if shape != "sheet":
            raise _err(source, oid, "shape", "a deformable object must have shape 'sheet'")
        flex_raw = raw.get("flex") or {}
        if not isinstance(flex_raw, dict):
            raise _err(source, oid, "flex", "must be a mapping")
        kw = {}
        for k, v in flex_raw.items():
            if k == "count":
                kw[k] = tuple(int(c) for c in _vector(source, oid, "flex.count", v, 2, lo=2, hi=60))
            elif k in {f.name for f in fields(FlexSpec)}:
                kw[k] = _number(source, oid, f"flex.{k}", v, lo=0)
            else:
                raise _err(source, oid, f"flex.{k}", "unknown field")
        flex = FlexSpec(**kw)
    elif "flex" in raw:
        raise _err(source, oid, "flex", "only deformable objects take flex settings")
    for k in ("category", "split"):
        if not isinstance(raw[k], str) or not raw[k]:
            raise _err(source, oid, k, "must be a non-empty string")
    return ObjectSpec(
        id=oid,
        category=raw["category"],
        split=raw["split"],
        material=material,
        shape=shape,
        size=_vector(source, oid, "size", raw["size"], 3, lo=0.0, hi=1.0),
        mass=_number(source, oid, "mass", raw["mass"], lo=0.0, hi=20.0),
        strategy=_choice(source, oid, "strategy", raw["strategy"], STRATEGIES),
        friction=_number(source, oid, "friction", raw.get("friction", 0.4), lo=0.0, hi=3.0),
        com_offset=_vector(source, oid, "com_offset", raw.get("com_offset", [0, 0, 0]), 3, signed=True),
        rgba=_vector(source, oid, "rgba", raw.get("rgba", [0.6, 0.3, 0.2, 1.0]), 4, lo=-1e-9, hi=1.0),
        flex=flex,
        source=source,
    )


def load_objects(directory: Path | None = None) -> dict[str, ObjectSpec]:
    """All objects of every ``*.yaml`` under ``envs/objects`` (or ``directory``), by id."""
    directory = Path(directory) if directory else ENVS_DIR / "objects"
    out: dict[str, ObjectSpec] = {}
    for path in sorted(directory.glob("*.yaml")):
        source = str(path)
        try:
            doc = yaml.safe_load(path.read_text())
        except yaml.YAMLError as exc:
            raise CatalogError(f"{source}: not valid YAML: {exc}") from exc
        if not isinstance(doc, dict) or not isinstance(doc.get("objects"), list):
            raise CatalogError(f"{source}: field 'objects': the file must hold a list under 'objects:'")
        for raw in doc["objects"]:
            spec = parse_object(raw, source)
            if spec.id in out:
                raise _err(source, spec.id, "id", f"duplicate id (also in {out[spec.id].source})")
            out[spec.id] = spec
    return out


def get_object(object_id: str) -> ObjectSpec:
    objects = load_objects()
    if object_id not in objects:
        raise KeyError(f"unknown object id {object_id!r}; known: {sorted(objects)}")
    return objects[object_id]


REFERENCE_OBJECTS = {"A": "ref_book", "B": "ref_box", "C": "ref_towel"}
"""The reference object of each strategy (``envs/objects/reference.yaml``)."""

