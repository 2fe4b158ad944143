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
from flatlab_lerobot.catalog import ObjectSpec
from flatlab_lerobot.sim.robot import ARMS, BIT_LEFT, BIT_OBJECT, BIT_RIGHT, BIT_TABLE, attach_arm



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


@dataclass
class CellConfig:
    """Geometry and physics of the cell.

    table_height: height of the table top above the floor (m).  table_size: (depth along x,
    width along y) of the top (m).  table_thickness: slab thickness (m).  table_friction:
    sliding friction of the top.  table_rgba: colour.  arm_base_y: |y| of the arm bases;
    arm_base_x: x of both bases; arm_base_drop: how far the bases sit below the table top (m),
    which lets a hand reach the table edge horizontally (measured with IK, see robot.py).  cameras: the named cameras (default: front, top, left, right).
    rigid_timestep / cloth_timestep: physics step for scenes without / with a cloth (s).
    """

    table_height: float = 0.75
    table_size: tuple[float, float] = (0.6, 0.9)
    table_thickness: float = 0.04
    table_friction: float = 0.3
    table_rgba: tuple[float, float, float, float] = (0.62, 0.5, 0.38, 1.0)
    arm_base_x: float = 0.0
    arm_base_y: float = 0.65
    arm_base_drop: float = 0.15
    cameras: tuple[CameraSpec, ...] | None = None
    rigid_timestep: float = 0.002
    cloth_timestep: float = 0.004
    extra: dict = field(default_factory=dict)

    @property
    def edge_x(self) -> float:
        return self.table_size[0] / 2

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
    <texture name="floor_tex" type="2d" builtin="checker" rgb1="0.55 0.55 0.58" rgb2="0.45 0.45 0.48" width="256" height="256"/>
    <material name="floor" texture="floor_tex" texrepeat="6 6"/>
    <material name="table_top" rgba="{_fmt(cell.table_rgba)}"/>
    <material name="table_leg" rgba="0.3 0.3 0.32 1"/>
    <material name="wall" rgba="0.85 0.84 0.8 1"/>
  </asset>
  <worldbody>
    <light name="sun" pos="0.5 0 2.6" dir="-0.2 0 -1" diffuse="0.5 0.5 0.5" castshadow="false"/>
    <geom name="floor" type="plane" size="3 3 0.1" material="floor" contype="0" conaffinity="0"/>
    <geom name="wall_back" type="box" size="0.02 2.5 1.3" pos="-1.6 0 1.3" material="wall" contype="0" conaffinity="0"/>
    <body name="table">
      <geom name="table_top" type="box" size="{tx / 2:.6g} {ty / 2:.6g} {tt / 2:.6g}" pos="0 0 {h - tt / 2:.6g}" material="table_top"
            friction="{cell.table_friction:.6g} 0.005 0.0001" condim="4" {table_mask}/>
{legs}
    </body>
{pedestals}
{cams}
{obj_xml}
  </worldbody>
</mujoco>"""


def build_spec(cell: CellConfig, obj: ObjectSpec | None) -> mujoco.MjSpec:
    spec = mujoco.MjSpec.from_string(scene_xml(cell, obj))
    for arm, s in zip(ARMS, (1, -1)):
        base = (cell.arm_base_x, s * cell.arm_base_y, cell.table_height - cell.arm_base_drop)
        attach_arm(spec, arm, base, yaw=-s * np.pi / 2)
    return spec


def build_model(cell: CellConfig, obj: ObjectSpec | None) -> mujoco.MjModel:
    """Compile the cell with ``obj`` (or with no object, e.g. for a kinematic IK model)."""
    return build_spec(cell, obj).compile()
