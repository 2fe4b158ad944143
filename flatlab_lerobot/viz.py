"""``flatlab view``: a rerun recording of one dataset episode, with what ``lerobot-dataset-viz`` lacks.

``lerobot-dataset-viz`` logs the camera images, depth, state and action of a LeRobotDataset.  This
viewer adds, for a FlatLab collection (``flatlab collect``):

* the cameras posed in 3D (``rr.Pinhole`` + ``rr.Transform3D`` from ``meta/flatlab.json``), so the
  RGB and depth images appear in the 3D view;
* the scene and object point clouds (``observation.pointcloud`` / ``observation.object_pointcloud``),
  or, for a dataset with depth but no clouds, the scene cloud rebuilt from depth with the camera
  metadata (:func:`flatlab_lerobot.collect.features.depth_to_points`), coloured by the RGB image;
* both arms' TCP poses as axes and their growing trajectories (``observation.ee_pose``);
* the stage as a text log, stage index / gripper widths / joint state / action as scalars;
* the episode's strategy, object, seed, success and failure reason as a text document;
* the table top as a box.

Entity layout (stable, the tests read it back)::

    world/table                   Boxes3D (static)
    world/cameras/<cam>           Transform3D + Pinhole (static); .../rgb Image, .../depth DepthImage
    world/clouds/scene            Points3D (dataset cloud, or rebuilt from depth)
    world/clouds/object           Points3D
    world/clouds/depth            Points3D (only with --depth-cloud: rebuilt from depth next to the stored cloud)
    world/ee/<arm>                Transform3D + TransformAxes3D
    world/ee_trajectory/<arm>     LineStrips3D (the path up to the current frame)
    stage                         TextLog (one entry per stage change, one at the end: success / failure)
    scalars/...                   Scalars: stage_index, gripper_width/<arm>, state, action, success
    episode                       TextDocument (static, markdown)

Timelines: ``frame_index`` (sequence) and ``timestamp`` (duration, seconds).

``--save out.rrd`` writes the recording without any display (written to a temporary file, then
renamed).  Without ``--save`` the rerun viewer is spawned, which needs a display.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from contextlib import nullcontext
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from flatlab_lerobot.atomic import replacing

EXIT_USAGE = 2
ARM_COLORS = {"left": (40, 120, 255), "right": (255, 80, 40)}
SCENE_COLOR = (150, 150, 150)
OBJECT_COLOR = (255, 170, 0)
DEPTH_CLOUD_COLOR = (60, 200, 120)


class ViewError(ValueError):
    """Bad input (root, episode, output path): the message names the path or field."""


@dataclass
class EpisodeSource:
    """What ``flatlab view`` needs to know about the dataset before reading frames."""

    root: Path
    repo_id: str
    episode: int
    total_episodes: int
    features: dict
    flatlab_meta: dict | None
    record: dict | None  # this episode's line of meta/flatlab_episodes.jsonl
    rgb_cams: list[str] = field(default_factory=list)
    depth_cams: list[str] = field(default_factory=list)

    @property
    def cameras(self) -> dict:
        """Intrinsics/extrinsics per camera in this episode (jittered cameras: the episode's pose)."""
        from flatlab_lerobot.collect.features import episode_cameras

        return episode_cameras((self.flatlab_meta or {}).get("cameras") or {}, self.record)

    def has(self, key: str) -> bool:
        return key in self.features


# ---------------------------------------------------------------------------------- inputs
def inspect_dataset(root: Path, episode: int, repo_id: str | None = None) -> EpisodeSource:
    """Check ``root`` and ``episode`` (clear errors naming the path / field) and read the metadata."""
    root = Path(root)
    if not root.exists():
        raise ViewError(f"--root {root}: no such directory")
    if not root.is_dir():
        raise ViewError(f"--root {root}: not a directory")
    info_path = root / "meta" / "info.json"
    if not info_path.is_file():
        raise ViewError(f"--root {root}: not a LeRobotDataset (missing {info_path})")
    try:
        info = json.loads(info_path.read_text())
        total = int(info["total_episodes"])
        features = dict(info["features"])
    except (ValueError, KeyError, TypeError) as exc:
        raise ViewError(f"{info_path}: unreadable dataset info ({type(exc).__name__}: {exc})") from exc
    if total == 0:
        raise ViewError(f"--root {root}: the dataset has no episodes ({info_path}: total_episodes = 0)")
    if not 0 <= episode < total:
        raise ViewError(
            f"--episode {episode}: out of range; {root} has {total} episode{'s' if total != 1 else ''} "
            f"(valid: 0..{total - 1}, from {info_path}: total_episodes)"
        )
    meta = None
    meta_path = root / "meta" / "flatlab.json"
    if meta_path.is_file():
        try:
            meta = json.loads(meta_path.read_text())
        except ValueError as exc:
            raise ViewError(f"{meta_path}: not valid JSON ({exc})") from exc
    record = None
    eps_path = root / "meta" / "flatlab_episodes.jsonl"
    if eps_path.is_file():
        for n, line in enumerate(eps_path.read_text().splitlines(), 1):
            if not line.strip():
                continue
            try:
                r = json.loads(line)
            except ValueError as exc:
                raise ViewError(f"{eps_path}, line {n}: not valid JSON ({exc})") from exc
            if r.get("dataset_episode_index") == episode:
                record = r
                break
    if repo_id is None:
        repo_id = ((meta or {}).get("recipe") or {}).get("repo_id") or f"local/{root.name}"
    src = EpisodeSource(root, repo_id, episode, total, features, meta, record)
    src.rgb_cams = [k.split(".", 2)[2] for k in features if k.startswith("observation.images.")]
    src.depth_cams = [k.split(".", 2)[2] for k in features if k.startswith("observation.depth.")]
    return src


def load_episode(src: EpisodeSource):
    """The episode as a ``LeRobotDataset`` restricted to it (depth decoded in metres)."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    return LeRobotDataset(
        src.repo_id, root=src.root, episodes=[src.episode], video_backend="pyav", depth_output_unit="m"
    )


# ---------------------------------------------------------------------------------- geometry
def table_box(src: EpisodeSource, first_frame: dict | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(center, half_size) of the table top: the cell defaults, the height from the env state when logged."""
    from flatlab_lerobot.sim.scene import CellConfig

    cell = CellConfig()
    h = cell.table_height
    if first_frame is not None and "observation.environment_state" in first_frame:
        names = src.features["observation.environment_state"].get("names") or []
        if "table_height" in names:
            h = float(np.asarray(first_frame["observation.environment_state"])[names.index("table_height")])
    tx, ty = cell.table_size
    tt = cell.table_thickness
    return np.array([0.0, 0.0, h - tt / 2]), np.array([tx / 2, ty / 2, tt / 2])


def depth_cloud(depths: dict, cams: dict, rgbs: dict | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """World points (and RGB colours when images are given) from per-camera depth maps in metres."""
    from flatlab_lerobot.collect.features import depth_to_points

    pts, cols = [], []
    for cam, d in depths.items():
        if cam not in cams:
            continue
        d = np.asarray(d, np.float64).squeeze()
        pts.append(depth_to_points(d, cams[cam]))
        if rgbs is not None and cam in rgbs:
            valid = (d > 0) & (d < 0.99 * cams[cam]["zfar"])  # same mask and order as depth_to_points
            cols.append(np.asarray(rgbs[cam])[valid])
    if not pts:
        return np.zeros((0, 3)), None
    colours = np.concatenate(cols) if cols and len(cols) == len(pts) else None
    return np.concatenate(pts), colours


def _nonzero_points(p) -> np.ndarray:
    p = np.asarray(p, np.float32).reshape(-1, 3)
    return p[np.any(p != 0, axis=1)]  # the env pads an empty cloud with zeros


def _hwc_uint8(chw) -> np.ndarray:
    a = np.asarray(chw)
    if a.dtype != np.uint8:
        a = (np.clip(a, 0.0, 1.0) * 255 + 0.5).astype(np.uint8)
    return np.ascontiguousarray(np.moveaxis(a, 0, -1))


def _scalar(v):
    a = np.asarray(v)
    return a.reshape(-1)[0].item() if a.size else None


def _fmt_placement(p) -> str:
    if not isinstance(p, dict):
        return str(p) if p is not None else "-"
    return ", ".join(f"{k} = {v:.4g}" if isinstance(v, (int, float)) else f"{k} = {v}" for k, v in p.items())


def _names(src: EpisodeSource, key: str) -> list[str]:
    f = src.features.get(key) or {}
    names, dim = f.get("names"), int((f.get("shape") or [0])[-1])
    if isinstance(names, list) and len(names) == dim:
        return [str(n) for n in names]
    return [f"{key}_{i}" for i in range(dim)]


# ---------------------------------------------------------------------------------- recording
def episode_markdown(src: EpisodeSource, first: dict, n_frames: int, logged: int, cloud_note: str) -> str:
    rec = src.record or {}
    success = bool(_scalar(first["success"])) if "success" in first else rec.get("success")
    reason = first.get("failure_reason", rec.get("failure_reason")) or ""
    rows = [
        ("dataset", f"`{src.root}` (`{src.repo_id}`)"),
        ("episode", f"{src.episode} of {src.total_episodes}"),
        ("task", first.get("task", "")),
        ("strategy", first.get("strategy", rec.get("strategy", "?"))),
        ("object", first.get("object_id", rec.get("object_id", "?"))),
        ("seed", _scalar(first["episode_seed"]) if "episode_seed" in first else rec.get("seed", "?")),
        ("placement", _fmt_placement(rec.get("placement"))),
        ("success", "**yes**" if success else "**no**" if success is not None else "?"),
        ("failure reason", reason or "-"),
        ("frames", f"{n_frames}" + (f" (first {logged} logged)" if logged < n_frames else "")),
        ("stages", " → ".join(rec.get("stages") or []) or "-"),
        ("scene cloud", cloud_note),
    ]
    recipe = ((src.flatlab_meta or {}).get("recipe_source")) or "-"
    rows.append(("recipe", f"`{recipe}`"))
    body = "\n".join(f"| {k} | {v} |" for k, v in rows)
    return f"# FlatLab episode {src.episode}\n\n| | |\n|---|---|\n{body}\n"


def blueprint(src: EpisodeSource):
    import rerun.blueprint as rrb

    cams = list(dict.fromkeys([*src.rgb_cams, *src.depth_cams]))
    cam_views = [rrb.Spatial2DView(origin=f"world/cameras/{c}", name=c) for c in cams]
    side = [
        rrb.TextDocumentView(origin="episode", name="episode"),
        rrb.TextLogView(origin="stage", name="stages"),
        rrb.TimeSeriesView(origin="scalars", name="scalars"),
    ]
    left = rrb.Vertical(rrb.Spatial3DView(origin="world", name="3D"), *([rrb.Horizontal(*cam_views)] if cam_views else []),
                        row_shares=[3, 1] if cam_views else None)  # fmt: skip
    return rrb.Blueprint(rrb.Horizontal(left, rrb.Vertical(*side), column_shares=[3, 2]), collapse_panels=False)


def log_episode(rec, src: EpisodeSource, ds, *, max_frames: int | None = None, depth_cloud_too: bool = False) -> dict:
    """Log every frame of ``ds`` (the episode) to the recording stream ``rec``; returns counts."""
    import rerun as rr

    n = len(ds)
    if n == 0:
        raise ViewError(f"--episode {src.episode}: the episode has no frames in {src.root}")
    n_log = n if max_frames is None else max(1, min(n, max_frames))
    cams = src.cameras
    first = ds[0]

    rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    center, half = table_box(src, first)
    rec.log("world/table", rr.Boxes3D(centers=[center], half_sizes=[half], colors=[(158, 128, 97)],
                                      fill_mode="solid", labels=["table"]), static=True)  # fmt: skip
    for cam in dict.fromkeys([*src.rgb_cams, *src.depth_cams]):
        c = cams.get(cam)
        if c is None:
            continue
        T = np.asarray(c["cam_to_world"], np.float64)
        rec.log(f"world/cameras/{cam}", rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]), static=True)
        rec.log(
            f"world/cameras/{cam}",
            rr.Pinhole(image_from_camera=np.asarray(c["K"]), resolution=[c["width"], c["height"]],
                       camera_xyz=rr.ViewCoordinates.RUB, image_plane_distance=0.15),
            static=True,
        )  # fmt: skip

    has_scene = src.has("observation.pointcloud")
    has_obj = src.has("observation.object_pointcloud")
    rebuild = bool(src.depth_cams) and bool(cams) and (not has_scene or depth_cloud_too)
    if has_scene:
        cloud_note = "`observation.pointcloud`" + (" (+ rebuilt from depth: world/clouds/depth)" if rebuild else "")
    elif rebuild:
        cloud_note = f"rebuilt from depth ({', '.join(src.depth_cams)}) with meta/flatlab.json"
    else:
        cloud_note = "none (no point cloud and no depth with camera metadata)"
    rec.log("episode", rr.TextDocument(episode_markdown(src, first, n, n_log, cloud_note),
                                       media_type=rr.MediaType.MARKDOWN), static=True)  # fmt: skip

    has_ee = src.has("observation.ee_pose")
    arms = []
    if has_ee:
        ee_names = _names(src, "observation.ee_pose")
        arms = list(dict.fromkeys(n.rsplit("_", 1)[0] for n in ee_names))
        for arm in arms:
            rec.log(f"world/ee/{arm}", rr.TransformAxes3D(0.08), static=True)
    state_names = _names(src, "observation.state") if src.has("observation.state") else []
    grip_idx = {n[: -len("_gripper_width")]: i for i, n in enumerate(state_names) if n.endswith("_gripper_width")}
    if state_names:
        rec.log("scalars/state", rr.SeriesLines(names=state_names), static=True)
    if src.has("action"):
        rec.log("scalars/action", rr.SeriesLines(names=_names(src, "action")), static=True)

    trajectories: dict[str, list] = {a: [] for a in arms}
    counts = {"frames": n_log, "scene_points": 0, "object_points": 0, "depth_points": 0}
    last_stage = None
    for i in range(n_log):
        f = first if i == 0 else ds[i]
        rec.set_time("frame_index", sequence=int(_scalar(f["frame_index"])))
        rec.set_time("timestamp", duration=float(_scalar(f["timestamp"])))
        rgbs, depths = {}, {}
        for cam in src.rgb_cams:
            img = _hwc_uint8(f[f"observation.images.{cam}"])
            rgbs[cam] = img
            rec.log(f"world/cameras/{cam}/rgb", rr.Image(img))
        for cam in src.depth_cams:
            d = np.asarray(f[f"observation.depth.{cam}"], np.float32).squeeze()
            depths[cam] = d
            zfar = (cams.get(cam) or {}).get("zfar")
            rec.log(f"world/cameras/{cam}/depth",
                    rr.DepthImage(d, meter=1.0, colormap="viridis", depth_range=(0.0, zfar) if zfar else None))  # fmt: skip
        if has_scene:
            p = _nonzero_points(f["observation.pointcloud"])
            counts["scene_points"] += len(p)
            rec.log("world/clouds/scene", rr.Points3D(p, colors=[SCENE_COLOR], radii=0.004))
        if rebuild:
            p, colours = depth_cloud(depths, cams, rgbs if not has_scene else None)
            path = "world/clouds/depth" if has_scene else "world/clouds/scene"
            counts["depth_points"] += len(p)
            rec.log(path, rr.Points3D(p, colors=colours if colours is not None else [DEPTH_CLOUD_COLOR], radii=0.003))
        if has_obj:
            p = _nonzero_points(f["observation.object_pointcloud"])
            counts["object_points"] += len(p)
            rec.log("world/clouds/object", rr.Points3D(p, colors=[OBJECT_COLOR], radii=0.006))
        if has_ee:
            ee = np.asarray(f["observation.ee_pose"], np.float64).reshape(-1, 7)
            for arm, (x, y, z, qw, qx, qy, qz) in zip(arms, ee, strict=True):
                rec.log(
                    f"world/ee/{arm}",
                    rr.Transform3D(translation=[x, y, z], quaternion=rr.Quaternion(xyzw=[qx, qy, qz, qw])),
                )
                trajectories[arm].append((x, y, z))
                rec.log(f"world/ee_trajectory/{arm}",
                        rr.LineStrips3D([np.asarray(trajectories[arm])], colors=[ARM_COLORS.get(arm, (200, 200, 200))],
                                        radii=0.003))  # fmt: skip
        if "stage" in f:
            stage = str(f["stage"])
            si = int(_scalar(f["stage_index"])) if "stage_index" in f else None
            if stage != last_stage:
                rec.log("stage", rr.TextLog(f"[{si}] {stage}" if si is not None else stage, level="INFO"))
                last_stage = stage
            if si is not None:
                rec.log("scalars/stage_index", rr.Scalars(si))
        for arm, j in grip_idx.items():
            rec.log(f"scalars/gripper_width/{arm}", rr.Scalars(float(np.asarray(f["observation.state"])[j])))
        if state_names:
            rec.log("scalars/state", rr.Scalars(np.asarray(f["observation.state"], np.float64)))
        if "action" in f:
            rec.log("scalars/action", rr.Scalars(np.asarray(f["action"], np.float64)))
        if "success" in f:
            rec.log("scalars/success", rr.Scalars(float(bool(_scalar(f["success"])))))
    if "success" in first:
        ok = bool(_scalar(first["success"]))
        reason = str(first.get("failure_reason", "") or "")
        rec.log("stage", rr.TextLog("episode end: SUCCESS" if ok else f"episode end: FAILED ({reason or 'no reason'})",
                                    level="INFO" if ok else "WARN"))  # fmt: skip
    return counts


def _has_display() -> bool:
    if sys.platform in ("darwin", "win32"):
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def view(root: Path, episode: int, *, save: Path | None = None, spawn: bool = False, repo_id: str | None = None,
         max_frames: int | None = None, depth_cloud_too: bool = False) -> dict:  # fmt: skip
    """Log one episode to a rerun recording: saved to ``save`` (no display needed) and/or a spawned viewer."""
    import rerun as rr

    if max_frames is not None and max_frames < 1:
        raise ViewError(f"--max-frames {max_frames}: must be >= 1")
    if save is None and not spawn:
        raise ViewError("nothing to do: pass --save out.rrd and/or --spawn")
    src = inspect_dataset(root, episode, repo_id)
    save = Path(save) if save is not None else None
    if save is not None:
        if save.is_dir():
            raise ViewError(f"--save {save}: is a directory; give a file name such as {save / 'episode.rrd'}")
        save.parent.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    ds = load_episode(src)
    rec = rr.RecordingStream(f"flatlab/{src.repo_id}/episode_{episode}")
    bp = blueprint(src)
    with replacing(save) if save is not None else nullcontext() as tmp:
        if spawn and tmp is not None:
            rec.spawn(connect=False)
            rec.set_sinks(rr.GrpcSink(), rr.FileSink(tmp), default_blueprint=bp)
        elif tmp is not None:
            rec.save(tmp, default_blueprint=bp)
        else:
            rec.spawn(default_blueprint=bp)
        counts = log_episode(rec, src, ds, max_frames=max_frames, depth_cloud_too=depth_cloud_too)
        rec.flush(timeout_sec=60.0 if spawn else 1e38)  # a viewer that died must not hang us
        rec.disconnect()
        if tmp is not None:
            if not tmp.is_file() or tmp.stat().st_size == 0:
                raise RuntimeError(f"rerun wrote nothing to {tmp}")
    counts.update(wall_s=round(time.perf_counter() - t0, 2), episode=episode, root=str(src.root),
                  rrd=str(save) if save else None, rrd_bytes=save.stat().st_size if save else None)  # fmt: skip
    return counts


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="flatlab view",
        description="Rerun recording of one episode of a FlatLab LeRobotDataset: camera images posed in 3D, "
        "point clouds, end-effector poses and trajectories, stages, success (what lerobot-dataset-viz lacks).",
    )
    ap.add_argument("--root", type=Path, required=True, help="the dataset folder (e.g. outputs/datasets/tiny_rigid)")
    ap.add_argument("--repo-id", default=None, help="repo id to load it under (default: from meta/flatlab.json)")
    ap.add_argument("--episode", type=int, default=0, help="episode index (default 0)")
    ap.add_argument(
        "--save", type=Path, default=None, help="write an .rrd file (no display needed); open it with `rerun FILE`"
    )
    ap.add_argument(
        "--spawn", action="store_true", help="spawn the rerun viewer (the default when --save is not given)"
    )
    ap.add_argument("--max-frames", type=int, default=None, help="log only the first K frames")
    ap.add_argument("--depth-cloud", action="store_true",
                    help="also rebuild the scene cloud from depth (world/clouds/depth) when the dataset stores clouds")  # fmt: skip
    return ap


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    spawn = args.spawn or args.save is None
    if spawn and not _has_display():
        print(
            "flatlab view: no display (DISPLAY/WAYLAND_DISPLAY unset), so no viewer can be spawned.\n"
            f"  Save a recording instead (without --spawn):  flatlab view --root {args.root} --episode {args.episode} --save episode.rrd\n"
            "  then open it where there is a display:  rerun episode.rrd",
            file=sys.stderr,
        )
        return EXIT_USAGE
    try:
        out = view(args.root, args.episode, save=args.save, spawn=spawn, repo_id=args.repo_id,
                   max_frames=args.max_frames, depth_cloud_too=args.depth_cloud)  # fmt: skip
    except ViewError as exc:
        print(f"flatlab view: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    what = f"wrote {out['rrd']} ({out['rrd_bytes'] / 1e6:.2f} MB)" if out["rrd"] else "sent to the viewer"
    print(f"[view] episode {out['episode']} of {out['root']}: {out['frames']} frames {what} in {out['wall_s']:.1f} s")
    if out["rrd"]:
        print(f"[view] open it with: rerun {out['rrd']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
