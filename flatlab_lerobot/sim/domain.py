"""Domain randomization of one cell: the robot's start posture, the object's mass and friction,
and the camera poses.

A :class:`Domain` is plain data: it is sampled from ranges and a seed (:func:`sample_domain`),
recorded with every collected episode (``Domain.to_json``), and set on a
:class:`~flatlab_lerobot.sim.core.FlatLabSim` by :func:`apply_domain`.  ``apply_domain`` always
starts from the model's nominal values (kept on the first call), so applying one domain after
another never compounds, and ``Domain()`` restores the nominal cell.  The start posture is used
by ``FlatLabSim.reset(home_offsets=...)``: the arms start, and hold, there.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import mujoco
import numpy as np

DOMAIN_STREAM = 0x0D0  # the domain's random stream, separate from the placement's (same episode seed)


@dataclass(frozen=True)
class Domain:
    home_offsets: tuple[float, ...] = ()  # (14,) rad added to the home joints (left arm 7, right arm 7)
    mass_scale: float = 1.0  # object mass (and inertia) x this
    friction_scale: float = 1.0  # object sliding friction x this
    # camera -> (dx, dy, dz) metres in the world frame + (rx, ry, rz) rotation vector (rad) in the camera frame
    camera_offsets: dict[str, tuple[float, ...]] = field(default_factory=dict)

    def to_json(self) -> dict:
        """Plain JSON data, exact (floats are not rounded: the record reproduces the episode)."""
        return {
            "home_offsets": [float(v) for v in self.home_offsets],
            "mass_scale": float(self.mass_scale),
            "friction_scale": float(self.friction_scale),
            "camera_offsets": {c: [float(v) for v in o] for c, o in self.camera_offsets.items()},
        }

    @classmethod
    def from_json(cls, d: dict) -> Domain:
        return cls(
            tuple(d.get("home_offsets", ())), float(d.get("mass_scale", 1.0)), float(d.get("friction_scale", 1.0)),
            {c: tuple(o) for c, o in d.get("camera_offsets", {}).items()},
        )  # fmt: skip


def sample_domain(
    seed: int,
    cameras: Sequence[str] = (),
    joint_noise: float = 0.0,
    mass_scale: tuple[float, float] = (1.0, 1.0),
    friction_scale: tuple[float, float] = (1.0, 1.0),
    camera_pos_jitter: float = 0.0,
    camera_rot_jitter_deg: float = 0.0,
) -> Domain:
    """A domain drawn uniformly from the ranges (joint offsets in +-joint_noise rad, camera offsets
    in +-camera_pos_jitter m per axis and +-camera_rot_jitter_deg per rotation axis); the same
    seed and ranges always give the same domain."""
    rng = np.random.default_rng([int(seed), DOMAIN_STREAM])
    home = rng.uniform(-joint_noise, joint_noise, 14) if joint_noise > 0 else ()
    ms = float(rng.uniform(*mass_scale)) if mass_scale[0] != mass_scale[1] else float(mass_scale[0])
    fs = float(rng.uniform(*friction_scale)) if friction_scale[0] != friction_scale[1] else float(friction_scale[0])
    cams = {}
    if camera_pos_jitter > 0 or camera_rot_jitter_deg > 0:
        rot = np.radians(camera_rot_jitter_deg)
        for c in cameras:
            cams[c] = (*rng.uniform(-camera_pos_jitter, camera_pos_jitter, 3), *rng.uniform(-rot, rot, 3))
    return Domain(tuple(float(v) for v in home), ms, fs, cams)


@dataclass
class _Nominal:
    body_mass: np.ndarray
    body_inertia: np.ndarray
    geom_friction: np.ndarray
    flex_friction: np.ndarray
    cam_pos: np.ndarray
    cam_quat: np.ndarray


def apply_domain(sim, domain: Domain | None) -> None:
    """Set ``domain``'s object mass/friction and camera poses on ``sim``'s model, from the nominal
    values (the start posture is ``sim.reset``'s ``home_offsets``).  Call before ``sim.reset``.
    ``None``: back to the nominal model (nothing to do when no domain was ever applied)."""
    m = sim.model
    nom = sim.domain_nominal
    if domain is None:
        if nom is None:
            return
        domain = Domain()
    if nom is None:
        nom = sim.domain_nominal = _Nominal(
            m.body_mass.copy(), m.body_inertia.copy(), m.geom_friction.copy(), m.flex_friction.copy(),
            m.cam_pos.copy(), m.cam_quat.copy(),
        )  # fmt: skip
    if not (domain.mass_scale > 0 and domain.friction_scale > 0):
        raise ValueError(f"mass_scale and friction_scale must be > 0, got {domain.mass_scale}, {domain.friction_scale}")
    m.body_mass[:], m.body_inertia[:] = nom.body_mass, nom.body_inertia
    m.geom_friction[:], m.flex_friction[:] = nom.geom_friction, nom.flex_friction
    m.cam_pos[:], m.cam_quat[:] = nom.cam_pos, nom.cam_quat
    for o in sim.objects[:1]:  # the target object (clutter keeps its catalog values)
        if o.flex_id >= 0:
            adr, num = m.flex_vertadr[o.flex_id], m.flex_vertnum[o.flex_id]
            bodies = m.flex_vertbodyid[adr : adr + num]
            m.flex_friction[o.flex_id, 0] = nom.flex_friction[o.flex_id, 0] * domain.friction_scale
        else:
            bodies = np.array([o.body])
            m.geom_friction[o.geoms, 0] = nom.geom_friction[o.geoms, 0] * domain.friction_scale
        m.body_mass[bodies] = nom.body_mass[bodies] * domain.mass_scale
        m.body_inertia[bodies] = nom.body_inertia[bodies] * domain.mass_scale
    for cam, off in domain.camera_offsets.items():
        i = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_CAMERA, cam)
        if i < 0:
            raise ValueError(f"domain: unknown camera {cam!r}")
        off = np.asarray(off, float)
        m.cam_pos[i] = nom.cam_pos[i] + off[:3]
        angle = float(np.linalg.norm(off[3:6]))
        if angle > 0:
            dq = np.zeros(4)
            mujoco.mju_axisAngle2Quat(dq, off[3:6] / angle, angle)
            q = np.zeros(4)
            mujoco.mju_mulQuat(q, nom.cam_quat[i], dq)
            m.cam_quat[i] = q
    if domain.mass_scale != sim.domain_mass_scale:
        mujoco.mj_setConst(m, sim.data)  # mass-derived constants (subtree masses, inverse weights)
        sim.domain_mass_scale = domain.mass_scale
