"""Simulated data transformations (paper §3.2.2) as catalog operations on :class:`ObjectSpec`.

* :func:`scaled` -- a uniform scale of every length of an object (outline, thickness, centre of
  mass, the family's length parameters).  Mass: a rigid object keeps its density, so its mass
  scales with ``s**3``; a deformable sheet keeps its fabric (thickness, flex radius and shell
  thickness are material properties and stay; the flex grid keeps its vertex count), so only its
  outline scales and its mass scales with ``s**2`` (constant areal density).
* :func:`scale_range` / :func:`seven_scales` -- the paper's scale set: 7 scales spaced uniformly
  between the smallest sensible scale and the largest that fits the table (limits below).
* :func:`rigid_counterpart` -- the material transformation: a cloth becomes a rigid plate of the
  same outline (sheet: rectangle; shorts: legs around the gap; skirt: trapezoid) and thickness
  (``assets.RIGID_COUNTERPART_BUILDERS``), same mass, ``material: rigid``.
* :func:`label` -- the strategy recomputed by one documented rule (:data:`LABEL_RULE`), whose
  thresholds are fitted to the catalog's own labels; :func:`label_disagreements` lists the catalog
  objects whose label the rule does not reproduce.

Scale limits (:func:`scale_range`), for the default cell (table 0.6 m deep x 0.9 m wide, arms at
y = +-0.65 m) and the task reset distribution (+-5 cm, +-30 deg):

* smallest: the catalog's own lower bounds (``catalog.RIGID_SIZE`` / ``SHEET_SIZE``): a rigid
  object keeps a footprint of at least 4 cm (two 2-cm Panda fingertips still fit on it) and at
  least 4 mm of thickness (the thinnest object whose cloud still shows a top *and* side faces, the
  paper's "smallest single-layer point cloud"); a sheet keeps at least 8 x 10 cm.
* largest: at its nominal pose (table centre, yaw 0) the footprint stays ``reset planar range +
  2 cm`` inside every table edge (x <= 0.46 m, y <= 0.76 m on the default table), and every
  footprint corner stays within :data:`PANDA_REACH` of the nearer arm's shoulder.  (With the
  default cell the table bound always binds first; yawed placements of the largest scales may
  overhang an edge by a few cm, as the catalog's 0.4 m boards already do.)
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable

import numpy as np

from flatlab_lerobot.catalog import (
    FAMILIES,
    RIGID_SIZE,
    SHEET_SIZE,
    STRATEGY_LABELS,
    ObjectSpec,
)
from flatlab_lerobot.sim.scene import CellConfig
from flatlab_lerobot.tasks import ResetDistribution

N_SCALES = 7
"""The paper's scale set: 7 rescaled instances per object (plus the original)."""

RATIO_PARAMS = frozenset({"base_fraction", "rise", "waist_ratio"})
"""Numeric family parameters that are fractions, not lengths: a uniform scale keeps them."""

# ------------------------------------------------------------------------------ limits
MIN_RIGID_SIDE = RIGID_SIZE[0][0]  # 0.04 m
MIN_RIGID_THICKNESS = RIGID_SIZE[2][0]  # 0.004 m
MIN_SHEET_SIDES = (SHEET_SIZE[1][0], SHEET_SIZE[0][0])  # (shorter, longer) >= (0.08, 0.10) m
TABLE_EDGE_MARGIN = 0.02  # m kept free at each table edge, beyond the reset's planar range
PANDA_REACH = 0.855  # m, Franka Panda maximum reach from the shoulder (datasheet)
PANDA_SHOULDER_HEIGHT = 0.333  # m, shoulder (joint 2) above the arm base (DH d1)

# ------------------------------------------------------------------------------ label rule
B_THICKNESS = 0.0325
"""m: at least this thick -> B, whatever the footprint.  Midway between the thickest A book / album
(3.0 cm: ``album_travel``) and the thinnest B book (3.5 cm: ``book_atlas``)."""
B_SQUEEZE_THICKNESS = 0.01
"""m: a large object needs at least this thickness for the two-arm squeeze: B's fingertips reach
down to 7 mm above the table (``strategies``), plus a 3 mm contact patch."""
B_LARGE_SIDE = 0.24
"""m: a squeezable object whose longer side is at least this long -> B.  Any value in
(0.23, 0.25] gives the same (fewest) disagreements with the catalog; 0.24 is the middle."""
LABEL_RULE = (
    f"deformable -> C; rigid: thickness >= {B_THICKNESS} m, or thickness >= {B_SQUEEZE_THICKNESS} m "
    f"with longer side >= {B_LARGE_SIDE} m -> B; else A"
)
LABEL_INDEX = {s: i for i, s in enumerate(STRATEGY_LABELS)}
"""Strategy letter -> integer class (A=0, B=1, C=2)."""


# ------------------------------------------------------------------------------ helpers
def _check_scale(spec: ObjectSpec, s) -> float:
    if isinstance(s, bool) or not isinstance(s, (int, float, np.integer, np.floating)):
        raise ValueError(f"object '{spec.id}': scale must be a number, got {s!r}")  # noqa: TRY004 (one error type for a bad scale)
    s = float(s)
    if not math.isfinite(s) or s <= 0:
        raise ValueError(f"object '{spec.id}': scale must be a finite number > 0, got {s!r}")
    return s


def scale_tag(s: float) -> str:
    """The id suffix of a scale: ``@s0.75``."""
    return f"@s{float(s):.4g}"


# ------------------------------------------------------------------------------ operations
def scaled(spec: ObjectSpec, s: float, cell: CellConfig | None = None) -> ObjectSpec:
    """``spec`` uniformly scaled by ``s`` (> 0), with id ``<id>@s<s>``; mass ~ s**3 (rigid) or
    s**2 (cloth: the fabric's thickness stays).  With ``cell``, ``s`` must lie in
    :func:`scale_range` ``(spec, cell)``.  Raises ValueError for a bad scale."""
    s = _check_scale(spec, s)
    if cell is not None:
        lo, hi = scale_range(spec, cell)
        if not lo - 1e-9 <= s <= hi + 1e-9:
            raise ValueError(f"object '{spec.id}': scale {s:g} outside its sensible range [{lo:.4g}, {hi:.4g}]")
    params = dict(spec.params)
    for key, (kind, *_rest) in FAMILIES[spec.shape].items():
        if kind == "num" and key not in RATIO_PARAMS:
            params[key] = float(spec.param(key)) * s
    if spec.deformable:  # the fabric stays: only the outline grows
        size = (spec.size[0] * s, spec.size[1] * s, spec.size[2])
        com = (spec.com_offset[0] * s, spec.com_offset[1] * s, spec.com_offset[2])
        mass = spec.mass * s**2
    else:
        size = tuple(v * s for v in spec.size)
        com = tuple(v * s for v in spec.com_offset)
        mass = spec.mass * s**3
    out = dataclasses.replace(
        spec, id=spec.id + scale_tag(s), name=f"{spec.name or spec.id} (x{s:.4g})",
        size=tuple(float(v) for v in size), com_offset=tuple(float(v) for v in com), mass=float(mass), params=params,
    )  # fmt: skip
    return dataclasses.replace(out, strategy=label(out), paper_strategy=label(out))


def _shorts_outline(spec: ObjectSpec) -> tuple[float, float]:
    """(leg_gap, rise) of the gap the cloth really has: ``assets.garment_mesh`` drops whole grid
    cells, so the gap is a whole number of cells wide and high."""
    nx, ny = spec.flex.count
    sx, sy = spec.size[0], spec.size[1]
    xs, ys = np.linspace(-sx / 2, sx / 2, nx), np.linspace(-sy / 2, sy / 2, ny)
    half = max(spec.param("leg_gap") / 2, (sx / (nx - 1)) / 2 + 1e-9)
    crotch = sy / 2 - spec.param("rise") * sy
    cols = np.abs((xs[:-1] + xs[1:]) / 2) < half
    rows = (ys[:-1] + ys[1:]) / 2 < crotch
    if not cols.any() or not rows.any():
        return 0.0, 0.0
    return float(2 * xs[1:][cols].max()), float((sy / 2 - ys[1:][rows].max()) / sy)


def rigid_counterpart(spec: ObjectSpec) -> ObjectSpec:
    """The material transformation of a cloth: a rigid plate of the same outline, thickness and
    mass (id ``<id>@rigid``, strategy recomputed: A).  Raises ValueError for a rigid object."""
    if not spec.deformable:
        raise ValueError(f"object '{spec.id}': already rigid (only a deformable object has a rigid counterpart)")
    params = dict(spec.params)
    if spec.shape == "shorts":
        params["leg_gap"], params["rise"] = _shorts_outline(spec)
    out = dataclasses.replace(
        spec,
        id=spec.id + "@rigid",
        name=f"{spec.name or spec.id} (rigid)",
        material="rigid",
        flex=None,
        params=params,
    )
    return dataclasses.replace(out, strategy=label(out), paper_strategy=label(out))


def label(spec: ObjectSpec) -> str:
    """The strategy of ``spec`` by :data:`LABEL_RULE` (A | B | C)."""
    if spec.deformable:
        return "C"
    t, longer = spec.size[2], max(spec.size[0], spec.size[1])
    if t >= B_THICKNESS or (t >= B_SQUEEZE_THICKNESS and longer >= B_LARGE_SIDE):
        return "B"
    return "A"


def label_disagreements(objects: Iterable[ObjectSpec]) -> list[tuple[str, str, str]]:
    """(id, paper label, rule label) of every object whose paper (design) label the rule does not
    give.  The rule is fitted to the paper's labels; grounded relabels are reported separately."""
    return [(o.id, o.paper_strategy, label(o)) for o in objects if label(o) != o.paper_strategy]


# ------------------------------------------------------------------------------ scale limits
def _footprint(spec: ObjectSpec) -> tuple[float, float]:
    return float(spec.size[0]), float(spec.size[1])


def _reach_limit(spec: ObjectSpec, cell: CellConfig) -> float:
    """Largest s whose footprint (nominal pose) stays within reach of the nearer shoulder.  The
    footprint point farthest from both shoulders is the middle of the front (or back) edge,
    (+-x/2, 0), for a rectangle and a disc alike."""
    hx = _footprint(spec)[0] / 2
    dz = PANDA_SHOULDER_HEIGHT - cell.arm_base_drop  # shoulder above the table top

    def ok(s):
        return math.hypot(abs(s * hx) + abs(cell.arm_base_x), cell.arm_base_y, dz) <= PANDA_REACH

    lo, hi = 0.0, 100.0
    if ok(hi):
        return hi
    for _ in range(60):
        mid = (lo + hi) / 2
        lo, hi = (mid, hi) if ok(mid) else (lo, mid)
    return lo


def scale_range(
    spec: ObjectSpec, cell: CellConfig | None = None, reset: ResetDistribution | None = None
) -> tuple[float, float]:
    """(s_min, s_max) of ``spec`` in ``cell`` (limits: module docstring).  Raises ValueError when
    no scale satisfies both ends."""
    cell = cell or CellConfig()
    reset = reset or ResetDistribution()
    sx, sy = _footprint(spec)
    shorter, longer = min(sx, sy), max(sx, sy)
    if spec.deformable:
        s_min = max(MIN_SHEET_SIDES[0] / shorter, MIN_SHEET_SIDES[1] / longer)
    else:
        s_min = max(MIN_RIGID_SIDE / shorter, MIN_RIGID_THICKNESS / spec.size[2])
    margin = reset.planar + TABLE_EDGE_MARGIN
    tx, ty = cell.table_size
    s_table = min((tx - 2 * margin) / sx, (ty - 2 * margin) / sy)
    s_max = min(s_table, _reach_limit(spec, cell))
    if s_min > s_max:
        raise ValueError(f"object '{spec.id}': no sensible scale: smallest {s_min:.4g} > largest {s_max:.4g}")
    return float(s_min), float(s_max)


def seven_scales(spec: ObjectSpec, cell: CellConfig | None = None, n: int = N_SCALES) -> tuple[float, ...]:
    """``n`` (default 7) scales spaced uniformly over :func:`scale_range`, rounded to 3 decimals
    inwards (so every one stays inside the range)."""
    if isinstance(n, bool) or not isinstance(n, int) or n < 1:
        raise ValueError(f"number of scales must be an integer >= 1, got {n!r}")
    lo, hi = scale_range(spec, cell)
    lo, hi = math.ceil(lo * 1000 - 1e-6) / 1000, math.floor(hi * 1000 + 1e-6) / 1000
    if n == 1:
        return (round((lo + hi) / 2, 3),)
    return tuple(round(float(v), 3) for v in np.linspace(lo, hi, n))


@dataclasses.dataclass(frozen=True)
class Variant:
    """One transformed instance of a base object: the spec, the scale (None: the original size)
    and whether it is the rigid counterpart of a cloth."""

    spec: ObjectSpec
    base: ObjectSpec
    scale: float | None
    rigid_counterpart: bool

    @property
    def transform(self) -> str:
        parts = (["scale"] if self.scale is not None else []) + (["rigid"] if self.rigid_counterpart else [])
        return "+".join(parts) or "original"

    @property
    def strategy(self) -> str:
        """The original keeps its catalog label.  A transformed instance keeps it too while the rule
        gives the instance the same label as its base (the transform crosses no threshold of
        :data:`LABEL_RULE`); where the rule's label changes (a book scaled past the B thickness, a
        cloth's rigid counterpart), the instance carries the rule's new label.  So a base whose
        grounded label the rule does not reproduce (e.g. the stiff mouse pads: catalog A, rule C)
        does not teach the opposite label through its rescaled copies."""
        return label(self.spec) if self.label_source == "rule" else self.base.strategy

    @property
    def label_source(self) -> str:
        """``catalog`` (the original), ``catalog_kept`` (transformed, the rule's label unchanged)
        or ``rule`` (transformed across a threshold of the rule)."""
        if self.transform == "original":
            return "catalog"
        return "catalog_kept" if label(self.spec) == label(self.base) else "rule"


def variants(
    base: ObjectSpec, n_scales: int = N_SCALES, counterparts: bool = True, cell: CellConfig | None = None
) -> list[Variant]:
    """The base object, its ``n_scales`` rescaled instances and, for a cloth, the rigid counterpart
    of each of these (made from the cloth at that scale, so each pair differs in material only)."""
    out = [Variant(base, base, None, False)]
    out += [Variant(scaled(base, s), base, s, False) for s in (seven_scales(base, cell, n_scales) if n_scales else ())]
    if counterparts and base.deformable:
        out += [Variant(rigid_counterpart(v.spec), base, v.scale, True) for v in list(out)]
    return out
