"""Room dressing of a FlatLab cell: table top with its front-edge profile and material texture,
floor and walls, and visual-only props.

Everything here produces MJCF text (plus a few generated texture images that
:func:`apply_textures` writes into an ``MjSpec``); :mod:`flatlab_lerobot.sim.scene` composes it.
The plain default cell (``CellConfig()``: square edge, flat colour, no room, no props) comes out
exactly as before scenes existed.

Table (front edge at x = +table_size[0]/2, top flat at z = table_height):

* ``square``: one box.
* ``rounded``: a bullnose.  The box stops ``r = thickness/2`` short of the front and a capsule of
  radius ``r`` along y closes it; the capsule's top is tangent to the top surface and its front
  is at the edge, so the edge stays where it was and nothing sticks out below the top.
* ``bevelled``: an undercut chamfer.  The upper half of the slab runs to the edge (a vertical lip);
  below it a 45-degree chamfer (a box rotated about y) slopes back, so a hand reaching under the
  overhang (strategy A) meets less table than at a square edge, never more.

All edge parts carry the top's friction and collision bits (they are table).  Props are built from
primitive geoms with ``contype = conaffinity = 0`` (never touched by physics), placed behind the
table or along the side walls (see :func:`place_props`), outside the arms' workspace and behind the
table as seen from every cell camera (checked in ``tests/test_scenes.py``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np

from flatlab_lerobot.constants import PROP_NAMES

BACK_WALL_X = -1.6  # centre of the back wall; its inner face is at -1.58
WALL_FACE_X = -1.58
SIDE_WALL_Y = 2.4  # side walls (room scenes only); inner faces at +-2.38
SIDE_FACE_Y = 2.38
ARM_CLEARANCE = 0.2  # |y| of an arm base = table half-width + this (m)
ARM_MAX_Y = 0.65  # ... but never farther out than in the default cell (A loses reach on 1 m wide tables)
ARM_EDGE_REACH = 0.3  # the arm bases stand at most this far behind the usable edge (m), as in the default cell
KEEP_OUT_BEHIND = 0.35  # props stay this far behind the table's back edge ...
KEEP_OUT_SIDE = 0.5  # ... or this far beyond an arm base in |y| (the arms' workspace)

VISUAL = 'contype="0" conaffinity="0"'


def _f(v) -> str:
    return " ".join(f"{float(x):.6g}" for x in np.atleast_1d(v))


# ------------------------------------------------------------------------------ textures
@lru_cache(maxsize=32)
def grain_texture(rgb1: tuple, rgb2: tuple, size: int = 256, seed: int = 0) -> np.ndarray:
    """Wood grain (size x size x 3 uint8): wavy bands along the texture's u axis, rgb1 -> rgb2."""
    rng = np.random.default_rng(seed)
    v, u = np.mgrid[0:size, 0:size] / size
    warp = 0.04 * np.sin(2 * np.pi * (2 * u + rng.uniform())) + 0.015 * np.sin(2 * np.pi * (7 * u + rng.uniform()))
    rings = np.sin(2 * np.pi * (11 * (v + warp) + 0.3 * np.sin(2 * np.pi * 3 * v)))
    t = 0.5 + 0.22 * rings + 0.15 * rng.normal(size=(size, 1)).repeat(size, axis=1)  # streaks along u
    t = np.clip(t + 0.06 * rng.normal(size=(size, size)), 0, 1)[..., None]
    img = (1 - t) * np.asarray(rgb1) + t * np.asarray(rgb2)
    return np.clip(img * 255, 0, 255).astype(np.uint8)


@lru_cache(maxsize=32)
def plank_texture(rgb: tuple, size: int = 256, planks: int = 4, seed: int = 1) -> np.ndarray:
    """Floor boards: ``planks`` boards across the texture, each a slightly different shade with
    grain, dark seams between boards and staggered butt joints."""
    rng = np.random.default_rng(seed)
    base = np.asarray(rgb, float)
    img = np.zeros((size, size, 3))
    w = size // planks
    for k in range(planks):
        shade = base * rng.uniform(0.85, 1.08)
        g = grain_texture(tuple(shade), tuple(shade * 0.82), size, seed + 10 + k).astype(float) / 255
        img[k * w:(k + 1) * w] = g[: w]
        img[k * w, :] = base * 0.45  # seam along the board
        joint = int(rng.uniform(0.1, 0.9) * size)
        img[k * w:(k + 1) * w, joint:joint + 2] = base * 0.5  # butt joint
    return np.clip(img * 255, 0, 255).astype(np.uint8)


@lru_cache(maxsize=32)
def concrete_texture(rgb: tuple, size: int = 256, seed: int = 2) -> np.ndarray:
    """Concrete: low-frequency blotches plus fine speckle around ``rgb``."""
    rng = np.random.default_rng(seed)
    coarse = rng.normal(size=(8, 8))
    coarse = np.kron(coarse, np.ones((size // 8, size // 8)))
    k = np.ones(size // 8) / (size // 8)
    coarse = np.apply_along_axis(lambda r: np.convolve(r, k, "same"), 0, coarse)
    coarse = np.apply_along_axis(lambda r: np.convolve(r, k, "same"), 1, coarse)
    t = 1 + 0.06 * coarse / (np.abs(coarse).max() + 1e-9) + 0.05 * rng.normal(size=(size, size))
    return np.clip(np.asarray(rgb)[None, None] * t[..., None] * 255, 0, 255).astype(np.uint8)


def apply_textures(spec, textures: dict[str, np.ndarray]) -> None:
    """Replace the placeholder (builtin flat) textures named in ``textures`` by the images."""
    import mujoco

    for name, img in textures.items():
        t = spec.texture(name)
        if t is None:
            raise KeyError(f"texture {name!r} not in the scene")
        h, w, c = img.shape
        t.builtin = mujoco.mjtBuiltin.mjBUILTIN_NONE
        t.width, t.height, t.nchannel = w, h, c
        t.data = np.ascontiguousarray(img, dtype=np.uint8).tobytes()


# ------------------------------------------------------------------------------ table
EDGE_PROFILES = ("square", "rounded", "bevelled")
PATTERNS = ("flat", "checker", "grain")


@dataclass
class Dressing:
    """MJCF pieces of the room: ``assets`` (inside ``<asset>``), ``floor_walls``, ``table`` and
    ``props`` (inside ``<worldbody>``), and ``textures`` (name -> image) for :func:`apply_textures`."""

    assets: str
    floor_walls: str
    table: str
    props: str
    textures: dict[str, np.ndarray] = field(default_factory=dict)


def table_material_xml(cell) -> tuple[str, dict]:
    """The ``table_top`` material (and texture) of ``cell``."""
    rgba = _f(cell.table_rgba)
    if cell.table_pattern == "flat":
        return f'<material name="table_top" rgba="{rgba}"/>', {}
    c1, c2 = _f(cell.table_rgba[:3]), _f(cell.table_rgba2[:3])
    alpha = f"1 1 1 {cell.table_rgba[3]:.6g}"
    if cell.table_pattern == "checker":  # stone / tile: 3 cm squares with a light speckle
        tex = (f'<texture name="table_tex" type="2d" builtin="checker" rgb1="{c1}" rgb2="{c2}" mark="random" '
               f'random="0.02" markrgb="{_f(np.clip(np.asarray(cell.table_rgba2[:3]) * 1.25, 0, 1))}" width="128" height="128"/>')
        return tex + f'\n    <material name="table_top" texture="table_tex" texrepeat="16 16" texuniform="true" rgba="{alpha}"/>', {}
    if cell.table_pattern == "grain":
        img = grain_texture(tuple(cell.table_rgba[:3]), tuple(cell.table_rgba2[:3]))
        tex = f'<texture name="table_tex" type="2d" builtin="flat" rgb1="{c1}" width="{img.shape[1]}" height="{img.shape[0]}"/>'
        return (tex + f'\n    <material name="table_top" texture="table_tex" texrepeat="1.5 1.5" texuniform="true" rgba="{alpha}"/>',
                {"table_tex": img})
    raise ValueError(f"scene '{cell.scene_id or 'custom'}': field 'table_pattern': must be one of {list(PATTERNS)}, got {cell.table_pattern!r}")


def table_geoms_xml(cell, mask: str) -> str:
    """The table top (named ``table_top``: its upper face is the working surface) and its front-edge
    parts (``table_edge``, ``table_under``), all with the top's friction and collision ``mask``."""
    h, (tx, ty), tt = cell.table_height, cell.table_size, cell.table_thickness
    phys = f'material="table_top" friction="{cell.table_friction:.6g} 0.005 0.0001" condim="4" {mask}'
    if cell.edge == "square":
        return f"""      <geom name="table_top" type="box" size="{tx / 2:.6g} {ty / 2:.6g} {tt / 2:.6g}" pos="0 0 {h - tt / 2:.6g}" material="table_top"
            friction="{cell.table_friction:.6g} 0.005 0.0001" condim="4" {mask}/>"""
    if cell.edge == "rounded":
        r = tt / 2
        return (
            f'      <geom name="table_top" type="box" size="{(tx - r) / 2:.6g} {ty / 2:.6g} {tt / 2:.6g}" '
            f'pos="{-r / 2:.6g} 0 {h - tt / 2:.6g}" {phys}/>\n'
            f'      <geom name="table_edge" type="capsule" size="{r:.6g}" '
            f'fromto="{tx / 2 - r:.6g} {-(ty / 2 - r):.6g} {h - r:.6g} {tx / 2 - r:.6g} {ty / 2 - r:.6g} {h - r:.6g}" {phys}/>'
        )
    if cell.edge == "bevelled":
        a = b = tt / 2  # lip thickness a (vertical front face at the top), chamfer leg b
        d = b / (2 * np.sqrt(2))  # chamfer box half-thickness: just covers the notch behind the face
        return (
            f'      <geom name="table_top" type="box" size="{tx / 2:.6g} {ty / 2:.6g} {a / 2:.6g}" pos="0 0 {h - a / 2:.6g}" {phys}/>\n'
            f'      <geom name="table_under" type="box" size="{(tx - b) / 2:.6g} {ty / 2:.6g} {b / 2:.6g}" '
            f'pos="{-b / 2:.6g} 0 {h - a - b / 2:.6g}" {phys}/>\n'
            f'      <geom name="table_edge" type="box" size="{d:.6g} {ty / 2:.6g} {b / np.sqrt(2):.6g}" '
            f'pos="{tx / 2 - 3 * b / 4:.6g} 0 {h - a - b / 4:.6g}" euler="0 {np.pi / 4:.8g} 0" {phys}/>'
        )
    raise ValueError(f"scene '{cell.scene_id or 'custom'}': field 'edge': must be one of {list(EDGE_PROFILES)}, got {cell.edge!r}")


# ------------------------------------------------------------------------------ floor and walls
FLOOR_STYLE = {"Bedroom": "planks", "Livingroom": "planks", "Study": "planks",
               "Kitchen": "tiles", "Laundryroom": "tiles", "Warehouse": "concrete"}
DEFAULT_FLOOR = ('<texture name="floor_tex" type="2d" builtin="checker" rgb1="0.55 0.55 0.58" rgb2="0.45 0.45 0.48" '
                 'width="256" height="256"/>\n    <material name="floor" texture="floor_tex" texrepeat="6 6"/>')


def floor_material_xml(cell) -> tuple[str, dict]:
    if cell.floor_rgba is None:
        return DEFAULT_FLOOR, {}
    rgb = tuple(float(c) for c in cell.floor_rgba[:3])
    style = FLOOR_STYLE.get(cell.room, "tiles")
    if style == "tiles":  # 40 cm tiles with light grout lines
        tex = (f'<texture name="floor_tex" type="2d" builtin="checker" rgb1="{_f(rgb)}" rgb2="{_f(np.asarray(rgb) * 0.94)}" '
               f'mark="edge" markrgb="{_f(np.clip(np.asarray(rgb) * 1.2 + 0.1, 0, 1))}" width="256" height="256"/>')
        return tex + '\n    <material name="floor" texture="floor_tex" texrepeat="1.25 1.25" texuniform="true"/>', {}
    img = plank_texture(rgb) if style == "planks" else concrete_texture(rgb)
    rep = "1.6 1.6" if style == "planks" else "0.5 0.5"  # planks: 4 boards per 0.625 m -> 16 cm boards
    tex = f'<texture name="floor_tex" type="2d" builtin="flat" rgb1="{_f(rgb)}" width="{img.shape[1]}" height="{img.shape[0]}"/>'
    return tex + f'\n    <material name="floor" texture="floor_tex" texrepeat="{rep}" texuniform="true"/>', {"floor_tex": img}


def floor_walls_xml(cell) -> str:
    lines = [
        '    <geom name="floor" type="plane" size="3 3 0.1" material="floor" contype="0" conaffinity="0"/>',
        '    <geom name="wall_back" type="box" size="0.02 2.5 1.3" pos="-1.6 0 1.3" material="wall" contype="0" conaffinity="0"/>',
    ]
    if cell.room:
        skirting = f'rgba="{_f(np.clip(np.asarray(cell.wall_rgba[:3]) * 0.8, 0, 1))} 1" {VISUAL}'
        lines += [
            f'    <geom name="wall_left" type="box" size="1.8 0.02 1.3" pos="0.2 {SIDE_WALL_Y} 1.3" material="wall" {VISUAL}/>',
            f'    <geom name="wall_right" type="box" size="1.8 0.02 1.3" pos="0.2 {-SIDE_WALL_Y} 1.3" material="wall" {VISUAL}/>',
            f'    <geom name="skirting_back" type="box" size="0.01 2.38 0.04" pos="{WALL_FACE_X + 0.01} 0 0.04" {skirting}/>',
            f'    <geom name="skirting_left" type="box" size="1.79 0.01 0.04" pos="0.21 {SIDE_FACE_Y - 0.01} 0.04" {skirting}/>',
            f'    <geom name="skirting_right" type="box" size="1.79 0.01 0.04" pos="0.21 {-SIDE_FACE_Y + 0.01} 0.04" {skirting}/>',
        ]
    return "\n".join(lines)


def dressing(cell, table_mask: str) -> Dressing:
    """Every room/table piece of ``cell`` (see :class:`Dressing`)."""
    table_mat, tex1 = table_material_xml(cell)
    floor_mat, tex2 = floor_material_xml(cell)
    assets = "\n    ".join([
        floor_mat,
        table_mat,
        '<material name="table_leg" rgba="0.3 0.3 0.32 1"/>',
        f'<material name="wall" rgba="{_f(cell.wall_rgba)}"/>',
    ])
    return Dressing(assets, floor_walls_xml(cell), table_geoms_xml(cell, table_mask), props_xml(cell), {**tex1, **tex2})


# ------------------------------------------------------------------------------ props
class _Parts:
    """Collects primitive visual geoms of one prop in its local frame: origin on the floor at the
    centre of its footprint, +x = the side that faces the table."""

    def __init__(self):
        self.xml: list[str] = []

    def _add(self, s: str, rgba) -> None:
        self.xml.append(f'{s} rgba="{_f(rgba if len(rgba) == 4 else (*rgba, 1))}" {VISUAL}/>')

    def box(self, c, half, rgba, euler=None):
        e = f' euler="{_f(euler)}"' if euler is not None else ""
        self._add(f'<geom type="box" pos="{_f(c)}" size="{_f(half)}"{e}', rgba)

    def cyl(self, c, r, half_h, rgba, axis="z"):
        e = {"z": "", "x": ' euler="0 1.5707963 0"', "y": ' euler="1.5707963 0 0"'}[axis]
        self._add(f'<geom type="cylinder" pos="{_f(c)}" size="{r:.6g} {half_h:.6g}"{e}', rgba)

    def cap(self, a, b, r, rgba):
        self._add(f'<geom type="capsule" fromto="{_f(a)} {_f(b)}" size="{r:.6g}"', rgba)

    def sphere(self, c, r, rgba):
        self._add(f'<geom type="sphere" pos="{_f(c)}" size="{r:.6g}"', rgba)

    def ellipsoid(self, c, radii, rgba):
        self._add(f'<geom type="ellipsoid" pos="{_f(c)}" size="{_f(radii)}"', rgba)


@dataclass(frozen=True)
class Prop:
    """A prop builder.  depth / width: footprint along local x / y (m).  place: ``wall`` (against
    the back wall), ``near`` (free-standing just behind the keep-out zone behind the table),
    ``side`` (against a side wall) or ``floor`` (a rug under the table, footprint ignored)."""

    build: callable
    depth: float
    width: float
    place: str = "wall"


WOOD, DARK_WOOD, LIGHT_WOOD = (0.55, 0.38, 0.24), (0.32, 0.2, 0.12), (0.78, 0.64, 0.46)
WHITE, OFFWHITE, STEEL, BLACK = (0.93, 0.93, 0.92), (0.86, 0.85, 0.82), (0.68, 0.7, 0.72), (0.08, 0.08, 0.09)
CARDBOARD = (0.72, 0.56, 0.36)


def _bed(p: _Parts):  # head against the back wall (local -y once placed on the left side wall)
    p.box((0, 0, 0.15), (0.5, 0.975, 0.13), WOOD)
    p.box((0, 0.02, 0.36), (0.47, 0.93, 0.09), WHITE)  # mattress
    p.box((0, 0.3, 0.4), (0.49, 0.64, 0.075), (0.35, 0.45, 0.7))  # duvet
    p.ellipsoid((0, -0.7, 0.49), (0.32, 0.15, 0.07), OFFWHITE)  # pillow
    p.box((0, -0.965, 0.55), (0.51, 0.025, 0.55), DARK_WOOD)  # headboard
    p.box((0, 0.965, 0.3), (0.51, 0.025, 0.3), DARK_WOOD)  # footboard


def _lamp(p: _Parts):  # floor lamp
    p.cyl((0, 0, 0.015), 0.15, 0.015, BLACK)
    p.cap((0, 0, 0.03), (0, 0, 1.42), 0.012, STEEL)
    p.cyl((0, 0, 1.5), 0.2, 0.13, (0.98, 0.9, 0.7))


def _mirror(p: _Parts):  # wall mirror above a low shelf
    p.box((0, 0, 1.35), (0.02, 0.42, 0.57), (0.72, 0.58, 0.25))
    p.box((0.021, 0, 1.35), (0.003, 0.37, 0.52), (0.78, 0.85, 0.9))
    p.box((0.0, 0, 0.7), (0.02, 0.3, 0.015), (0.72, 0.58, 0.25))


def _wardrobe(p: _Parts):
    p.box((0, 0, 1.02), (0.29, 0.5, 0.98), LIGHT_WOOD)
    p.box((0, 0, 0.02), (0.28, 0.49, 0.02), DARK_WOOD)
    for s in (-1, 1):
        p.box((0.295, s * 0.25, 1.03), (0.006, 0.24, 0.93), (0.84, 0.71, 0.52))
        p.cap((0.31, s * 0.03, 0.95), (0.31, s * 0.03, 1.2), 0.008, STEEL)


def _stool(p: _Parts, seat=0.47, at=(0.0, 0.0)):
    x, y = at
    p.cyl((x, y, seat), 0.17, 0.025, DARK_WOOD)
    for sx in (-1, 1):
        for sy in (-1, 1):
            p.cap((x + sx * 0.08, y + sy * 0.08, seat - 0.02), (x + sx * 0.14, y + sy * 0.14, 0.01), 0.014, BLACK)
    p.cyl((x, y, seat * 0.4), 0.13, 0.008, STEEL)  # foot ring


def _stools(p: _Parts):  # two bar stools
    for y in (-0.3, 0.3):
        _stool(p, seat=0.72, at=(0.0, y))


def _base_cabinet(p: _Parts, width: float, doors: int, top_rgba=(0.2, 0.2, 0.22)):
    p.box((-0.01, 0, 0.05), (0.27, width / 2, 0.05), (0.25, 0.25, 0.25))  # toe kick
    p.box((0, 0, 0.475), (0.29, width / 2, 0.375), WHITE)
    p.box((0.01, 0, 0.87), (0.31, width / 2 + 0.01, 0.02), top_rgba)  # counter top
    dw = width / doors
    for k in range(doors):
        y = -width / 2 + (k + 0.5) * dw
        p.box((0.292, y, 0.48), (0.004, dw / 2 - 0.008, 0.36), (0.86, 0.87, 0.88))
        p.box((0.3, y + (dw / 2 - 0.06) * (1 if k % 2 else -1), 0.74), (0.008, 0.006, 0.05), STEEL)


def _cabinets(p: _Parts):  # kitchen base + wall cabinets
    _base_cabinet(p, 2.0, 4)
    p.box((-0.12, 0, 1.8), (0.17, 1.0, 0.35), WHITE)
    for k in range(4):
        y = -0.75 + 0.5 * k
        p.box((0.052, y, 1.8), (0.004, 0.24, 0.34), (0.86, 0.87, 0.88))
        p.box((0.06, y + 0.18 * (1 if k % 2 else -1), 1.55), (0.006, 0.006, 0.05), STEEL)


def _sink(p: _Parts):  # sink unit: base cabinet, steel basin, tap
    _base_cabinet(p, 1.0, 2)
    p.box((0.04, 0, 0.893), (0.22, 0.34, 0.004), STEEL)
    p.box((0.04, 0, 0.896), (0.19, 0.3, 0.002), (0.42, 0.44, 0.46))  # basin floor seen from above
    p.cap((-0.23, 0, 0.89), (-0.23, 0, 1.16), 0.016, (0.85, 0.86, 0.88))
    p.cap((-0.23, 0, 1.16), (-0.07, 0, 1.12), 0.014, (0.85, 0.86, 0.88))
    p.cap((-0.23, 0.1, 0.9), (-0.23, 0.1, 0.95), 0.015, (0.85, 0.86, 0.88))


def _chair(p: _Parts, at=(0.0, 0.0), rgba=WOOD):  # dining chair facing +x
    x, y = at
    p.box((x, y, 0.45), (0.21, 0.21, 0.025), rgba)
    for sx in (-1, 1):
        for sy in (-1, 1):
            p.box((x + sx * 0.18, y + sy * 0.18, 0.215), (0.018, 0.018, 0.215), rgba)
    for sy in (-1, 1):
        p.box((x - 0.18, y + sy * 0.18, 0.72), (0.018, 0.018, 0.25), rgba)
    p.box((x - 0.185, y, 0.85), (0.014, 0.18, 0.1), rgba)
    p.box((x - 0.185, y, 0.64), (0.014, 0.18, 0.025), rgba)


def _chairs(p: _Parts):
    for y in (-0.3, 0.3):
        _chair(p, at=(0.0, y))


def _fruit_bowl(p: _Parts):  # sideboard with a fruit bowl
    p.box((0, 0, 0.42), (0.22, 0.6, 0.38), DARK_WOOD)
    for s in (-1, 1):
        p.box((0.222, s * 0.3, 0.42), (0.003, 0.28, 0.34), WOOD)
    p.box((0, 0, 0.02), (0.2, 0.58, 0.02), BLACK)
    p.ellipsoid((0, 0.2, 0.83), (0.17, 0.17, 0.045), (0.95, 0.95, 0.9))
    p.sphere((0.04, 0.24, 0.88), 0.045, (0.8, 0.1, 0.08))
    p.sphere((-0.05, 0.17, 0.88), 0.045, (0.95, 0.5, 0.05))
    p.sphere((0.02, 0.12, 0.875), 0.038, (0.4, 0.7, 0.15))
    p.cap((-0.05, 0.3, 0.885), (0.06, 0.33, 0.895), 0.02, (0.95, 0.82, 0.2))
    p.cyl((0, -0.35, 0.9), 0.05, 0.1, (0.3, 0.5, 0.6))  # vase
    p.sphere((0, -0.35, 1.05), 0.08, (0.75, 0.3, 0.45))


def _washer(p: _Parts, dryer: bool = False):  # front loader
    p.box((0, 0, 0.425), (0.3, 0.3, 0.425), WHITE)
    p.box((0.301, 0, 0.78), (0.003, 0.29, 0.055), (0.8, 0.8, 0.82))
    p.cyl((0.306, 0.17, 0.78), 0.03, 0.008, (0.3, 0.3, 0.32), axis="x")
    if dryer:
        p.cyl((0.306, 0.07, 0.78), 0.02, 0.006, (0.3, 0.3, 0.32), axis="x")
        p.cyl((0.305, 0, 0.4), 0.22, 0.008, (0.75, 0.75, 0.77), axis="x")
        p.cyl((0.31, 0, 0.4), 0.17, 0.008, (0.55, 0.6, 0.65), axis="x")
    else:
        p.box((0.301, -0.18, 0.78), (0.004, 0.08, 0.025), (0.2, 0.3, 0.35))  # display
        p.cyl((0.305, 0, 0.42), 0.19, 0.008, (0.45, 0.47, 0.5), axis="x")
        p.cyl((0.31, 0, 0.42), 0.14, 0.008, (0.1, 0.14, 0.2), axis="x")


def _dryer(p: _Parts):
    _washer(p, dryer=True)


def _basket(p: _Parts):  # laundry basket with clothes
    blue = (0.25, 0.45, 0.8)
    p.box((0, 0, 0.01), (0.22, 0.3, 0.01), blue)
    for s in (-1, 1):
        p.box((s * 0.21, 0, 0.2), (0.01, 0.3, 0.2), blue)
        p.box((0, s * 0.29, 0.2), (0.22, 0.01, 0.2), blue)
        for z in (0.12, 0.24):  # slots
            p.box((s * 0.222, 0, z), (0.002, 0.2, 0.02), (0.15, 0.28, 0.55))
    p.ellipsoid((0.05, 0.1, 0.38), (0.14, 0.16, 0.06), (0.9, 0.3, 0.3))
    p.ellipsoid((-0.05, -0.1, 0.39), (0.15, 0.14, 0.06), (0.95, 0.95, 0.95))
    p.ellipsoid((0.0, 0.0, 0.42), (0.1, 0.12, 0.05), (0.3, 0.6, 0.4))


def _shelf_unit(p: _Parts, depth, width, height, levels, post, deck, items_seed=0, beam=None):
    for sx in (-1, 1):
        for sy in (-1, 1):
            p.box((sx * (depth / 2 - 0.02), sy * (width / 2 - 0.02), height / 2), (0.02, 0.02, height / 2), post)
    rng = np.random.default_rng(items_seed)
    zs = np.linspace(0.08, height - 0.1, levels)
    for z in zs:
        p.box((0, 0, z), (depth / 2 - 0.01, width / 2 - 0.01, 0.012), deck)
        if beam is not None:
            p.box((depth / 2 - 0.02, 0, z - 0.03), (0.015, width / 2, 0.03), beam)
        if z < height - 0.3:  # items on every level but the top
            y = -width / 2 + 0.08
            while y < width / 2 - 0.2:
                w, d, h = rng.uniform(0.2, 0.4), rng.uniform(0.2, depth - 0.08), rng.uniform(0.1, min(0.3, zs[1] - zs[0] - 0.08))
                col = CARDBOARD if rng.uniform() < 0.6 else tuple(rng.uniform(0.2, 0.9, 3))
                p.box((0, y + w / 2, z + 0.012 + h / 2), (d / 2, w / 2, h / 2), col)
                y += w + rng.uniform(0.08, 0.2)


def _shelf(p: _Parts):  # utility shelf
    _shelf_unit(p, 0.4, 0.9, 1.8, 4, STEEL, (0.8, 0.8, 0.8), items_seed=3)


def _shelving(p: _Parts):  # warehouse pallet rack
    _shelf_unit(p, 0.6, 1.8, 2.2, 4, (0.15, 0.3, 0.65), (0.55, 0.5, 0.45), items_seed=5, beam=(0.95, 0.45, 0.1))


def _bookshelf(p: _Parts):
    d, w, h = 0.32, 0.9, 1.9
    p.box((-d / 2 + 0.01, 0, h / 2), (0.01, w / 2, h / 2), DARK_WOOD)  # back panel
    for s in (-1, 1):
        p.box((0, s * (w / 2 - 0.01), h / 2), (d / 2, 0.01, h / 2), WOOD)
    rng = np.random.default_rng(7)
    palette = [(0.6, 0.1, 0.1), (0.1, 0.25, 0.5), (0.15, 0.4, 0.2), (0.85, 0.75, 0.5), (0.3, 0.3, 0.3),
               (0.9, 0.5, 0.1), (0.45, 0.2, 0.4), (0.95, 0.95, 0.9)]
    levels = np.linspace(0.02, h - 0.02, 6)
    for k, z in enumerate(levels):
        p.box((0, 0, z), (d / 2, w / 2 - 0.02, 0.012), WOOD)
        if k == len(levels) - 1:
            break
        y, stop = -w / 2 + 0.03, w / 2 - 0.03 - rng.uniform(0.3, 0.5)
        while y < stop:  # a few books per shelf (each geom costs render time in every camera frame)
            t = rng.uniform(0.05, 0.09)
            bh = rng.uniform(0.18, 0.28)
            p.box((0.0, y + t / 2, z + 0.012 + bh / 2), (rng.uniform(0.1, 0.13), t / 2 - 0.001, bh / 2),
                  palette[rng.integers(len(palette))])
            y += t


def _detergent(p: _Parts):  # bench with detergent jugs
    p.box((0, 0, 0.2), (0.2, 0.35, 0.2), OFFWHITE)
    for y, col, hh in ((-0.22, (0.1, 0.35, 0.85), 0.14), (0.0, (0.95, 0.5, 0.05), 0.12), (0.22, (0.15, 0.65, 0.3), 0.15)):
        p.box((0, y, 0.4 + hh), (0.07, 0.09, hh), col)
        p.cyl((0.0, y + 0.05, 0.4 + 2 * hh + 0.02), 0.025, 0.02, WHITE)
        p.box((0.071, y, 0.4 + hh), (0.002, 0.06, hh * 0.5), WHITE)  # label


def _sofa(p: _Parts, width=2.0, rgba=(0.3, 0.45, 0.5)):
    p.box((0, 0, 0.22), (0.42, width / 2, 0.17), rgba)
    p.box((-0.31, 0, 0.62), (0.11, width / 2, 0.28), rgba)
    for s in (-1, 1):
        p.box((0, s * (width / 2 - 0.08), 0.5), (0.42, 0.08, 0.13), rgba)
        for sx in (-1, 1):
            p.cyl((sx * 0.36, s * (width / 2 - 0.06), 0.03), 0.025, 0.03, DARK_WOOD)
    n = 2 if width > 1.2 else 1
    cw = (width - 0.16) / n
    shade = tuple(np.clip(np.asarray(rgba) * 1.15, 0, 1))
    for k in range(n):
        y = -width / 2 + 0.08 + (k + 0.5) * cw
        p.box((0.06, y, 0.44), (0.33, cw / 2 - 0.01, 0.06), shade)
        p.box((-0.16, y, 0.66), (0.06, cw / 2 - 0.02, 0.18), shade)


def _armchair(p: _Parts):
    _sofa(p, width=0.9, rgba=(0.55, 0.25, 0.2))


def _rug(p: _Parts):  # built in place by props_xml (its size follows the table)
    pass


def _tv(p: _Parts):
    p.box((0, 0, 0.25), (0.22, 0.8, 0.25), DARK_WOOD)
    for s in (-1, 1):
        p.box((0.222, s * 0.4, 0.25), (0.002, 0.38, 0.2), WOOD)
    p.box((-0.05, 0, 0.52), (0.08, 0.2, 0.01), BLACK)
    p.box((-0.06, 0, 0.6), (0.02, 0.04, 0.08), BLACK)
    p.box((-0.06, 0, 1.02), (0.025, 0.64, 0.37), BLACK)
    p.box((-0.034, 0, 1.03), (0.002, 0.6, 0.34), (0.12, 0.2, 0.35))


def _plant(p: _Parts):
    p.cyl((0, 0, 0.2), 0.17, 0.2, (0.7, 0.36, 0.22))
    p.cyl((0, 0, 0.39), 0.155, 0.012, (0.25, 0.17, 0.1))
    p.cap((0, 0, 0.4), (0, 0, 0.85), 0.015, (0.3, 0.45, 0.2))
    for k, (dx, dy, z, r) in enumerate(((0.1, 0, 0.8, 0.16), (-0.08, 0.1, 0.95, 0.15), (-0.05, -0.12, 0.9, 0.15),
                                        (0.02, 0.02, 1.1, 0.14), (0.1, -0.05, 1.02, 0.12))):
        g = (0.15 + 0.05 * k, 0.5 + 0.04 * k, 0.15)
        p.ellipsoid((dx, dy, z), (r, r * 0.9, r * 0.7), g)


def _office_chair(p: _Parts):
    for k in range(5):
        a = 2 * np.pi * k / 5
        p.cap((0, 0, 0.06), (0.28 * np.cos(a), 0.28 * np.sin(a), 0.03), 0.022, BLACK)
    p.cap((0, 0, 0.06), (0, 0, 0.42), 0.025, STEEL)
    p.box((0, 0, 0.46), (0.24, 0.24, 0.045), (0.15, 0.15, 0.18))
    p.box((-0.25, 0, 0.82), (0.035, 0.23, 0.26), (0.15, 0.15, 0.18), euler=(0, -0.12, 0))
    for s in (-1, 1):
        p.box((0, s * 0.25, 0.63), (0.14, 0.02, 0.015), BLACK)
        p.box((0.04, s * 0.25, 0.56), (0.015, 0.015, 0.07), BLACK)


def _monitor(p: _Parts):  # side desk with a monitor and keyboard
    p.box((0, 0, 0.72), (0.3, 0.6, 0.02), (0.9, 0.9, 0.88))
    for sy in (-1, 1):
        p.box((0, sy * 0.56, 0.35), (0.27, 0.02, 0.35), (0.3, 0.3, 0.32))
    p.box((-0.12, 0, 0.747), (0.1, 0.13, 0.007), (0.2, 0.2, 0.22))
    p.box((-0.16, 0, 0.88), (0.02, 0.03, 0.13), (0.2, 0.2, 0.22))
    p.box((-0.13, 0, 1.07), (0.02, 0.34, 0.2), BLACK)
    p.box((-0.109, 0, 1.075), (0.002, 0.32, 0.18), (0.25, 0.45, 0.75))
    p.box((0.12, 0, 0.75), (0.07, 0.22, 0.01), (0.2, 0.2, 0.22))


def _cardboard_box(p: _Parts, c, half):
    p.box(c, half, CARDBOARD)
    p.box((c[0], c[1], c[2] + half[2]), (half[0] + 0.001, 0.03, 0.002), (0.82, 0.72, 0.55))  # tape


def _pallet(p: _Parts):  # euro pallet (0.8 x 1.2) with a load of boxes
    for y in np.linspace(-0.54, 0.54, 5):
        p.box((0, y, 0.134), (0.4, 0.06, 0.011), LIGHT_WOOD)
    for x in (-0.34, 0.34):  # the front/back runners; blocks and bottom boards merged into them
        p.box((x, 0, 0.062), (0.05, 0.6, 0.061), (0.68, 0.55, 0.38))
    for x, y, z, hz in ((0.0, -0.3, 0.145, 0.15), (0.0, 0.3, 0.145, 0.15), (0.0, -0.3, 0.445, 0.12)):
        _cardboard_box(p, (x, y, z + hz), (0.39, 0.28, hz))


def _boxes(p: _Parts):  # a stack of cardboard boxes
    for c, half in (((0, -0.25, 0.2), (0.3, 0.24, 0.2)), ((0, 0.25, 0.15), (0.25, 0.24, 0.15)),
                    ((-0.02, -0.2, 0.55), (0.22, 0.2, 0.15)), ((0.02, 0.3, 0.42), (0.2, 0.18, 0.12)),
                    ((0, -0.2, 0.82), (0.15, 0.14, 0.12))):
        _cardboard_box(p, c, half)


def _tape_dispenser(p: _Parts):  # packing stand with a tape gun and rolls
    p.box((0, 0, 0.44), (0.25, 0.4, 0.02), LIGHT_WOOD)
    for sx in (-1, 1):
        for sy in (-1, 1):
            p.box((sx * 0.22, sy * 0.37, 0.21), (0.02, 0.02, 0.21), STEEL)
    p.box((0, 0, 0.1), (0.22, 0.37, 0.01), LIGHT_WOOD)
    p.cyl((0.0, -0.1, 0.53), 0.07, 0.025, (0.75, 0.6, 0.35), axis="x")  # tape roll on the gun
    p.cyl((0.0, -0.1, 0.53), 0.035, 0.028, (0.45, 0.35, 0.2), axis="x")
    p.box((0.0, -0.02, 0.52), (0.015, 0.1, 0.012), (0.85, 0.1, 0.1))
    p.cap((0.0, 0.06, 0.52), (0.0, 0.1, 0.46), 0.018, (0.85, 0.1, 0.1))  # handle
    for y in (0.2, 0.3):
        p.cyl((0.0, y, 0.49), 0.06, 0.025, (0.75, 0.6, 0.35))
    p.cyl((0.0, 0.0, 0.2), 0.1, 0.1, (0.85, 0.88, 0.9))  # stretch-film roll on the lower shelf


def _conveyor(p: _Parts):  # roller conveyor with parcels
    L = 1.0
    p.box((0, 0, 0.8), (0.25, L, 0.015), (0.12, 0.12, 0.12))  # belt
    for s in (-1, 1):
        p.box((s * 0.27, 0, 0.79), (0.02, L, 0.05), (0.75, 0.75, 0.7))
        p.cyl((0, s * L, 0.79), 0.045, 0.25, STEEL, axis="x")
        for y in (-0.8, 0.0, 0.8):
            p.box((s * 0.24, y, 0.37), (0.02, 0.02, 0.37), (0.2, 0.4, 0.2))
    p.box((0, 0.5, 0.95), (0.18, 0.15, 0.135), CARDBOARD)
    p.box((0, -0.4, 0.9), (0.14, 0.2, 0.085), CARDBOARD)
    p.box((0, -0.4, 0.985), (0.141, 0.03, 0.002), (0.82, 0.72, 0.55))


PROPS: dict[str, Prop] = {
    "bed": Prop(_bed, 1.0, 1.95, "side"),
    "lamp": Prop(_lamp, 0.4, 0.4),
    "mirror": Prop(_mirror, 0.05, 0.84),
    "wardrobe": Prop(_wardrobe, 0.62, 1.0),
    "stool": Prop(_stool, 0.34, 0.34, "near"),
    "stools": Prop(_stools, 0.34, 0.94, "near"),
    "cabinets": Prop(_cabinets, 0.64, 2.02),
    "sink": Prop(_sink, 0.64, 1.02),
    "chair": Prop(_office_chair, 0.6, 0.6, "near"),
    "chairs": Prop(_chairs, 0.45, 1.05, "near"),
    "fruit_bowl": Prop(_fruit_bowl, 0.45, 1.2),
    "washer": Prop(_washer, 0.62, 0.6),
    "dryer": Prop(_dryer, 0.62, 0.6),
    "basket": Prop(_basket, 0.45, 0.6),
    "shelf": Prop(_shelf, 0.4, 0.9),
    "detergent": Prop(_detergent, 0.4, 0.7),
    "sofa": Prop(_sofa, 0.85, 2.0),
    "armchair": Prop(_armchair, 0.85, 0.9, "near"),
    "rug": Prop(_rug, 0.0, 0.0, "floor"),
    "tv": Prop(_tv, 0.45, 1.6),
    "plant": Prop(_plant, 0.5, 0.5),
    "bookshelf": Prop(_bookshelf, 0.32, 0.9),
    "monitor": Prop(_monitor, 0.6, 1.2),
    "pallet": Prop(_pallet, 0.8, 1.2),
    "shelving": Prop(_shelving, 0.6, 1.8),
    "boxes": Prop(_boxes, 0.6, 1.0),
    "tape_dispenser": Prop(_tape_dispenser, 0.5, 0.8),
    "conveyor": Prop(_conveyor, 0.58, 2.1),
}
"""A builder for every prop name a scene may list (:data:`flatlab_lerobot.constants.PROP_NAMES`)."""
if set(PROPS) != set(PROP_NAMES):
    raise ImportError(f"sim.room.PROPS and constants.PROP_NAMES disagree: {sorted(set(PROPS) ^ set(PROP_NAMES))}")


@dataclass(frozen=True)
class Placement:
    name: str
    x: float
    y: float
    yaw: float  # rad, turns the prop's local +x (its front)
    footprint: tuple[float, float, float, float]  # world x_lo, x_hi, y_lo, y_hi


def _unknown_prop(cell, name: str) -> ValueError:
    where = f"scene '{cell.scene_id}'" if cell.scene_id else "CellConfig"
    return ValueError(f"{where}: field 'props': unknown prop {name!r} (known: {sorted(PROPS)})")


def place_props(cell) -> list[Placement]:
    """Where each of ``cell.props`` goes.  Rule: ``wall`` props take the back wall, first right of
    the centre line (-y, in full view of the scene sheet's camera), then left, then the side walls; ``near`` props stand just behind the
    keep-out zone behind the table (centred when alone, else left then right); ``side`` props take
    a side wall; the rug lies under the table.  Raises if a prop is unknown, no place is left or
    two footprints overlap."""
    tx = cell.table_size[0]
    x_near = -tx / 2 - KEEP_OUT_BEHIND - 0.01  # front of a near prop
    near = [n for n in cell.props if n in PROPS and PROPS[n].place == "near"]
    back_free, side_free = [-1.0, 1.0], [1.0, -1.0]
    near_sides = [0.0] if len(near) == 1 else [1.0, -1.0]
    # how far the free-standing props reach in |y| and in -x (a wall prop in front of them moves aside)
    near_y = max([PROPS[n].width / 2 + (0.0 if len(near) == 1 else PROPS[n].width / 2 + 0.05) for n in near], default=0.0)
    near_back = min([x_near - PROPS[n].depth for n in near], default=0.0)
    out: list[Placement] = []
    for name in cell.props:
        if name not in PROPS:
            raise _unknown_prop(cell, name)
        pr = PROPS[name]
        d, w = pr.depth, pr.width
        where = pr.place
        if where == "wall" and not back_free:
            where = "side"
        if where == "floor":
            out.append(Placement(name, 0.0, 0.0, 0.0, (0.0, 0.0, 0.0, 0.0)))
            continue
        if where == "wall":
            s = back_free.pop(0)
            y = max(w / 2 + 0.25, 0.9)
            if near and WALL_FACE_X + d > near_back:
                y = max(y, near_y + 0.05 + w / 2)
            x, y = WALL_FACE_X + d / 2, s * y
            fp = (x - d / 2, x + d / 2, y - w / 2, y + w / 2)
            out.append(Placement(name, x, y, 0.0, fp))
        elif where == "near":
            if not near_sides:
                raise ValueError(f"scene '{cell.scene_id}': field 'props': too many free-standing props ({near})")
            s = near_sides.pop(0)
            x, y = x_near - d / 2, s * (w / 2 + 0.05)
            out.append(Placement(name, x, y, 0.0, (x - d / 2, x + d / 2, y - w / 2, y + w / 2)))
        else:  # side wall, front facing the room centre, starting at the back corner
            if not side_free:
                raise ValueError(f"scene '{cell.scene_id}': field 'props': no wall left for prop {name!r}")
            s = side_free.pop(0)
            x, y = WALL_FACE_X + w / 2, s * (SIDE_FACE_Y - d / 2)
            out.append(Placement(name, x, y, -s * np.pi / 2, (x - w / 2, x + w / 2, y - d / 2, y + d / 2)))
    boxes = [p for p in out if PROPS[p.name].place != "floor"]
    for i, a in enumerate(boxes):
        for b in boxes[i + 1:]:
            if a.footprint[0] < b.footprint[1] and b.footprint[0] < a.footprint[1] and \
               a.footprint[2] < b.footprint[3] and b.footprint[2] < a.footprint[3]:
                raise ValueError(f"scene '{cell.scene_id}': field 'props': props {a.name!r} and {b.name!r} overlap")
    return out


def props_xml(cell) -> str:
    """``<body>`` elements (no joints: fixed to the world) holding each prop's visual geoms."""
    if not cell.props:
        return ""
    bodies = []
    for k, pl in enumerate(place_props(cell)):
        p = _Parts()
        if pl.name == "rug":
            tx, ty = cell.table_size
            hx, hy = tx / 2 + 0.45, ty / 2 + 0.45
            p.box((0, 0, 0.002), (hx, hy, 0.002), (0.6, 0.2, 0.18))
            p.box((0, 0, 0.0045), (hx - 0.08, hy - 0.08, 0.0005), (0.85, 0.75, 0.55))
            p.box((0, 0, 0.005), (hx - 0.14, hy - 0.14, 0.0005), (0.55, 0.18, 0.16))
        else:
            PROPS[pl.name].build(p)
        geoms = "\n".join(f"      {g}" for g in p.xml)
        bodies.append(f'    <body name="prop{k}_{pl.name}" pos="{pl.x:.6g} {pl.y:.6g} 0" euler="0 0 {pl.yaw:.8g}">\n{geoms}\n    </body>')
    return "\n".join(bodies)


def room_textures(cell) -> dict[str, np.ndarray]:
    """The generated texture images of ``cell`` (name -> image), for :func:`apply_textures`."""
    return {**table_material_xml(cell)[1], **floor_material_xml(cell)[1]}
