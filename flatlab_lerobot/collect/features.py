"""The dataset's features (keys, dtypes, shapes, names), the camera metadata that lets depth be turned back
into point clouds, and that back-projection."""

from __future__ import annotations


import numpy as np

from flatlab_lerobot.collect.recipe import Recipe
from flatlab_lerobot.sim.core import EE_POSE_NAMES, ENV_STATE_DIM, ENV_STATE_NAMES, STATE_NAMES

def joint_names() -> list[str]:
    return list(STATE_NAMES)


def build_features(recipe: Recipe) -> dict:
    s = recipe.image_size
    vis = "video" if recipe.video.use_videos else "image"
    feats: dict = {
        "observation.state": {"dtype": "float32", "shape": (16,), "names": joint_names()},
        "action": {"dtype": "float32", "shape": (16,), "names": joint_names()},
    }
    if recipe.has("rgb"):
        for cam in recipe.cameras:
            feats[f"observation.images.{cam}"] = {
                "dtype": vis, "shape": (s, s, 3), "names": ["height", "width", "channels"],
            }  # fmt: skip
    if recipe.has("depth"):
        for cam in recipe.cameras:
            feats[f"observation.depth.{cam}"] = {
                "dtype": vis, "shape": (s, s, 1), "names": ["height", "width", "channels"],
                "info": {"is_depth_map": True},
            }  # fmt: skip
    if recipe.has("pointcloud"):
        feats["observation.pointcloud"] = {"dtype": "float32", "shape": (recipe.n_points, 3), "names": None}
    if recipe.has("object_pointcloud"):
        feats["observation.object_pointcloud"] = {
            "dtype": "float32", "shape": (recipe.n_object_points, 3), "names": None,
        }  # fmt: skip
    if recipe.has("ee_pose"):
        feats["observation.ee_pose"] = {
            "dtype": "float32", "shape": (len(EE_POSE_NAMES),), "names": list(EE_POSE_NAMES),
        }  # fmt: skip
    if recipe.has("environment_state"):
        feats["observation.environment_state"] = {"dtype": "float32", "shape": (ENV_STATE_DIM,), "names": list(ENV_STATE_NAMES)}
    feats.update(
        {
            "stage_index": {"dtype": "int64", "shape": (1,), "names": None},
            "stage": {"dtype": "string", "shape": (1,), "names": None},
            "strategy": {"dtype": "string", "shape": (1,), "names": None},
            "object_id": {"dtype": "string", "shape": (1,), "names": None},
            "success": {"dtype": "bool", "shape": (1,), "names": None},
            "failure_reason": {"dtype": "string", "shape": (1,), "names": None},
            "episode_seed": {"dtype": "int64", "shape": (1,), "names": None},
        }
    )
    return feats


def camera_meta(recipe: Recipe) -> dict:
    """Per camera: image size, pinhole intrinsics and camera-to-world extrinsics (fixed cameras)."""
    from flatlab_lerobot.collect.runner import make_env

    cams = list(dict.fromkeys([*recipe.cameras, *(recipe.pointcloud_cameras or ())]))
    if not cams:
        return {}
    env = make_env(recipe, recipe.objects[0])
    try:
        env.reset(seed=0)
        out = {}
        for cam in cams:
            fx, fy, cx, cy = env.rig.intrinsics(cam)
            pos, R = env.rig.extrinsics(env.sim.data, cam)
            T = np.eye(4)
            T[:3, :3], T[:3, 3] = R, pos
            out[cam] = {
                "width": recipe.image_size,
                "height": recipe.image_size,
                "fx": fx, "fy": fy, "cx": cx, "cy": cy,
                "K": [[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]],
                "cam_to_world": T.tolist(),
                "znear": float(env.rig.znear), "zfar": float(env.rig.zfar),
            }  # fmt: skip
        return out
    finally:
        env.close()


CAMERA_CONVENTION = (
    "OpenGL/MuJoCo camera frame: x right, y up, the camera looks along -z. Pixel (u=col, v=row, row 0 at "
    "the top) with metric depth z (metres along the optical axis; observation.depth.* decodes to mm by "
    "default) -> p_cam = ((u - cx) z / fx, -(v - cy) z / fy, -z); p_world = R p_cam + t with "
    "[R|t] = cam_to_world[:3]. Depth at or beyond 0.99*zfar means nothing was hit."
)


def episode_cameras(cameras: dict, record: dict | None) -> dict:
    """The ``meta/flatlab.json`` cameras as they were in one episode: a recipe with camera jitter
    records each episode's ``cam_to_world`` in its ``meta/flatlab_episodes.jsonl`` line
    (``domain.cam_to_world``), which replaces the nominal extrinsics."""
    moved = ((record or {}).get("domain") or {}).get("cam_to_world") or {}
    return {c: {**m, "cam_to_world": moved[c]} if c in moved else m for c, m in cameras.items()}


def depth_to_points(depth_m: np.ndarray, cam: dict) -> np.ndarray:
    """World points (K, 3) from an (H, W) depth map in metres and a ``meta/flatlab.json`` camera."""
    depth_m = np.asarray(depth_m, dtype=np.float64).squeeze()
    valid = (depth_m > 0) & (depth_m < 0.99 * cam["zfar"])
    v, u = np.nonzero(valid)
    z = depth_m[v, u]
    p = np.stack([(u - cam["cx"]) * z / cam["fx"], -(v - cam["cy"]) * z / cam["fy"], -z], axis=1)
    T = np.asarray(cam["cam_to_world"])
    return p @ T[:3, :3].T + T[:3, 3]


