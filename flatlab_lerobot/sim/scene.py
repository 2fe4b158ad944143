"""Compose a FlatLab cell as a MuJoCo model: room + table + two Pandas + cameras + one object.

World frame: floor at z = 0, table centred on the origin, its top at ``table_height``.  The
*usable edge* (where strategy A pushes objects to) is the front edge, at x = +table_size[0]/2,
facing the ``front`` camera.  The arms stand on pedestals at the two short ends of the table
(left arm at +y, right arm at -y), facing each other.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import mujoco
import numpy as np

from flatlab_lerobot.assets import object_xml
from flatlab_lerobot.catalog import ObjectSpec, get_scene
from flatlab_lerobot.constants import BIT_LEFT, BIT_OBJECT, BIT_RIGHT, BIT_TABLE, OBJECT_BODY
from flatlab_lerobot.sim.robot import ARMS, attach_arm
from flatlab_lerobot.sim.room import (
    ARM_CLEARANCE,
    ARM_EDGE_REACH,
    ARM_MAX_Y,
    apply_textures,
    dressing,
    room_textures,
)


RIGID_TIMESTEP = 0.001
"""Physics step of rigid scenes (s).  At 2 ms a light object pressed by a fingertip (a 30 g CD
squeezed between the stiff finger pad and the table: 7 finger + 4 table contacts on a body 100x
lighter than the arm) made the contact solve jump: the disc was shot up into the finger and then
through the table top.  Strategy A on a CD and a cork coaster (5 seeds each): 0/10 at 2 ms,
10/10 at 1 ms; B on ref_box, a glass chessboard and a pizza box: 16/18 at both steps."""
CLOTH_TIMESTEP = 0.004
"""Physics step of scenes with a cloth (s): flex collisions dominate the cost there."""


@dataclass(frozen=True)
class CameraSpec:
    """A named camera looking from ``pos`` at ``target`` (world frame, metres), ``fovy`` in degrees."""

    name: str
    pos: tuple[float, float, float]
    target: tuple[float, float, float]
    fovy: float = 58.0


def default_cameras(table_height: float) -> tuple[CameraSpec, ...]:
    h = table_height
    return (
        CameraSpec("front", (1.25, 0.0, h + 0.55), (0.05, 0.0, h)),
        CameraSpec("top", (0.0, 0.0, h + 1.25), (0.0, 0.0, h), fovy=55.0),
        CameraSpec("left", (0.95, 0.75, h + 0.75), (0.0, 0.0, h)),
        CameraSpec("right", (0.95, -0.75, h + 0.75), (0.0, 0.0, h)),
    )


CALIBRATION_NAMES = (
    "table_height", "table_depth", "table_width", "table_thickness", "arm_base_x", "arm_base_y", "arm_base_drop",
)  # fmt: skip  (CellConfig.calibration: what the env observes as ``cell``)


@dataclass
class CellConfig:
    """Geometry and physics of the cell.

    table_height: height of the table top above the floor (m).  table_size: (depth along x,
    width along y) of the top (m).  table_thickness: slab thickness (m).  table_friction:
    sliding friction of the top.  table_rgba: colour.  arm_base_y: |y| of the arm bases (default:
    table half-width + ARM_CLEARANCE = 0.2 m, at most ARM_MAX_Y = 0.65 m as in the default cell; on
    1 m wide tables 0.7 m cost strategy A reach: 24/40 lifts vs 35/40 at 0.65 m).  arm_base_x: x of
    both bases (default: 0, on tables deeper than 0.6 m ARM_EDGE_REACH = 0.3 m behind the usable
    edge, so A still reaches it).  arm_base_drop: how far the bases sit below the table top (m),
    which lets a hand reach the table edge horizontally (measured with IK, see robot.py).  cameras: the named cameras (default: front, top, left, right).
    rigid_timestep / cloth_timestep: physics step for scenes without / with a cloth (s); see
    RIGID_TIMESTEP for why rigid scenes step at 1 ms.

    Scene dressing (:meth:`from_scene` fills these from
    ``envs/scenes``; the defaults give the plain cell): edge: front-edge profile (square | rounded |
    bevelled, see ``sim/room.py``); table_rgba2 / table_pattern: second colour and pattern (flat |
    checker | grain) of the top; room: room category ('' = no side walls, no room floor); wall_rgba /
    floor_rgba (None = grey checker floor); props: names of visual-only props (``sim.room.PROPS``);
    scene_id: the scene's id (for messages).
    """

    table_height: float = 0.75
    table_size: tuple[float, float] = (0.6, 0.9)
    table_thickness: float = 0.04
    table_friction: float = 0.3
    table_rgba: tuple[float, float, float, float] = (0.62, 0.5, 0.38, 1.0)
    arm_base_x: float | None = None
    arm_base_y: float | None = None
    arm_base_drop: float = 0.15
    cameras: tuple[CameraSpec, ...] | None = None
    rigid_timestep: float = RIGID_TIMESTEP
    cloth_timestep: float = CLOTH_TIMESTEP
    extra: dict = field(default_factory=dict)
    edge: str = "square"
    table_rgba2: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0)
    table_pattern: str = "flat"
    room: str = ""
    wall_rgba: tuple[float, float, float, float] = (0.85, 0.84, 0.8, 1.0)
    floor_rgba: tuple[float, float, float, float] | None = None
    props: tuple[str, ...] = ()
    scene_id: str = ""

    def __post_init__(self):
        if self.arm_base_y is None:
            self.arm_base_y = min(self.table_size[1] / 2 + ARM_CLEARANCE, ARM_MAX_Y)
        if self.arm_base_x is None:
            self.arm_base_x = max(0.0, self.table_size[0] / 2 - ARM_EDGE_REACH)
        self.props = tuple(self.props)

    @classmethod
    def from_scene(cls, scene_id: str, scenes_dir=None, materials_dir=None) -> CellConfig:
        """The cell of scene ``scene_id`` (``envs/scenes``): table geometry, edge profile, material
        (friction, colours, pattern), room colours and props.  The arm bases follow the table
        (``arm_base_y`` = half-width + 0.2 m, the default).  KeyError for an unknown id."""
        s, mat = get_scene(scene_id, scenes_dir, materials_dir)
        return cls(
            table_height=s.table_height, table_size=s.table_size, table_thickness=s.table_thickness,
            table_friction=mat.friction, table_rgba=mat.rgba, table_rgba2=mat.rgba2, table_pattern=mat.pattern,
            edge=s.edge, room=s.room, wall_rgba=s.wall_rgba, floor_rgba=s.floor_rgba, props=s.props, scene_id=s.id,
        )  # fmt: skip

    @property
    def edge_x(self) -> float:
        return self.table_size[0] / 2

    def calibration(self) -> np.ndarray:
        """The cell as a robot's calibration knows it (``CALIBRATION_NAMES``): table top height,
        depth, width and thickness, and where the arm bases stand.  The env observes it as ``cell``,
        so a policy that plans with a kinematic model (the scripted expert, the learned executor)
        builds the cell it is evaluated in: :meth:`from_calibration`."""
        depth, width = self.table_size
        return np.array(
            [self.table_height, depth, width, self.table_thickness, self.arm_base_x, self.arm_base_y, self.arm_base_drop]
        )

    @classmethod
    def from_calibration(cls, v) -> CellConfig:
        """The kinematic cell of :meth:`calibration`'s vector (no scene dressing: the arms, the
        table top and its edge are what a planner needs)."""
        v = np.asarray(v, np.float64).reshape(-1)
        if v.shape != (len(CALIBRATION_NAMES),):
            raise ValueError(f"a cell calibration has {len(CALIBRATION_NAMES)} values {CALIBRATION_NAMES}, got {v.shape}")
        h, depth, width, thick, bx, by, drop = (float(x) for x in v)
        return cls(table_height=h, table_size=(depth, width), table_thickness=thick, arm_base_x=bx, arm_base_y=by,
                   arm_base_drop=drop)  # fmt: skip

    def camera_specs(self) -> tuple[CameraSpec, ...]:
        return self.cameras if self.cameras is not None else default_cameras(self.table_height)


def look_at_xyaxes(pos, target) -> list[float]:
    """MuJoCo camera ``xyaxes`` for a camera at ``pos`` looking at ``target`` (z up)."""
    fwd = np.asarray(target, float) - np.asarray(pos, float)
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, [0.0, 0.0, 1.0])
    if np.linalg.norm(right) < 1e-6:
        right = np.array([0.0, -1.0, 0.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    return [*right, *up]


def _fmt(v) -> str:
    return " ".join(f"{float(x):.6g}" for x in np.atleast_1d(v))


def scene_xml(cell: CellConfig, obj: ObjectSpec | None) -> str:
    """The world part of the cell (everything but the arms) as MJCF text."""
    deformable = obj is not None and obj.deformable
    if deformable:
        # Cloth scenes: the discrete integrator (flex elasticity needs it).  Sleeping islands let a cloth
        # at rest drop out of the solver (it wakes when touched): 1176 cloth-table contacts otherwise
        # dominate the step.
        option = (
            f'<option timestep="{cell.cloth_timestep}" integrator="discrete" solver="Newton" tolerance="1e-6" '
            f'cone="elliptic" impratio="10"><flag sleep="enable"/></option>'
        )
    else:
        option = f'<option timestep="{cell.rigid_timestep}" integrator="implicitfast" cone="elliptic" impratio="10"/>'
    h, (tx, ty), tt = cell.table_height, cell.table_size, cell.table_thickness
    table_mask = f'contype="{BIT_TABLE}" conaffinity="{BIT_OBJECT | BIT_LEFT | BIT_RIGHT}"'
    room = dressing(cell, table_mask)  # floor, walls, table top + edge, material textures, props (sim/room.py)
    props = f"\n{room.props}" if room.props else ""
    legs = "\n".join(
        f'      <geom type="box" size="0.025 0.025 {(h - tt) / 2:.6g}" pos="{sx * (tx / 2 - 0.05):.6g} {sy * (ty / 2 - 0.05):.6g} {(h - tt) / 2:.6g}" material="table_leg" contype="0" conaffinity="0"/>'
        for sx in (-1, 1)
        for sy in (-1, 1)
    )
    pedestals = "\n".join(
        f'    <geom name="{arm}_pedestal" type="box" size="0.1 0.1 {(h - cell.arm_base_drop) / 2:.6g}" pos="{cell.arm_base_x:.6g} {s * cell.arm_base_y:.6g} {(h - cell.arm_base_drop) / 2:.6g}" rgba="0.25 0.25 0.27 1" contype="0" conaffinity="0"/>'
        for arm, s in zip(ARMS, (1, -1))
    )
    cams = "\n".join(
        f'    <camera name="{c.name}" pos="{_fmt(c.pos)}" xyaxes="{_fmt(look_at_xyaxes(c.pos, c.target))}" fovy="{c.fovy:.6g}"/>'
        for c in cell.camera_specs()
    )
    obj_xml = object_xml(obj, cell.table_height) if obj is not None else ""
    return f"""
<mujoco model="flatlab_cell">
  <compiler angle="radian" autolimits="true"/>
  {option}
  <size memory="64M"/>
  <visual>
    <quality offsamples="0" shadowsize="0"/>
    <global offwidth="1280" offheight="960"/>
    <headlight ambient="0.45 0.45 0.45" diffuse="0.5 0.5 0.5" specular="0.05 0.05 0.05"/>
  </visual>
  <asset>
    {room.assets}
  </asset>
  <worldbody>
    <light name="sun" pos="0.5 0 2.6" dir="-0.2 0 -1" diffuse="0.5 0.5 0.5" castshadow="false"/>
{room.floor_walls}
    <geom name="floor_collision" type="plane" size="0 0 1" group="3" rgba="0 0 0 0" contype="0" conaffinity="{BIT_OBJECT | BIT_LEFT | BIT_RIGHT}"/>
    <body name="table">
{room.table}
{legs}
    </body>
{pedestals}
{cams}{props}
{obj_xml}
  </worldbody>
</mujoco>"""


CLUTTER_PREFIX = "clutter"


def clutter_name(i: int, name: str = OBJECT_BODY) -> str:
    """Name of element ``name`` (body ``object``, joint ``object_free``, geom ``object_geom``...) of
    clutter object ``i`` (1, 2, ...): ``clutter<i>/<name>``."""
    return f"{CLUTTER_PREFIX}{i}/{name}"


def add_clutter(spec: mujoco.MjSpec, cell: CellConfig, clutter) -> None:
    """Add rigid ``clutter`` objects (ObjectSpecs) next to the main one: each is the object's own
    MJCF body (same collision bits) attached under the prefix ``clutter<i>/``, resting at the
    table centre until the sim places it."""
    for i, o in enumerate(clutter, start=1):
        if o.deformable:
            raise ValueError(f"clutter object {o.id!r} is deformable; clutter objects must be rigid")
        sub = mujoco.MjSpec.from_string(
            f'<mujoco><compiler angle="radian"/><worldbody>{object_xml(o, cell.table_height)}</worldbody></mujoco>'
        )
        spec.worldbody.add_frame().attach_body(sub.body(OBJECT_BODY), f"{CLUTTER_PREFIX}{i}/", "")


BIN_DEPTH = 0.6  # m along x, in front of the usable edge
BIN_WALL = 0.22  # wall height above the floor (m)


def add_drop_bin(spec: mujoco.MjSpec, cell: CellConfig) -> None:
    """An open bin on the floor in front of the usable edge (x from the edge to edge + BIN_DEPTH,
    as wide as the table): objects carried past the edge and released fall into it.  It collides
    with objects only (contype 0, conaffinity BIT_OBJECT), never with the arms; its floor is a
    10 cm slab so falling thin objects cannot tunnel through."""
    x0, hy, t = cell.edge_x, cell.table_size[1] / 2 + 0.05, 0.02
    body = spec.worldbody.add_body(name="drop_bin")
    box = mujoco.mjtGeom.mjGEOM_BOX
    parts = {
        "bottom": ([BIN_DEPTH / 2, hy, 0.05], [x0 + BIN_DEPTH / 2, 0.0, -0.03]),
        "near": ([t / 2, hy, BIN_WALL / 2], [x0 - t / 2, 0.0, BIN_WALL / 2]),
        "far": ([t / 2, hy, BIN_WALL / 2], [x0 + BIN_DEPTH + t / 2, 0.0, BIN_WALL / 2]),
        "side_l": ([BIN_DEPTH / 2, t / 2, BIN_WALL / 2], [x0 + BIN_DEPTH / 2, hy + t / 2, BIN_WALL / 2]),
        "side_r": ([BIN_DEPTH / 2, t / 2, BIN_WALL / 2], [x0 + BIN_DEPTH / 2, -hy - t / 2, BIN_WALL / 2]),
    }
    for name, (size, pos) in parts.items():
        body.add_geom(name=f"drop_bin_{name}", type=box, size=size, pos=pos, rgba=[0.22, 0.32, 0.42, 1.0],
                      contype=0, conaffinity=BIT_OBJECT)  # fmt: skip


def build_spec(cell: CellConfig, obj: ObjectSpec | None, clutter=(), drop_bin: bool = False) -> mujoco.MjSpec:
    spec = mujoco.MjSpec.from_string(scene_xml(cell, obj))
    apply_textures(spec, room_textures(cell))
    for arm, s in zip(ARMS, (1, -1)):
        base = (cell.arm_base_x, s * cell.arm_base_y, cell.table_height - cell.arm_base_drop)
        attach_arm(spec, arm, base, yaw=-s * np.pi / 2)
    if clutter:
        add_clutter(spec, cell, clutter)
    if drop_bin:
        add_drop_bin(spec, cell)
    return spec


def build_model(cell: CellConfig, obj: ObjectSpec | None, clutter=(), drop_bin: bool = False) -> mujoco.MjModel:
    """Compile the cell with ``obj`` (or with no object, e.g. for a kinematic IK model) and, for a
    cluttered desk, the rigid ``clutter`` objects (:func:`add_clutter`) and the drop bin."""
    return build_spec(cell, obj, clutter, drop_bin).compile()
