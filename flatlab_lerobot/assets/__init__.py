"""Object geometry: one builder per geometry family, producing the MJCF of a catalog object.

A rigid object is ONE free body named ``object`` (freejoint ``object_free``) composed of MuJoCo
primitive geoms, so it needs no mesh assets:

* **collision** geoms: one hidden primitive of the object's bounding extent (box, or cylinder for
  round objects) -- simple and stable contacts, exactly the ``size`` the expert reasons with.
  Families whose shape matters for grasping (the cutting board's handle hole, the plain slab)
  collide with their visible boxes instead.  The first collision geom is named ``object_geom``.
* **visual** geoms (``contype=conaffinity=0``): covers, pages, keys, rims, faces, frames,
  squares... so every family is recognisable at a glance.  They stay inside the bounding box.
* the inertia is explicit: ``mass`` at ``com_offset``, with the solid box/cylinder inertia of the
  bounding extent.

A deformable object is a flexcomp named ``cloth`` under a static body named ``object``: a
``grid`` sheet (fabrics, towels, scarves, mouse pads) or a ``direct`` triangle mesh whose
outline is a garment (``shorts``: two legs with a gap; ``skirt``: a trapezoid).

Families (see ``catalog.FAMILIES`` for their parameters): slab, book, magazine, photo_album, pad,
box, board, plate, disk, disk_case, keyboard, clock, laptop, painting, chessboard,
cutting_board, sheet, shorts, skirt.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from flatlab_lerobot.catalog import ObjectSpec
from flatlab_lerobot.constants import BIT_LEFT, BIT_OBJECT, BIT_RIGHT, BIT_TABLE, OBJECT_BODY
CLOTH_FLEX = "cloth"
_EPS = 0.0004  # height step between stacked decoration layers (m)
_DECO = 0.001  # thickness of a decoration layer (m)


def _fmt(v) -> str:
    return " ".join(f"{float(x):.6g}" for x in np.atleast_1d(v))


def _shade(rgba, k: float):
    r, g, b, a = rgba
    return (min(1.0, r * k), min(1.0, g * k), min(1.0, b * k), a)


@dataclass(frozen=True)
class Geom:
    """One primitive geom in the object's frame (origin = bounding-box centre).

    type: box | cylinder.  size: MJCF half sizes (box: hx hy hz; cylinder: radius, half height).
    yaw: rotation about z (rad); axis: the axis a cylinder lies along (x | y | z; hinges lie along x).  collide: a
    collision geom (else visual only); hidden: collision-only (not drawn, group 3).
    """

    type: str
    size: tuple
    pos: tuple
    rgba: tuple = (0.5, 0.5, 0.5, 1.0)
    collide: bool = False
    hidden: bool = False
    yaw: float = 0.0
    axis: str = "z"

    def aabb_half(self) -> np.ndarray:
        """Half extent of this geom's axis-aligned bounding box (in the object frame)."""
        if self.type == "box":
            hx, hy, hz = self.size
            c, s = abs(np.cos(self.yaw)), abs(np.sin(self.yaw))
            return np.array([c * hx + s * hy, s * hx + c * hy, hz])
        r, hl = self.size
        return {"x": np.array([hl, r, r]), "y": np.array([r, hl, r]), "z": np.array([r, r, hl])}[self.axis]


def _box(x0, x1, y0, y1, z0, z1, rgba, **kw) -> Geom:
    return Geom("box", ((x1 - x0) / 2, (y1 - y0) / 2, (z1 - z0) / 2), ((x0 + x1) / 2, (y0 + y1) / 2, (z0 + z1) / 2), tuple(rgba), **kw)


def _cyl(r, z0, z1, rgba, x=0.0, y=0.0, **kw) -> Geom:
    return Geom("cylinder", (r, (z1 - z0) / 2), (x, y, (z0 + z1) / 2), tuple(rgba), **kw)


class _Frame:
    """Helpers for one object: half extents and the z of stacked top layers."""

    def __init__(self, obj: ObjectSpec):
        self.obj = obj
        self.hx, self.hy, self.hz = (s / 2 for s in obj.size)
        self.rgba = tuple(obj.rgba)

    def top(self, level: int) -> float:
        """Top z of decoration layer ``level`` (3 = the object's top face, 0 = the body below)."""
        return self.hz - (3 - level) * _EPS

    def deco(self, x0, x1, y0, y1, rgba, level=1) -> Geom:
        t = self.top(level)
        return _box(x0, x1, y0, y1, t - _DECO, t, rgba)

    def deco_disk(self, r, rgba, level=1, x=0.0, y=0.0) -> Geom:
        t = self.top(level)
        return _cyl(r, t - _DECO, t, rgba, x, y)

    def hidden_box(self) -> Geom:
        return _box(-self.hx, self.hx, -self.hy, self.hy, -self.hz, self.hz, (0, 0, 0, 0), collide=True, hidden=True)

    def hidden_cylinder(self) -> Geom:
        return _cyl(self.hx, -self.hz, self.hz, (0, 0, 0, 0), collide=True, hidden=True)

    def body(self, rgba=None, inset=0.0, level=0) -> Geom:
        """The main visual block, its top at layer ``level``."""
        return _box(-self.hx + inset, self.hx - inset, -self.hy + inset, self.hy - inset, -self.hz, self.top(level), rgba or self.rgba)


# ------------------------------------------------------------------------------ rigid families


def _slab(o: ObjectSpec) -> list[Geom]:
    f = _Frame(o)
    return [_box(-f.hx, f.hx, -f.hy, f.hy, -f.hz, f.hz, f.rgba, collide=True)]


def _book(o: ObjectSpec, photo_window: bool = False) -> list[Geom]:
    """Covers + spine (at -y) in the main colour, a page block inset on three sides, a label."""
    f = _Frame(o)
    c = min(o.param("cover"), f.hz * 0.6)
    inset = min(o.param("page_inset"), f.hx * 0.2, f.hy * 0.2)
    page = o.param("page_rgba")
    g = [f.hidden_box(),
         _box(-f.hx, f.hx, -f.hy, f.hy, -f.hz, -f.hz + c, f.rgba),  # back cover
         _box(-f.hx, f.hx, -f.hy, f.hy, f.top(0) - c, f.top(0), f.rgba),  # front cover
         _box(-f.hx, f.hx, -f.hy, -f.hy + max(c, 0.002), -f.hz, f.top(0), _shade(f.rgba, 0.8)),  # spine
         _box(-f.hx + inset, f.hx - inset, -f.hy + c, f.hy - inset, -f.hz + c, f.top(0) - c, page)]  # pages
    if photo_window:  # photo album: a photo in a frame on the cover
        g.append(f.deco(-0.3 * f.hx, 0.3 * f.hx, -0.2 * f.hy, 0.4 * f.hy, _shade(f.rgba, 0.6), level=1))
        g.append(f.deco(-0.25 * f.hx, 0.25 * f.hx, -0.13 * f.hy, 0.33 * f.hy, o.param("photo_rgba"), level=2))
    else:  # title label and a band near the spine
        g.append(f.deco(-0.5 * f.hx, 0.5 * f.hx, 0.1 * f.hy, 0.45 * f.hy, o.param("label_rgba"), level=1))
        g.append(f.deco(-f.hx, f.hx, -0.75 * f.hy, -0.65 * f.hy, o.param("label_rgba"), level=1))
    return g


def _photo_album(o: ObjectSpec) -> list[Geom]:
    return _book(o, photo_window=True)


def _magazine(o: ObjectSpec) -> list[Geom]:
    """A page block with a glossy cover: a big photo and a title band at the top (+x)."""
    f = _Frame(o)
    return [f.hidden_box(), f.body(o.param("page_rgba")),
            f.deco(-f.hx, f.hx, -f.hy, f.hy, f.rgba, level=1),
            f.deco(-0.75 * f.hx, 0.45 * f.hx, -0.8 * f.hy, 0.8 * f.hy, o.param("photo_rgba"), level=2),
            f.deco(0.6 * f.hx, 0.9 * f.hx, -0.85 * f.hy, 0.85 * f.hy, o.param("title_rgba"), level=2)]


def _pad(o: ObjectSpec) -> list[Geom]:
    """A stiff back, a paper block, a binding strip at +x and ruled lines."""
    f = _Frame(o)
    b = min(o.param("binding"), f.hx)
    back = min(0.002, f.hz * 0.3)
    g = [f.hidden_box(), _box(-f.hx, f.hx, -f.hy, f.hy, -f.hz, -f.hz + back, f.rgba),
         _box(-f.hx + 0.001, f.hx - b, -f.hy + 0.001, f.hy - 0.001, -f.hz + back, f.top(0), o.param("page_rgba")),
         _box(f.hx - b, f.hx, -f.hy, f.hy, -f.hz, f.top(2), o.param("binding_rgba"))]
    n = o.param("lines")
    for x in np.linspace(-f.hx, f.hx - b, n + 2)[1:-1]:
        g.append(f.deco(x - 0.0008, x + 0.0008, -f.hy * 0.9, f.hy * 0.9, o.param("line_rgba"), level=1))
    return g


def _box_family(o: ObjectSpec) -> list[Geom]:
    """A closed box: a lid (darker rim band) and an optional tape/ribbon strip."""
    f = _Frame(o)
    g = [f.hidden_box()]
    lid = min(o.param("lid"), f.hz * 2)
    if lid > 0:
        g += [_box(-f.hx + 0.003, f.hx - 0.003, -f.hy + 0.003, f.hy - 0.003, -f.hz, f.hz - lid, _shade(f.rgba, 0.8)),
              _box(-f.hx, f.hx, -f.hy, f.hy, f.hz - lid, f.top(0), f.rgba)]
    else:
        g.append(f.body())
    w = o.param("tape_width")
    if w > 0:
        tape = o.param("tape_rgba")
        g.append(f.deco(-f.hx, f.hx, -w / 2, w / 2, tape, level=1))
        if o.category == "Box" and lid == 0 and w < 0.04:  # a ribbon: the cross strip too
            g.append(f.deco(-w / 2, w / 2, -f.hy, f.hy, tape, level=2))
    return g


def _board(o: ObjectSpec) -> list[Geom]:
    """Planks with seams, or a board with a frame border (whiteboard, cork board)."""
    f = _Frame(o)
    g = [f.hidden_box(), f.body()]
    n = o.param("planks")
    for y in np.linspace(-f.hy, f.hy, n + 1)[1:-1]:
        g.append(f.deco(-f.hx, f.hx, y - 0.0012, y + 0.0012, o.param("seam_rgba"), level=1))
    b = o.param("border")
    if b > 0:
        br = o.param("border_rgba")
        g += [f.deco(-f.hx, f.hx, -f.hy, -f.hy + b, br, 2), f.deco(-f.hx, f.hx, f.hy - b, f.hy, br, 2),
              f.deco(-f.hx, -f.hx + b, -f.hy, f.hy, br, 2), f.deco(f.hx - b, f.hx, -f.hy, f.hy, br, 2)]
    return g


def _ring(r_out: float, width: float, z0: float, z1: float, rgba, n: int = 48) -> list[Geom]:
    """A ring of ``n`` upright boxes (a rim) whose outer corners stay inside radius ``r_out``."""
    t = np.tan(np.pi / n)
    # outer corner at (rc + w/2, seg/2) with seg = 2 (rc + w/2) t (segments touch at the outside)
    ro = r_out / np.sqrt(1 + t * t)
    rc = ro - width / 2
    seg = 2 * ro * t
    out = []
    for k in range(n):
        a = 2 * np.pi * k / n
        out.append(Geom("box", (width / 2, seg / 2, (z1 - z0) / 2), (rc * np.cos(a), rc * np.sin(a), (z0 + z1) / 2), tuple(rgba), yaw=a))
    return out


def _plate(o: ObjectSpec) -> list[Geom]:
    """A foot, a flat well and a raised rim (24 segments).  Collision: the full cylinder."""
    f = _Frame(o)
    r = f.hx
    rim = min(o.param("rim"), r * 0.5)
    base = min(o.param("base"), f.hz * 0.6)
    return [f.hidden_cylinder(),
            _cyl(r * 0.55, -f.hz, -f.hz + base, _shade(f.rgba, 0.9)),  # foot
            _cyl(r - rim + 0.002, -f.hz, -f.hz + base + 0.001, o.param("well_rgba")),  # well
            *_ring(r, rim, -f.hz + base * 0.5, f.hz, f.rgba)]


def _disk(o: ObjectSpec) -> list[Geom]:
    """A disc with an optional centre label and spindle hole."""
    f = _Frame(o)
    g = [f.hidden_cylinder(), _cyl(f.hx, -f.hz, f.top(0), f.rgba)]
    if o.param("label") > 0:
        g.append(f.deco_disk(min(o.param("label"), f.hx * 0.9), o.param("label_rgba"), 1))
    if o.param("hole") > 0:
        g.append(f.deco_disk(o.param("hole"), (0.08, 0.08, 0.08, 1), 2))
    return g


def _disk_case(o: ObjectSpec) -> list[Geom]:
    """A case: the tray, the cover sheet behind the lid, a spine at -x and a title strip."""
    f = _Frame(o)
    s = min(o.param("spine"), f.hx * 0.3)
    return [f.hidden_box(), f.body(),
            f.deco(-f.hx + s, f.hx - 0.003, -f.hy + 0.003, f.hy - 0.003, o.param("cover_rgba"), 1),
            f.deco(-f.hx, -f.hx + s, -f.hy, f.hy, o.param("spine_rgba"), 1),
            f.deco(0.45 * f.hx, 0.75 * f.hx, -0.8 * f.hy, 0.8 * f.hy, o.param("title_rgba"), 2)]


def _keyboard(o: ObjectSpec) -> list[Geom]:
    """A base plate with a grid of keys (the front row has a space bar)."""
    f = _Frame(o)
    kh = min(o.param("key_height"), f.hz)
    m = o.param("margin")
    rows, cols = o.param("rows"), o.param("cols")
    zb = f.hz - kh
    g = [f.hidden_box(), _box(-f.hx, f.hx, -f.hy, f.hy, -f.hz, zb, f.rgba)]
    px, py = (2 * f.hx - 2 * m) / cols, (2 * f.hy - 2 * m) / rows
    key = o.param("key_rgba")
    for r in range(rows):
        y0 = -f.hy + m + r * py
        if r == 0:  # space-bar row, at -y (the front edge of the keyboard)
            c0, c1 = int(cols * 0.3), int(cols * 0.7)
            spans = [(c, c + 1) for c in range(c0)] + [(c0, c1)] + [(c, c + 1) for c in range(c1, cols)]
        else:
            spans = [(c, c + 1) for c in range(cols)]
        for a, b in spans:
            x0 = -f.hx + m + a * px
            g.append(_box(x0 + 0.1 * px, x0 + (b - a) * px - 0.1 * px, y0 + 0.1 * py, y0 + 0.9 * py, zb - 0.001, f.hz, key))
    return g


def _clock(o: ObjectSpec) -> list[Geom]:
    """A case (round or square), a face, 12 hour ticks and two hands at 10:10."""
    f = _Frame(o)
    round_ = o.param("outline") == "round"
    rf = min(f.hx, f.hy) - o.param("bezel")
    g = [f.hidden_cylinder() if round_ else f.hidden_box(),
         _cyl(f.hx, -f.hz, f.top(0), f.rgba) if round_ else f.body(),
         f.deco_disk(rf, o.param("face_rgba"), 1)]
    hand = o.param("hand_rgba")
    t = f.top(2)
    for k in range(12):
        a = 2 * np.pi * k / 12
        ln = 0.14 * rf if k % 3 == 0 else 0.08 * rf
        rc = rf * 0.9 - ln / 2
        g.append(Geom("box", (ln / 2, 0.012 * rf + 0.001, _DECO / 2), (rc * np.cos(a), rc * np.sin(a), t - _DECO / 2), tuple(hand), yaw=a))
    t3 = f.top(3)
    for ang, ln, w in ((np.deg2rad(90 + 60), 0.5 * rf, 0.035 * rf), (np.deg2rad(90 - 60), 0.8 * rf, 0.022 * rf)):
        g.append(Geom("box", (ln / 2, w + 0.0008, _DECO / 2), (ln / 2 * np.cos(ang), ln / 2 * np.sin(ang), t3 - _DECO / 2), tuple(hand), yaw=ang))
    g.append(f.deco_disk(0.05 * rf + 0.002, hand, 3))
    return g


def _laptop(o: ObjectSpec) -> list[Geom]:
    """A closed laptop: base and lid halves with a dark seam, a hinge barrel along the back
    (long) edge at -y, a logo on the lid."""
    f = _Frame(o)
    zb = -f.hz + 2 * f.hz * o.param("base_fraction")
    r = min(f.hz * 0.8, 0.008)
    return [f.hidden_box(),
            _box(-f.hx, f.hx, -f.hy + r, f.hy, -f.hz, zb - 0.0006, f.rgba),
            _box(-f.hx + 0.002, f.hx - 0.002, -f.hy + r, f.hy - 0.002, zb - 0.0006, zb + 0.0006, (0.08, 0.08, 0.08, 1)),
            _box(-f.hx + 0.001, f.hx - 0.001, -f.hy + r, f.hy - 0.001, zb + 0.0006, f.top(0), _shade(f.rgba, 0.92)),
            Geom("cylinder", (r, f.hx * 0.8), (0.0, -f.hy + r, -f.hz + r), tuple(o.param("hinge_rgba")), axis="x"),
            f.deco_disk(min(0.02, f.hy * 0.2), o.param("logo_rgba"), 1, y=0.05 * f.hy)]


def _painting(o: ObjectSpec) -> list[Geom]:
    """A frame around a recessed canvas showing a landscape: ground band and a sun."""
    f = _Frame(o)
    w = min(o.param("frame"), 0.4 * min(f.hx, f.hy))
    g = [f.hidden_box(),
         _box(-f.hx, f.hx, -f.hy, -f.hy + w, -f.hz, f.hz, f.rgba), _box(-f.hx, f.hx, f.hy - w, f.hy, -f.hz, f.hz, f.rgba),
         _box(-f.hx, -f.hx + w, -f.hy + w, f.hy - w, -f.hz, f.hz, f.rgba), _box(f.hx - w, f.hx, -f.hy + w, f.hy - w, -f.hz, f.hz, f.rgba)]
    zc = f.hz - max(0.003, 0.3 * f.hz)  # the canvas is recessed below the frame
    g.append(_box(-f.hx + w, f.hx - w, -f.hy + w, f.hy - w, -f.hz, zc - 2 * _EPS, o.param("canvas_rgba")))
    ix, iy = f.hx - w, f.hy - w
    g.append(_box(-ix, -ix + 0.8 * ix, -iy, iy, zc - _EPS - _DECO, zc - _EPS, o.param("art_rgba")))  # ground
    g.append(_cyl(0.25 * min(ix, iy), zc - _DECO, zc, o.param("sun_rgba"), x=0.45 * ix, y=0.45 * iy))
    return g


def _chessboard(o: ObjectSpec) -> list[Geom]:
    """A base with a border and n x n alternating squares."""
    f = _Frame(o)
    b, n = o.param("border"), o.param("squares")
    g = [f.hidden_box(), f.body()]
    sx, sy = (2 * f.hx - 2 * b) / n, (2 * f.hy - 2 * b) / n
    light, dark = o.param("light_rgba"), o.param("dark_rgba")
    for i in range(n):
        for j in range(n):
            x0, y0 = -f.hx + b + i * sx, -f.hy + b + j * sy
            g.append(f.deco(x0, x0 + sx, y0, y0 + sy, dark if (i + j) % 2 == 0 else light, 1))
    return g


def _cutting_board(o: ObjectSpec) -> list[Geom]:
    """A board with a handle at +x and a square hanging hole in it.  Collides with these boxes."""
    f = _Frame(o)
    hl = o.param("handle")
    hw = min(o.param("handle_width"), 2 * f.hy) / 2
    hole = o.param("hole")
    c = {"collide": True}
    g = [_box(-f.hx, f.hx - hl, -f.hy, f.hy, -f.hz, f.hz, f.rgba, **c)]
    if hl > 0:
        x0, x1 = f.hx - hl, f.hx
        hole = min(hole, hl / 2 - 0.008, hw - 0.008)
        if hole > 0.003:
            xc = (x0 + x1) / 2
            g += [_box(x0, x1, -hw, -hole, -f.hz, f.hz, f.rgba, **c), _box(x0, x1, hole, hw, -f.hz, f.hz, f.rgba, **c),
                  _box(x0, xc - hole, -hole, hole, -f.hz, f.hz, f.rgba, **c), _box(xc + hole, x1, -hole, hole, -f.hz, f.hz, f.rgba, **c)]
        else:
            g.append(_box(x0, x1, -hw, hw, -f.hz, f.hz, f.rgba, **c))
    # a juice groove around the working area (visual)
    gr = _shade(f.rgba, 0.8)
    m, x1 = 0.02, f.hx - hl - 0.02
    t = f.hz + 0.0003
    if min(x1 + f.hx - m, 2 * (f.hy - m)) > 0.01:  # room for it (a small, rescaled board has none)
        g += [_box(-f.hx + m, x1, -f.hy + m, -f.hy + m + 0.003, t - _DECO, t, gr), _box(-f.hx + m, x1, f.hy - m - 0.003, f.hy - m, t - _DECO, t, gr),
              _box(-f.hx + m, -f.hx + m + 0.003, -f.hy + m, f.hy - m, t - _DECO, t, gr), _box(x1 - 0.003, x1, -f.hy + m, f.hy - m, t - _DECO, t, gr)]
    return g


def _rigid_sheet(o: ObjectSpec) -> list[Geom]:
    """The rigid counterpart of a cloth (``transforms.rigid_counterpart``): a plate of the sheet's
    thickness and outline, colliding with its boxes.  sheet: one box; shorts: a waistband and two
    legs around the gap (``leg_gap`` wide, up to ``rise`` below the waist); skirt: 16 strips whose
    widths follow the trapezoid (hem at -y, waist ``waist_ratio`` as wide at +y)."""
    f = _Frame(o)
    c = {"collide": True}
    if o.shape == "shorts":
        g, yc = o.param("leg_gap") / 2, f.hy - o.param("rise") * 2 * f.hy
        return [_box(-f.hx, f.hx, yc, f.hy, -f.hz, f.hz, f.rgba, **c),
                _box(-f.hx, -g, -f.hy, yc, -f.hz, f.hz, f.rgba, **c), _box(g, f.hx, -f.hy, yc, -f.hz, f.hz, f.rgba, **c)]
    if o.shape == "skirt":
        n, wr = 16, o.param("waist_ratio")
        ys = np.linspace(-f.hy, f.hy, n + 1)
        ws = f.hx * (1 - (1 - wr) * ((ys[:-1] + ys[1:]) / 2 + f.hy) / (2 * f.hy))  # at each strip's middle
        return [_box(-ws[k], ws[k], ys[k], ys[k + 1], -f.hz, f.hz, f.rgba, **c) for k in range(n)]
    return [_box(-f.hx, f.hx, -f.hy, f.hy, -f.hz, f.hz, f.rgba, **c)]


RIGID_COUNTERPART_BUILDERS: dict[str, Callable[[ObjectSpec], list[Geom]]] = {
    "sheet": _rigid_sheet, "shorts": _rigid_sheet, "skirt": _rigid_sheet,
}
"""Deformable family -> builder of its rigid counterpart (``material: rigid`` with a cloth family)."""


RIGID_BUILDERS: dict[str, Callable[[ObjectSpec], list[Geom]]] = {
    "slab": _slab, "book": _book, "magazine": _magazine, "photo_album": _photo_album, "pad": _pad,
    "box": _box_family, "board": _board, "plate": _plate, "disk": _disk, "disk_case": _disk_case,
    "keyboard": _keyboard, "clock": _clock, "laptop": _laptop, "painting": _painting,
    "chessboard": _chessboard, "cutting_board": _cutting_board,
}
"""Geometry family -> builder of its primitive geoms (object frame)."""


def rigid_geoms(obj: ObjectSpec) -> list[Geom]:
    """The primitive geoms of a rigid object (collision first)."""
    builder = RIGID_BUILDERS.get(obj.shape) or RIGID_COUNTERPART_BUILDERS.get(obj.shape)
    if builder is None:
        raise ValueError(f"object '{obj.id}': no rigid builder for family {obj.shape!r}")
    return builder(obj)


def _geom_xml(g: Geom, name: str, mask: str, friction: float) -> str:
    attrs = [f'type="{g.type}"', f'size="{_fmt(g.size)}"', f'pos="{_fmt(g.pos)}"']
    if name:
        attrs.insert(0, f'name="{name}"')
    if g.axis != "z":
        attrs.append('zaxis="1 0 0"' if g.axis == "x" else 'zaxis="0 1 0"')
    elif g.yaw:
        attrs.append(f'quat="{np.cos(g.yaw / 2):.6g} 0 0 {np.sin(g.yaw / 2):.6g}"')  # independent of compiler angle units
    if g.collide:
        attrs += [mask, f'friction="{friction:.6g} 0.005 0.0001"', 'condim="4"']
        attrs.append('group="3" rgba="0.5 0.5 0.5 0.3"' if g.hidden else f'rgba="{_fmt(g.rgba)}"')
    else:
        attrs += ['contype="0" conaffinity="0"', 'group="1"', f'rgba="{_fmt(g.rgba)}"']
    return "<geom " + " ".join(attrs) + "/>"


# ------------------------------------------------------------------------------ deformables


def garment_mesh(obj: ObjectSpec) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (N, 3) and triangles (M, 3) of a ``shorts`` / ``skirt`` outline, centred.

    Built from the flex grid: shorts drop the grid cells of the gap between the legs (from the
    hems at -y up to the crotch, a ``rise`` fraction below the waist at +y); a skirt shears the
    grid into a trapezoid whose waist (+y) is ``waist_ratio`` of the hem width.
    """
    nx, ny = obj.flex.count
    sx, sy = obj.size[0], obj.size[1]
    xs, ys = np.linspace(-sx / 2, sx / 2, nx), np.linspace(-sy / 2, sy / 2, ny)
    pts = np.array([(x, y, 0.0) for y in ys for x in xs])
    if obj.shape == "skirt":
        t = (pts[:, 1] + sy / 2) / sy  # 0 at the hem, 1 at the waist
        pts[:, 0] *= 1.0 - (1.0 - obj.param("waist_ratio")) * t
    tris = []
    crotch_y = sy / 2 - obj.param("rise") * sy if obj.shape == "shorts" else -np.inf
    half_gap = obj.param("leg_gap") / 2 if obj.shape == "shorts" else 0.0
    cell_x = sx / (nx - 1)
    for j in range(ny - 1):
        for i in range(nx - 1):
            xc, yc = (xs[i] + xs[i + 1]) / 2, (ys[j] + ys[j + 1]) / 2
            if obj.shape == "shorts" and yc < crotch_y and abs(xc) < max(half_gap, cell_x / 2 + 1e-9):
                continue
            a, b, c, d = j * nx + i, j * nx + i + 1, (j + 1) * nx + i + 1, (j + 1) * nx + i
            tris += [(a, b, c), (a, c, d)]
    tris = np.array(tris, dtype=int)
    used = np.unique(tris)
    remap = -np.ones(len(pts), dtype=int)
    remap[used] = np.arange(len(used))
    return pts[used], remap[tris]


def _flex_body(obj: ObjectSpec, table_height: float, mask: str) -> str:
    f = obj.flex
    sx, sy, _ = obj.size
    nx, ny = f.count
    inner = f"""
        <contact condim="3" friction="{obj.friction:.6g} 0.005 0.0001" solref="{f.solref_timeconst:.6g} 1"
                 selfcollide="none" {mask}/>
        <edge equality="false"/>
        <elasticity young="{f.young:.6g}" poisson="{f.poisson:.6g}" thickness="{f.thickness:.6g}"
                    damping="{f.damping:.6g}" elastic2d="both"/>"""
    if obj.shape == "sheet":
        comp = (f'<flexcomp name="{CLOTH_FLEX}" type="grid" dim="2" count="{nx} {ny} 1" '
                f'spacing="{sx / (nx - 1):.6g} {sy / (ny - 1):.6g} 0.05"')
    elif obj.shape in ("shorts", "skirt"):
        pts, tris = garment_mesh(obj)
        comp = (f'<flexcomp name="{CLOTH_FLEX}" type="direct" dim="2" point="{_fmt(pts.ravel())}" '
                f'element="{" ".join(str(int(i)) for i in tris.ravel())}"')
    else:
        raise ValueError(f"object '{obj.id}': unknown deformable family {obj.shape!r}")
    return f"""
    <body name="{OBJECT_BODY}" pos="0 0 {table_height + f.radius + 0.001:.6g}">
      {comp}
                radius="{f.radius:.6g}" mass="{obj.mass:.6g}" rgba="{_fmt(obj.rgba)}">{inner}
      </flexcomp>
    </body>"""


# ------------------------------------------------------------------------------ public API


def object_xml(obj: ObjectSpec, table_height: float) -> str:
    """MJCF ``<body>`` for ``obj``, resting at the table centre (the env moves it at reset).

    Rigid objects are one free body named ``object``; deformable sheets are a flexcomp named
    ``cloth`` under a static body named ``object``.  Collision bits: see ``sim.robot``.
    """
    mask = f'contype="{BIT_OBJECT}" conaffinity="{BIT_TABLE | BIT_OBJECT | BIT_LEFT | BIT_RIGHT}"'
    if obj.deformable:
        return _flex_body(obj, table_height, mask)
    sz = obj.size[2]
    geoms = rigid_geoms(obj)
    lines, n_col = [], 0
    for g in geoms:
        name = ""
        if g.collide:
            name = "object_geom" if n_col == 0 else f"object_geom{n_col}"
            n_col += 1
        lines.append("      " + _geom_xml(g, name, mask, obj.friction))
    body_geoms = "\n".join(lines)
    return f"""
    <body name="{OBJECT_BODY}" pos="0 0 {table_height + sz / 2 + 0.0005:.6g}">
      <freejoint name="object_free"/>
      <inertial pos="{_fmt(obj.com_offset)}" mass="{obj.mass:.6g}" diaginertia="{_fmt(inertia(obj))}"/>
{body_geoms}
    </body>"""


def inertia(obj: ObjectSpec) -> np.ndarray:
    """Principal moments of inertia (about the centre of mass) of the bounding solid."""
    round_ = obj.shape in ("plate", "disk") or (obj.shape == "clock" and obj.param("outline") == "round")
    if round_:
        r, h, m = obj.size[0] / 2, obj.size[2], obj.mass
        ixx = m * (3 * r * r + h * h) / 12
        return np.array([ixx, ixx, m * r * r / 2])
    return _box_inertia(obj.mass, obj.size)


def _box_inertia(mass, size):
    x, y, z = size
    return mass / 12.0 * np.array([y * y + z * z, x * x + z * z, x * x + y * y])
