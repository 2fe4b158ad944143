"""``flatlab view`` (rerun recording with clouds, EE poses, stages, success) and ``lerobot-dataset-viz``
on FlatLab datasets: both write non-empty .rrd files without a display.

One module fixture collects two tiny datasets (32 px, 1 episode each): ``t`` with every modality,
``d`` with depth but no point clouds (the viewer rebuilds the cloud from depth)."""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from test_collect import write_recipe

from flatlab_lerobot.collect.collector import collect
from flatlab_lerobot.collect.recipe import load_recipe

BIN = Path(sys.executable).parent
N_FRAMES = 12


def _env(**extra):
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    env.setdefault("MUJOCO_GL", "egl")
    env["RERUN"] = "on"
    return {**env, **extra}


def read_rrd(path: Path) -> dict[str, dict]:
    """Per entity path: number of temporal rows and the static rows' record dicts (rerun's RRD reader)."""
    from rerun.experimental import RrdReader

    out: dict[str, dict] = {}
    for chunk in RrdReader(path).store().stream():
        e = out.setdefault(chunk.entity_path, {"rows": 0, "static": []})
        if chunk.is_static:
            e["static"].extend(chunk.to_record_batch().to_pylist())
        else:
            e["rows"] += chunk.num_rows
    return out


@pytest.fixture(scope="module")
def datasets(tmp_path_factory):
    d = tmp_path_factory.mktemp("view")
    full = load_recipe(write_recipe(d / "t.yaml", episodes=1, max_steps=N_FRAMES))
    depth_only = load_recipe(
        write_recipe(
            d / "d.yaml",
            name="d",
            repo_id="local/flatlab_d",
            episodes=1,
            max_steps=N_FRAMES,
            cameras=["front"],
            modalities=["rgb", "depth", "ee_pose"],
        )
    )
    collect(full, d / "out", progress=False, log=lambda *_: None)
    collect(depth_only, d / "out", progress=False, log=lambda *_: None)
    return d, d / "out" / "t", d / "out" / "d"


@pytest.mark.slow
def test_flatlab_view_cli_saves_rrd_with_clouds_ee_stages(datasets):
    d, root, _ = datasets
    rrd = d / "rrd" / "t_ep0.rrd"
    p = subprocess.run(
        [str(BIN / "flatlab"), "view", "--root", str(root), "--episode", "0", "--save", str(rrd)],
        check=False, capture_output=True, text=True, env=_env(), timeout=300,
    )  # fmt: skip
    assert p.returncode == 0, p.stderr[-3000:]
    assert rrd.is_file() and rrd.stat().st_size > 10_000
    assert [f.name for f in rrd.parent.iterdir()] == [rrd.name]  # no temporary file left behind
    ents = read_rrd(rrd)
    for path in ("/world/clouds/scene", "/world/clouds/object", "/world/ee/left", "/world/ee/right",
                 "/world/ee_trajectory/left", "/world/ee_trajectory/right", "/world/cameras/front/rgb",
                 "/world/cameras/top/depth", "/scalars/gripper_width/left", "/scalars/stage_index"):  # fmt: skip
        assert ents.get(path, {}).get("rows") == N_FRAMES, (path, ents.get(path))
    assert ents["/stage"]["rows"] >= 2  # at least the first stage and the end-of-episode line
    for path in ("/world/table", "/world/cameras/front", "/world/cameras/top"):
        assert ents[path]["static"], path
    pinhole = [r for r in ents["/world/cameras/front"]["static"] if any(k.startswith("Pinhole:") for k in r)]
    assert pinhole, ents["/world/cameras/front"]["static"]
    doc = ents["/episode"]["static"][0]["TextDocument:text"][0]
    assert "| strategy | B |" in doc and "| object | ref_box |" in doc and "| success |" in doc
    assert "failure reason" in doc


@pytest.mark.slow
def test_lerobot_dataset_viz_saves_rrd(datasets):
    d, root, _ = datasets
    out = d / "lerobot_viz"
    p = subprocess.run(
        [str(BIN / "lerobot-dataset-viz"), "--repo-id", "local/flatlab_t", "--root", str(root), "--episode-index", "0",
         "--save", "1", "--output-dir", str(out), "--num-workers", "0"],
        check=False, capture_output=True, text=True, env=_env(), timeout=300,
    )  # fmt: skip
    assert p.returncode == 0, p.stderr[-3000:]
    files = list(out.glob("*.rrd"))
    assert len(files) == 1 and files[0].stat().st_size > 10_000, files
    ents = read_rrd(files[0])
    assert ents["/observation.images.front"]["rows"] == N_FRAMES
    assert "/world/clouds/scene" not in ents  # what lerobot's viewer lacks, and `flatlab view` adds


def test_view_rebuilds_cloud_from_depth(datasets):
    """A dataset with depth and no stored cloud: the scene cloud comes from depth + meta/flatlab.json, and
    (on the full dataset) the rebuilt cloud lies on the stored one."""
    from flatlab_lerobot import viz

    d, full, depth_only = datasets
    out = viz.view(depth_only, 0, save=d / "d.rrd", max_frames=3)
    assert out["frames"] == 3 and out["depth_points"] > 3 * 500 and out["scene_points"] == 0
    ents = read_rrd(d / "d.rrd")
    assert ents["/world/clouds/scene"]["rows"] == 3 and "/world/clouds/object" not in ents
    assert ents["/world/ee_trajectory/right"]["rows"] == 3
    doc = ents["/episode"]["static"][0]["TextDocument:text"][0]
    assert "rebuilt from depth" in doc

    src = viz.inspect_dataset(full, 0)
    f = viz.load_episode(src)[0]
    depths = {c: np.asarray(f[f"observation.depth.{c}"]).squeeze() for c in src.depth_cams}
    rebuilt, _ = viz.depth_cloud(depths, src.cameras)
    stored = np.asarray(f["observation.pointcloud"])
    dist = np.min(np.linalg.norm(stored[:, None, :] - rebuilt[None, :, :], axis=2), axis=1)
    assert np.median(dist) < 0.005, np.median(dist)  # depth is 12-bit log-quantized: mm, not µm


def test_bad_episode_and_root_exit_2(datasets, tmp_path, capsys):
    _, root, _ = datasets
    p = subprocess.run(
        [str(BIN / "flatlab"), "view", "--root", str(root), "--episode", "5", "--save", str(tmp_path / "x.rrd")],
        check=False, capture_output=True, text=True, env=_env(), timeout=120,
    )  # fmt: skip
    assert p.returncode == 2, p.stderr
    assert "--episode 5" in p.stderr and "out of range" in p.stderr and "valid: 0..0" in p.stderr
    assert str(root / "meta" / "info.json") in p.stderr
    assert not (tmp_path / "x.rrd").exists()

    from flatlab_lerobot.viz import main

    missing = tmp_path / "no_such_dataset"
    assert main(["--root", str(missing), "--save", str(tmp_path / "y.rrd")]) == 2
    assert f"--root {missing}: no such directory" in capsys.readouterr().err
    not_ds = tmp_path / "empty"
    not_ds.mkdir()
    assert main(["--root", str(not_ds), "--save", str(tmp_path / "y.rrd")]) == 2
    assert f"not a LeRobotDataset (missing {not_ds / 'meta' / 'info.json'})" in capsys.readouterr().err
    assert main(["--root", str(root), "--episode", "-1", "--save", str(tmp_path / "y.rrd")]) == 2
    assert "--episode -1: out of range" in capsys.readouterr().err
    assert not list(tmp_path.glob("*.rrd"))


def test_no_display_without_save_explains_save(datasets, monkeypatch, capsys):
    from flatlab_lerobot.viz import main

    _, root, _ = datasets
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setattr(sys, "platform", "linux")
    assert main(["--root", str(root), "--episode", "0"]) == 2
    err = capsys.readouterr().err
    assert "no display" in err and "--save" in err and "rerun " in err
    assert main(["--root", str(root), "--spawn", "--save", "x.rrd"]) == 2  # --spawn needs a display too
    assert "no display" in capsys.readouterr().err and not Path("x.rrd").exists()
