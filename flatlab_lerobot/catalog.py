"""Typed, validated specs of the benchmark's world, loaded from ``envs/`` YAML.

* ``envs/objects/*.yaml`` -> :class:`ObjectSpec` (the 104 objects of the paper's 21 categories,
  plus the three reference objects of ``reference.yaml``),
* ``envs/materials/*.yaml`` -> :class:`MaterialSpec` (table-top materials),
* ``envs/scenes/*.yaml`` -> :class:`SceneSpec` (18 scenes in 6 room categories).

Every loading error is ONE :class:`CatalogError` whose message names the file, the entry and the
field, e.g. ``envs/objects/reference.yaml: object 'ref_book': field 'mass': must be > 0``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import yaml

from flatlab_lerobot.constants import PROP_NAMES
from flatlab_lerobot.paths import ENVS_DIR

STRATEGY_LABELS = ("A", "B", "C")  # the catalog's strategy labels; strategies.STRATEGIES maps each to its stages
MATERIALS = ("rigid", "deformable")
SPLITS = ("train", "test_alpha", "test_beta", "reference")
BENCHMARK_SPLITS = ("train", "test_alpha", "test_beta")


class CatalogError(ValueError):
    """A malformed catalog file; the message names file, entry and field."""


# --------------------------------------------------------------------------------------------
# The categories (DESIGN.md): material, expected strategies, and objects per split.


@dataclass(frozen=True)
class CategoryInfo:
    """What the paper says about one category: its material, the strategies its objects may
    carry, and how many objects it has in each benchmark split."""

    material: str
    strategies: tuple[str, ...]
    counts: dict[str, int] = field(hash=False)


def _cat(material, strategies, train=0, test_alpha=0, test_beta=0) -> CategoryInfo:
    return CategoryInfo(material, tuple(strategies), {"train": train, "test_alpha": test_alpha, "test_beta": test_beta})


CATEGORIES: dict[str, CategoryInfo] = {
    "Book": _cat("rigid", "AB", 4, 4),
    "Disk": _cat("rigid", "A", 3, 3),
    "Plate": _cat("rigid", "A", 3, 3),
    "Box": _cat("rigid", "B", 4, 4),
    "Board": _cat("rigid", "B", 3, 3),
    "Keyboard": _cat("rigid", "B", 3, 3),
    "Photo Album": _cat("rigid", "AB", 2, 2),
    "Clock": _cat("rigid", "B", 2, 2),
    "Fabric": _cat("deformable", "C", 2, 2),
    "Mouse Pad": _cat("deformable", "C", 2, 2),
    "Shorts": _cat("deformable", "C", 2, 2),
    "Magazine": _cat("rigid", "A", test_beta=6),
    "Pad": _cat("rigid", "A", test_beta=6),
    "Disk Case": _cat("rigid", "A", test_beta=4),
    "Cutting Board": _cat("rigid", "B", test_beta=6),
    "Chessboard": _cat("rigid", "B", test_beta=4),
    "Painting": _cat("rigid", "B", test_beta=4),
    "Laptop": _cat("rigid", "B", test_beta=2),
    "Scarf": _cat("deformable", "C", test_beta=4),
    "Skirt": _cat("deformable", "C", test_beta=4),
    "Towel": _cat("deformable", "C", test_beta=4),
}
"""The paper's 21 categories (30 train, 30 test-alpha, 44 test-beta objects)."""

# --------------------------------------------------------------------------------------------
# Geometry families and their parameters.  A parameter is (kind, default, lo, hi) with kind
# "num" (float, lo <= v <= hi), "int" (lo <= v <= hi), "rgba" (4 numbers in [0, 1]) or
# "choice" (default, choices).  Lengths are metres.

def _num(default, lo, hi):
    return ("num", default, lo, hi)


def _int(default, lo, hi):
    return ("int", default, lo, hi)


def _rgba(default):
    return ("rgba", tuple(default), 0.0, 1.0)


FAMILIES: dict[str, dict[str, tuple]] = {
    "slab": {},
    "book": {"cover": _num(0.002, 0.0, 0.01), "page_inset": _num(0.004, 0.0, 0.02),
             "page_rgba": _rgba((0.95, 0.93, 0.86, 1)), "label_rgba": _rgba((0.9, 0.8, 0.3, 1))},
    "magazine": {"page_rgba": _rgba((0.96, 0.96, 0.94, 1)), "title_rgba": _rgba((0.95, 0.95, 0.95, 1)),
                 "photo_rgba": _rgba((0.3, 0.5, 0.7, 1))},
    "photo_album": {"cover": _num(0.004, 0.0, 0.015), "page_inset": _num(0.004, 0.0, 0.02), "page_rgba": _rgba((0.2, 0.2, 0.2, 1)),
                    "photo_rgba": _rgba((0.85, 0.75, 0.55, 1))},
    "pad": {"page_rgba": _rgba((0.98, 0.95, 0.6, 1)), "binding_rgba": _rgba((0.5, 0.15, 0.15, 1)),
            "binding": _num(0.025, 0.0, 0.1), "lines": _int(10, 0, 40), "line_rgba": _rgba((0.5, 0.6, 0.9, 1))},
    "box": {"tape_rgba": _rgba((0.85, 0.75, 0.55, 1)), "tape_width": _num(0.05, 0.0, 0.2),
            "lid": _num(0.02, 0.0, 0.08)},
    "board": {"planks": _int(1, 1, 8), "seam_rgba": _rgba((0.3, 0.2, 0.12, 1)), "border": _num(0.0, -1e-9, 0.05),
              "border_rgba": _rgba((0.6, 0.6, 0.62, 1))},
    "plate": {"rim": _num(0.03, 0.0, 0.1), "well_rgba": _rgba((0.97, 0.97, 0.95, 1)), "base": _num(0.006, 0.0, 0.03)},
    "disk": {"hole": _num(0.0075, -1e-9, 0.05), "label": _num(0.0, -1e-9, 0.1), "label_rgba": _rgba((0.8, 0.2, 0.2, 1))},
    "disk_case": {"spine": _num(0.015, 0.0, 0.05), "title_rgba": _rgba((0.95, 0.95, 0.95, 1)),
                  "spine_rgba": _rgba((0.1, 0.1, 0.1, 1)), "cover_rgba": _rgba((0.3, 0.5, 0.8, 1))},
    "keyboard": {"rows": _int(6, 1, 8), "cols": _int(15, 4, 24), "key_rgba": _rgba((0.15, 0.15, 0.17, 1)),
                 "key_height": _num(0.008, 0.0, 0.03), "margin": _num(0.01, 0.0, 0.05)},
    "clock": {"outline": ("choice", "round", ("round", "square")), "face_rgba": _rgba((0.97, 0.97, 0.95, 1)),
              "hand_rgba": _rgba((0.05, 0.05, 0.05, 1)), "bezel": _num(0.015, 0.0, 0.06)},
    "laptop": {"hinge_rgba": _rgba((0.2, 0.2, 0.22, 1)), "logo_rgba": _rgba((0.9, 0.9, 0.92, 1)),
               "base_fraction": _num(0.5, 0.2, 0.8)},
    "painting": {"frame": _num(0.03, 0.0, 0.1), "canvas_rgba": _rgba((0.55, 0.75, 0.9, 1)),
                 "art_rgba": _rgba((0.3, 0.55, 0.25, 1)), "sun_rgba": _rgba((0.95, 0.8, 0.2, 1))},
    "chessboard": {"squares": _int(8, 2, 12), "light_rgba": _rgba((0.93, 0.85, 0.68, 1)),
                   "dark_rgba": _rgba((0.45, 0.28, 0.15, 1)), "border": _num(0.02, 0.0, 0.05)},
    "cutting_board": {"handle": _num(0.08, 0.0, 0.15), "handle_width": _num(0.08, 0.02, 0.3),
                      "hole": _num(0.025, 0.0, 0.06)},
    "sheet": {},
    "shorts": {"leg_gap": _num(0.04, 0.0, 0.15), "rise": _num(0.35, 0.05, 0.9)},
    "skirt": {"waist_ratio": _num(0.65, 0.2, 1.0)},
}
"""Geometry family -> its parameters (kind, default, lo, hi); see :mod:`flatlab_lerobot.assets`."""

DEFORMABLE_FAMILIES = ("sheet", "shorts", "skirt")
SHAPES = tuple(FAMILIES)
ROUND_FAMILIES = ("plate", "disk")  # plus clocks with outline "round": size x = y = diameter


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


_FLEX_RANGES = {  # field -> (lo (exclusive), hi)
    "young": (1e3, 1e9), "poisson": (0.0, 0.49), "thickness": (1e-4, 0.01), "damping": (0.0, 1.0),
    "radius": (5e-4, 0.01), "solref_timeconst": (1e-4, 0.05),
}
MAX_FLEX_COUNT = 15


@dataclass(frozen=True)
class ObjectSpec:
    """One flat object of the catalog.

    id: unique name.  name: human-readable label.  category: one of :data:`CATEGORIES`.
    split: train | test_alpha | test_beta | reference.  material: rigid | deformable.
    shape: the geometry family (:data:`FAMILIES`); ``params``: its family-specific parameters
    (defaults filled in).  size: bounding extent along the object's x, y, z in metres
    (z = thickness; round objects have x = y = diameter).  mass in kg.  com_offset: centre of
    mass relative to the bounding-box centre (m).  friction: sliding friction coefficient.
    rgba: main colour.  strategy: the label (A|B|C): the strategy that works on the object in this
    simulator.  paper_strategy: the label the paper's design gives the category (its thin / thick /
    deformable rule); it differs from ``strategy`` only where ``flatlab assets report`` measured
    another strategy working clearly better (the YAML notes the measurement).  flex: cloth
    settings (deformables only).  source: the file it came from.
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
    name: str = ""
    params: dict[str, Any] = field(default_factory=dict, hash=False)
    paper_strategy: str = ""

    def __post_init__(self):
        if not self.paper_strategy:
            object.__setattr__(self, "paper_strategy", self.strategy)

    @property
    def relabelled(self) -> bool:
        """Whether the physically grounded label differs from the paper's."""
        return self.strategy != self.paper_strategy

    @property
    def deformable(self) -> bool:
        return self.material == "deformable"

    @property
    def family(self) -> str:
        """The geometry family (an alias of ``shape``)."""
        return self.shape

    def param(self, key: str) -> Any:
        """A family parameter, falling back to the family default."""
        if key in self.params:
            return self.params[key]
        return FAMILIES[self.shape][key][1]


# --------------------------------------------------------------------------------------------
# Validation helpers: each raises one CatalogError naming file, entry and field.


def _err(source: str, entry: str, fld: str, msg: str, kind: str = "object") -> CatalogError:
    return CatalogError(f"{source}: {kind} '{entry}': field '{fld}': {msg}")


class _V:
    """Validators bound to one (file, entry) so every message names both."""

    def __init__(self, source: str, entry: str, kind: str = "object"):
        self.source, self.entry, self.kind = source, entry, kind

    def err(self, fld, msg) -> CatalogError:
        return _err(self.source, self.entry, fld, msg, self.kind)

    def number(self, name, value, lo=None, hi=None, integer=False, lo_inclusive=False):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.err(name, f"must be a number, got {value!r}")
        if not math.isfinite(value):
            raise self.err(name, f"must be finite, got {value!r}")
        if integer and int(value) != value:
            raise self.err(name, f"must be an integer, got {value!r}")
        if lo is not None and (value < lo if lo_inclusive else value <= lo):
            raise self.err(name, f"must be {'>=' if lo_inclusive else '>'} {lo}, got {value!r}")
        if hi is not None and value > hi:
            raise self.err(name, f"must be <= {hi}, got {value!r}")
        return int(value) if integer else float(value)

    def vector(self, name, value, n, lo=None, hi=None, integer=False, lo_inclusive=False):
        if not isinstance(value, (list, tuple)) or len(value) != n:
            raise self.err(name, f"must be a list of {n} numbers, got {value!r}")
        return tuple(self.number(f"{name}[{i}]", v, lo, hi, integer, lo_inclusive) for i, v in enumerate(value))

    def choice(self, name, value, choices):
        if value not in choices:
            raise self.err(name, f"must be one of {list(choices)}, got {value!r}")
        return value

    def string(self, name, value):
        if not isinstance(value, str) or not value:
            raise self.err(name, f"must be a non-empty string, got {value!r}")
        return value

    def rgba(self, name, value):
        return self.vector(name, value, 4, 0.0, 1.0, lo_inclusive=True)

    def mapping(self, name, value):
        if not isinstance(value, dict):
            raise self.err(name, f"must be a mapping, got {value!r}")
        return value

    def known_keys(self, raw: dict, known, prefix=""):
        for key in raw:
            if key not in known:
                raise self.err(f"{prefix}{key}", f"unknown field (known: {sorted(known)})")

    def required(self, raw: dict, keys, prefix=""):
        for key in keys:
            if key not in raw:
                raise self.err(f"{prefix}{key}", "missing")


# Physical ranges of the benchmark objects (the table top is 0.6 x 0.9 m; a Panda hand opens 8 cm).
RIGID_SIZE = ((0.04, 0.42), (0.04, 0.42), (0.004, 0.08))  # (lo, hi) per axis, inclusive
SHEET_SIZE = ((0.1, 0.5), (0.08, 0.5), (0.0005, 0.01))
MASS_RANGE = (0.005, 5.0)
FRICTION_RANGE = (0.05, 2.0)

_OBJECT_FIELDS = {f.name for f in fields(ObjectSpec)} - {"source"}


def _parse_params(v: _V, shape: str, raw) -> dict[str, Any]:
    schema = FAMILIES[shape]
    raw = v.mapping("params", raw if raw is not None else {})
    out: dict[str, Any] = {}
    for key, value in raw.items():
        if key not in schema:
            raise v.err(f"params.{key}", f"unknown parameter of family '{shape}' (known: {sorted(schema)})")
        kind = schema[key][0]
        lo, hi = (None, None) if kind == "choice" else schema[key][2:4]
        name = f"params.{key}"
        if kind == "num":
            out[key] = v.number(name, value, lo, hi, lo_inclusive=True)
        elif kind == "int":
            out[key] = v.number(name, value, lo, hi, integer=True, lo_inclusive=True)
        elif kind == "rgba":
            out[key] = v.rgba(name, value)
        elif kind == "choice":
            out[key] = v.choice(name, value, schema[key][2])
    return out


def _parse_flex(v: _V, raw) -> FlexSpec:
    raw = v.mapping("flex", raw if raw is not None else {})
    known = {f.name for f in fields(FlexSpec)}
    v.known_keys(raw, known, "flex.")
    kw: dict[str, Any] = {}
    for k, value in raw.items():
        if k == "count":
            kw[k] = v.vector("flex.count", value, 2, 3, MAX_FLEX_COUNT, integer=True, lo_inclusive=True)
        else:
            lo, hi = _FLEX_RANGES[k]
            kw[k] = v.number(f"flex.{k}", value, lo, hi)
    return FlexSpec(**kw)


def parse_object(raw: dict[str, Any], source: str) -> ObjectSpec:
    """Validate one raw YAML mapping into an :class:`ObjectSpec`."""
    if not isinstance(raw, dict):
        raise CatalogError(f"{source}: each object must be a mapping, got {raw!r}")
    oid = raw.get("id")
    if not isinstance(oid, str) or not oid:
        raise CatalogError(f"{source}: object {raw!r}: field 'id': missing or not a string")
    v = _V(source, oid)
    v.known_keys(raw, _OBJECT_FIELDS)
    v.required(raw, ("category", "split", "material", "shape", "size", "mass", "strategy"))
    category = v.choice("category", raw["category"], CATEGORIES)
    info = CATEGORIES[category]
    split = v.choice("split", raw["split"], SPLITS)
    if split != "reference" and info.counts.get(split, 0) == 0:
        raise v.err("split", f"category '{category}' has no objects in split '{split}' "
                             f"(it has: {[s for s, n in info.counts.items() if n]})")
    material = v.choice("material", raw["material"], MATERIALS)
    if material != info.material:
        raise v.err("material", f"category '{category}' is {info.material}, got {material!r}")
    shape = v.choice("shape", raw["shape"], SHAPES)
    deformable = material == "deformable"
    if deformable != (shape in DEFORMABLE_FAMILIES):
        allowed = DEFORMABLE_FAMILIES if deformable else tuple(s for s in SHAPES if s not in DEFORMABLE_FAMILIES)
        raise v.err("shape", f"a {material} object needs one of {list(allowed)}, got {shape!r}")
    strategy = v.choice("strategy", raw["strategy"], STRATEGY_LABELS)
    paper = v.choice("paper_strategy", raw["paper_strategy"], STRATEGY_LABELS) if "paper_strategy" in raw else strategy
    field_ = "paper_strategy" if "paper_strategy" in raw else "strategy"
    if paper not in info.strategies:
        raise v.err(field_, f"category '{category}' expects strategy {'/'.join(info.strategies)}, got {paper!r}")
    if "paper_strategy" in raw and paper == strategy:
        raise v.err("paper_strategy", f"equals strategy {strategy!r}: give paper_strategy only for a grounded relabel")
    ranges = SHEET_SIZE if deformable else RIGID_SIZE
    size = v.vector("size", raw["size"], 3)
    for i, (lo, hi) in enumerate(ranges):
        if not lo <= size[i] <= hi:
            raise v.err(f"size[{i}]", f"must be in [{lo}, {hi}] m for a {material} object, got {size[i]!r}")
    params = _parse_params(v, shape, raw.get("params"))
    round_ = shape in ROUND_FAMILIES or (shape == "clock" and params.get("outline", "round") == "round")
    if round_ and abs(size[0] - size[1]) > 1e-9:
        raise v.err("size", f"a round '{shape}' needs size x == y (the diameter), got {list(size)}")
    flex = None
    if deformable:
        flex = _parse_flex(v, raw.get("flex"))
    elif "flex" in raw:
        raise v.err("flex", "only deformable objects take flex settings")
    com = v.vector("com_offset", raw.get("com_offset", [0, 0, 0]), 3)
    for i in range(3):
        if abs(com[i]) > size[i] / 2:
            raise v.err(f"com_offset[{i}]", f"must lie inside the object (|c| <= {size[i] / 2:.4g}), got {com[i]!r}")
    name = raw.get("name", oid)
    return ObjectSpec(
        id=oid,
        category=category,
        split=split,
        material=material,
        shape=shape,
        size=size,
        mass=v.number("mass", raw["mass"], *MASS_RANGE, lo_inclusive=True),
        strategy=strategy,
        paper_strategy=paper,
        friction=v.number("friction", raw.get("friction", 0.4), *FRICTION_RANGE, lo_inclusive=True),
        com_offset=com,
        rgba=v.rgba("rgba", raw.get("rgba", [0.6, 0.3, 0.2, 1.0])),
        flex=flex,
        source=source,
        name=v.string("name", name),
        params=params,
    )


def _load_docs(directory: Path, key: str):
    """Yield (source, list of raw entries) of every ``*.yaml`` in ``directory``."""
    if not directory.is_dir():
        raise CatalogError(f"{directory}: catalog folder not found")
    for path in sorted(directory.glob("*.yaml")):
        source = str(path)
        try:
            doc = yaml.safe_load(path.read_text())
        except yaml.YAMLError as exc:
            raise CatalogError(f"{source}: not valid YAML: {exc}") from exc
        if not isinstance(doc, dict) or not isinstance(doc.get(key), list):
            raise CatalogError(f"{source}: field '{key}': the file must hold a list under '{key}:'")
        yield source, doc[key]


def load_objects(directory: Path | None = None) -> dict[str, ObjectSpec]:
    """All objects of every ``*.yaml`` under ``envs/objects`` (or ``directory``), by id."""
    directory = Path(directory) if directory else ENVS_DIR / "objects"
    out: dict[str, ObjectSpec] = {}
    for source, entries in _load_docs(directory, "objects"):
        for raw in entries:
            spec = parse_object(raw, source)
            if spec.id in out:
                raise _err(source, spec.id, "id", f"duplicate id (also in {out[spec.id].source})")
            out[spec.id] = spec
    return out


def benchmark_objects(split: str | None = None, directory: Path | None = None) -> list[ObjectSpec]:
    """The benchmark's objects (reference objects excluded), optionally of one split."""
    if split is not None and split not in BENCHMARK_SPLITS:
        raise ValueError(f"unknown split {split!r}; known: {list(BENCHMARK_SPLITS)}")
    objs = [o for o in load_objects(directory).values() if o.split != "reference"]
    return [o for o in objs if split is None or o.split == split]


def check_counts(objects: dict[str, ObjectSpec]) -> list[str]:
    """Differences between the loaded catalog and the paper's per-category/split counts."""
    problems = []
    for cat, info in CATEGORIES.items():
        for split, want in info.counts.items():
            got = sum(1 for o in objects.values() if o.category == cat and o.split == split)
            if got != want:
                problems.append(f"category '{cat}' split '{split}': {got} objects, expected {want}")
    return problems


def get_object(object_id: str) -> ObjectSpec:
    objects = load_objects()
    if object_id not in objects:
        raise KeyError(f"unknown object id {object_id!r}; known: {sorted(objects)}")
    return objects[object_id]


REFERENCE_OBJECTS = {"A": "ref_book", "B": "ref_box", "C": "ref_towel"}
"""The reference object of each strategy (``envs/objects/reference.yaml``)."""


# --------------------------------------------------------------------------------------------
# Table materials and scenes.

ROOMS = ("Bedroom", "Kitchen", "Laundryroom", "Livingroom", "Study", "Warehouse")
EDGES = ("square", "rounded", "bevelled")
PATTERNS = ("flat", "checker", "grain")


@dataclass(frozen=True)
class MaterialSpec:
    """A table-top material.  friction: sliding friction of the top.  rgba: base colour;
    rgba2 / pattern: the second colour of a ``checker`` or ``grain`` pattern (``flat``: unused)."""

    id: str
    name: str
    friction: float
    rgba: tuple[float, float, float, float]
    rgba2: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0)
    pattern: str = "flat"
    source: str = ""


@dataclass(frozen=True)
class SceneSpec:
    """A room with one table.  room: one of :data:`ROOMS`.  table_size: (depth x, width y) of the
    top (m); table_height: top above the floor (m); table_thickness (m); edge: the front edge
    profile (square | rounded | bevelled); material: a :class:`MaterialSpec` id.
    wall_rgba / floor_rgba: room colours; props: names of decorative props (visual only)."""

    id: str
    room: str
    name: str
    table_size: tuple[float, float]
    table_height: float
    table_thickness: float
    edge: str
    material: str
    wall_rgba: tuple[float, float, float, float] = (0.85, 0.84, 0.8, 1.0)
    floor_rgba: tuple[float, float, float, float] = (0.5, 0.5, 0.53, 1.0)
    props: tuple[str, ...] = ()
    source: str = ""


TABLE_SIZE = ((0.5, 0.8), (0.7, 1.0))  # depth x, width y (the arm pedestals stand at y = +-0.65 m)
TABLE_HEIGHT = (0.65, 0.9)


def _entry_id(raw, source, kind) -> str:
    if not isinstance(raw, dict):
        raise CatalogError(f"{source}: each {kind} must be a mapping, got {raw!r}")
    eid = raw.get("id")
    if not isinstance(eid, str) or not eid:
        raise CatalogError(f"{source}: {kind} {raw!r}: field 'id': missing or not a string")
    return eid


def parse_material(raw: dict[str, Any], source: str) -> MaterialSpec:
    mid = _entry_id(raw, source, "material")
    v = _V(source, mid, "material")
    v.known_keys(raw, {f.name for f in fields(MaterialSpec)} - {"source"})
    v.required(raw, ("name", "friction", "rgba"))
    return MaterialSpec(
        id=mid, name=v.string("name", raw["name"]), friction=v.number("friction", raw["friction"], *FRICTION_RANGE),
        rgba=v.rgba("rgba", raw["rgba"]), rgba2=v.rgba("rgba2", raw.get("rgba2", [0, 0, 0, 1])),
        pattern=v.choice("pattern", raw.get("pattern", "flat"), PATTERNS), source=source,
    )


def parse_scene(raw: dict[str, Any], source: str, materials: dict[str, MaterialSpec] | None = None) -> SceneSpec:
    sid = _entry_id(raw, source, "scene")
    v = _V(source, sid, "scene")
    v.known_keys(raw, {f.name for f in fields(SceneSpec)} - {"source"})
    v.required(raw, ("room", "name", "table_size", "table_height", "table_thickness", "edge", "material"))
    size = v.vector("table_size", raw["table_size"], 2)
    for i, (lo, hi) in enumerate(TABLE_SIZE):
        if not lo <= size[i] <= hi:
            raise v.err(f"table_size[{i}]", f"must be in [{lo}, {hi}] m, got {size[i]!r}")
    height = v.number("table_height", raw["table_height"], TABLE_HEIGHT[0], TABLE_HEIGHT[1], lo_inclusive=True)
    material = v.string("material", raw["material"])
    if materials is not None and material not in materials:
        raise v.err("material", f"unknown table material {material!r} (known: {sorted(materials)})")
    props = raw.get("props", [])
    if not isinstance(props, list) or not all(isinstance(p, str) for p in props):
        raise v.err("props", f"must be a list of strings, got {props!r}")
    for i, p in enumerate(props):
        if p not in PROP_NAMES:
            raise v.err(f"props[{i}]", f"unknown prop {p!r} (known: {sorted(PROP_NAMES)})")
    return SceneSpec(
        id=sid, room=v.choice("room", raw["room"], ROOMS), name=v.string("name", raw["name"]),
        table_size=size, table_height=height,
        table_thickness=v.number("table_thickness", raw["table_thickness"], 0.01, 0.1),
        edge=v.choice("edge", raw["edge"], EDGES), material=material,
        wall_rgba=v.rgba("wall_rgba", raw.get("wall_rgba", [0.85, 0.84, 0.8, 1])),
        floor_rgba=v.rgba("floor_rgba", raw.get("floor_rgba", [0.5, 0.5, 0.53, 1])),
        props=tuple(props), source=source,
    )


def _load_entries(directory, key, parse, kind, **kw):
    out = {}
    for source, entries in _load_docs(Path(directory), key):
        for raw in entries:
            spec = parse(raw, source, **kw)
            if spec.id in out:
                raise _err(source, spec.id, "id", f"duplicate id (also in {out[spec.id].source})", kind)
            out[spec.id] = spec
    return out


def load_materials(directory: Path | None = None) -> dict[str, MaterialSpec]:
    """All table materials under ``envs/materials`` (or ``directory``), by id."""
    return _load_entries(directory or ENVS_DIR / "materials", "materials", parse_material, "material")


def load_scenes(directory: Path | None = None, materials_dir: Path | None = None) -> dict[str, SceneSpec]:
    """All scenes under ``envs/scenes`` (or ``directory``), by id; materials are cross-checked."""
    materials = load_materials(materials_dir)
    return _load_entries(directory or ENVS_DIR / "scenes", "scenes", parse_scene, "scene", materials=materials)


def get_scene(scene_id: str, scenes_dir: Path | None = None, materials_dir: Path | None = None) -> tuple[SceneSpec, MaterialSpec]:
    """Scene ``scene_id`` of ``envs/scenes`` (or ``scenes_dir``) and its table material.  The
    simulation's cell is built from them by :meth:`flatlab_lerobot.sim.scene.CellConfig.from_scene`."""
    scenes = load_scenes(scenes_dir, materials_dir)
    if scene_id not in scenes:
        raise KeyError(f"unknown scene id {scene_id!r}; known: {sorted(scenes)}")
    s = scenes[scene_id]
    return s, load_materials(materials_dir)[s.material]
