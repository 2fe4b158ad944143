"""The ``flatlab assets`` subcommands: ``list``, ``validate`` and ``contact-sheet``.

* :func:`list_objects` -- one line per catalog object (id, category, split, family, size, strategy).
* :func:`validate` -- load objects, materials and scenes, check the paper's per-category counts and
  compile every object in the cell; returns a list of problems (empty = all good).
* :func:`contact_sheet` -- render every object alone on a small plain table (oblique view) into
  one labelled PNG grid, with MuJoCo's offscreen renderer (``MUJOCO_GL=egl`` on headless machines).
* :func:`scene_sheet` -- render every scene of ``envs/scenes`` (full cell: room dressing, table,
  arms at home, a reference object on the table) from an oblique overview camera into one
  labelled PNG grid.
"""

from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])

import sys
from pathlib import Path

import numpy as np

from flatlab_lerobot.assets import object_xml
from flatlab_lerobot.atomic import replacing
from flatlab_lerobot.catalog import (
    BENCHMARK_SPLITS,
    CatalogError,
    ObjectSpec,
    check_counts,
    load_objects,
    load_scenes,
)

PREVIEW_TABLE_HEIGHT = 0.1


def _label_font(size: int):
    """Pillow's default font at ``size`` (older Pillow: the fixed-size bitmap font)."""
    from PIL import ImageFont

    try:
        return ImageFont.load_default(size=size)
    except TypeError:  # Pillow < 10.1
        return ImageFont.load_default()


def list_objects(split: str | None = None, category: str | None = None) -> list[str]:
    """One formatted line per object (optionally filtered), header first."""
    objs = [o for o in load_objects().values()
            if (split is None or o.split == split) and (category is None or o.category == category)]
    lines = [f"{'id':28s} {'category':13s} {'split':10s} {'family':13s} {'size (m)':22s} {'mass':>6s} strategy"]
    for o in objs:
        size = "x".join(f"{s:.3f}" for s in o.size)
        lines.append(f"{o.id:28s} {o.category:13s} {o.split:10s} {o.shape:13s} {size:22s} {o.mass:6.3f} {o.strategy}")
    return lines


def validate(compile_models: bool = True) -> list[str]:
    """Every problem found in ``envs/`` (catalog errors, count mismatches, compile failures)."""
    problems: list[str] = []
    try:
        objects = load_objects()
    except CatalogError as exc:
        return [str(exc)]
    problems += check_counts(objects)
    try:
        scenes = load_scenes()
    except CatalogError as exc:
        problems.append(str(exc))
        scenes = {}
    if compile_models:
        import mujoco

        from flatlab_lerobot.catalog import REFERENCE_OBJECTS
        from flatlab_lerobot.sim.scene import CellConfig, build_model

        for sid in scenes:
            try:
                m = build_model(CellConfig.from_scene(sid), objects[REFERENCE_OBJECTS["B"]])
                d = mujoco.MjData(m)
                mujoco.mj_step(m, d)
                warn = [i for i, w in enumerate(d.warning) if w.number]
                if warn:
                    problems.append(f"scene '{sid}': MuJoCo warnings {warn} after one step")
            except Exception as exc:  # noqa: BLE001
                problems.append(f"scene '{sid}': does not compile: {exc}")

        for o in objects.values():
            try:
                m = build_model(CellConfig(), o)
                d = mujoco.MjData(m)
                mujoco.mj_step(m, d)
                warn = [i for i, w in enumerate(d.warning) if w.number]
                if warn:
                    problems.append(f"object '{o.id}': MuJoCo warnings {warn} after one step")
            except Exception as exc:  # noqa: BLE001 - report every object, not only the first
                problems.append(f"object '{o.id}': does not compile: {exc}")
    return problems


def preview_xml(obj: ObjectSpec, table_size=(3.0, 3.0), table_rgba=(0.82, 0.8, 0.76, 1.0)) -> str:
    """A tiny model: ``obj`` alone on a plain table top at height 0.1 m, with one oblique camera."""
    h = PREVIEW_TABLE_HEIGHT
    span = max(obj.size[0], obj.size[1], 0.12)
    dist = 1.6 * span + 0.05  # the whole object in frame, also a long diagonal
    cam = np.array([0.55 * dist, -0.2 * dist, h + 0.95 * dist])
    from flatlab_lerobot.sim.scene import CLOTH_TIMESTEP, RIGID_TIMESTEP, look_at_xyaxes

    xy = " ".join(f"{v:.6g}" for v in look_at_xyaxes(cam, (0, 0, h)))
    if obj.deformable:
        option = f'<option timestep="{CLOTH_TIMESTEP}" integrator="discrete" solver="Newton" tolerance="1e-6" cone="elliptic"/>'
    else:
        option = f'<option timestep="{RIGID_TIMESTEP}" integrator="implicitfast" cone="elliptic" impratio="10"/>'
    tx, ty = table_size
    return f"""
<mujoco model="preview_{obj.id}">
  {option}
  <visual><quality offsamples="4" shadowsize="0"/><global offwidth="640" offheight="640"/>
    <headlight ambient="0.5 0.5 0.5" diffuse="0.45 0.45 0.45" specular="0.05 0.05 0.05"/></visual>
  <worldbody>
    <light pos="0.3 -0.3 1.5" dir="-0.2 0.2 -1" diffuse="0.35 0.35 0.35" castshadow="false"/>
    <geom name="table_top" type="box" size="{tx / 2} {ty / 2} 0.02" pos="0 0 {h - 0.02}" rgba="{' '.join(map(str, table_rgba))}"
          contype="1" conaffinity="2" friction="0.4 0.005 0.0001" condim="4"/>
    <camera name="view" pos="{cam[0]:.6g} {cam[1]:.6g} {cam[2]:.6g}" xyaxes="{xy}" fovy="45"/>
{object_xml(obj, h)}
  </worldbody>
</mujoco>"""


def render_object(obj: ObjectSpec, size: int = 256, settle_steps: int = 0):
    """An RGB image (size x size x 3, uint8) of ``obj`` on the preview table."""
    import mujoco

    m = mujoco.MjModel.from_xml_string(preview_xml(obj))
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    for _ in range(settle_steps):
        mujoco.mj_step(m, d)
    r = mujoco.Renderer(m, size, size)
    try:
        r.update_scene(d, camera="view")
        return r.render().copy()
    finally:
        r.close()


def contact_sheet(out_png: str | Path, cols: int = 10, tile: int = 200, include_reference: bool = False,
                  objects: list[ObjectSpec] | None = None) -> Path:
    """Render every catalog object into one labelled grid PNG; returns its path."""
    from PIL import Image, ImageDraw

    if objects is None:
        order = {s: i for i, s in enumerate((*BENCHMARK_SPLITS, "reference"))}
        objects = [o for o in load_objects().values() if include_reference or o.split != "reference"]
        objects.sort(key=lambda o: (order[o.split], o.category, o.id))
    rows = (len(objects) + cols - 1) // cols
    label_h = 30
    sheet = Image.new("RGB", (cols * tile, rows * (tile + label_h)), (255, 255, 255))
    draw = ImageDraw.Draw(sheet)
    font = _label_font(11)
    colours = {"train": (30, 110, 30), "test_alpha": (20, 70, 170), "test_beta": (170, 60, 20), "reference": (90, 90, 90)}
    for k, o in enumerate(objects):
        img = Image.fromarray(render_object(o, tile, settle_steps=50 if o.deformable else 0))
        x, y = (k % cols) * tile, (k // cols) * (tile + label_h)
        sheet.paste(img, (x, y))
        draw.text((x + 3, y + tile + 1), o.id[:32], fill=(0, 0, 0), font=font)
        draw.text((x + 3, y + tile + 14), f"{o.category} | {o.split} | {o.strategy}", fill=colours[o.split], font=font)
    return _save_png(sheet, out_png)


def _save_png(img, out_png: str | Path) -> Path:
    """Write ``img`` (PIL) to ``out_png`` crash-safely."""
    out = Path(out_png)
    with replacing(out) as tmp:
        img.save(tmp, format="PNG")
    return out


# Oblique overview of a whole cell for the scene sheet: from the front-right corner, high up, so the
# back wall, the left side wall, the props, the table and both arms are in view.
OVERVIEW_POS = (2.2, -1.3, 2.1)
OVERVIEW_TARGET = (-0.6, 0.05, 0.72)
OVERVIEW_FOVY = 56.0


def overview_camera(pos=OVERVIEW_POS, target=OVERVIEW_TARGET):
    """A free ``mujoco.MjvCamera`` at ``pos`` looking at ``target`` (no camera is added to the model)."""
    import mujoco

    f = np.asarray(target, float) - np.asarray(pos, float)
    dist = float(np.linalg.norm(f))
    cam = mujoco.MjvCamera()
    cam.type = mujoco.mjtCamera.mjCAMERA_FREE
    cam.lookat[:] = target
    cam.distance = dist
    cam.azimuth = float(np.degrees(np.arctan2(f[1], f[0])))
    cam.elevation = float(np.degrees(np.arcsin(f[2] / dist)))
    return cam


def render_scene(scene_id: str, object_id: str | None = None, width: int = 480, height: int = 360,
                 camera=None, supersample: int = 2):
    """RGB image (height x width x 3, uint8) of scene ``scene_id`` with ``object_id`` (default: the
    strategy-B reference box) on the table and both arms at home, seen by ``camera`` (a camera name
    of the cell, or default the overview camera).  Rendered ``supersample`` times larger, then
    downsampled (anti-aliasing)."""
    import mujoco
    from PIL import Image

    from flatlab_lerobot.catalog import REFERENCE_OBJECTS, get_object
    from flatlab_lerobot.sim.core import FlatLabSim
    from flatlab_lerobot.sim.scene import CellConfig

    sim = FlatLabSim(get_object(object_id or REFERENCE_OBJECTS["B"]), CellConfig.from_scene(scene_id))
    sim.reset()
    m = sim.model
    fovy = m.vis.global_.fovy
    m.vis.global_.fovy = OVERVIEW_FOVY
    r = mujoco.Renderer(m, height * supersample, width * supersample)
    try:
        r.update_scene(sim.data, camera=camera if camera is not None else overview_camera())
        img = r.render().copy()
    finally:
        r.close()
        m.vis.global_.fovy = fovy
    if supersample > 1:
        img = np.asarray(Image.fromarray(img).resize((width, height), Image.LANCZOS))
    return img


def scene_sheet(out_png: str | Path, cols: int = 6, tile: tuple[int, int] = (360, 270), object_id: str | None = None,
                scene_ids: list[str] | None = None) -> Path:
    """Render every scene (or ``scene_ids``) into one labelled grid PNG (scene id; room, table
    material and edge profile; table size and height); returns its path."""
    from PIL import Image, ImageDraw

    from flatlab_lerobot.catalog import ROOMS, load_materials

    scenes = load_scenes()
    mats = load_materials()
    ids = scene_ids or sorted(scenes, key=lambda s: (ROOMS.index(scenes[s].room), s))
    for sid in ids:
        if sid not in scenes:
            raise KeyError(f"unknown scene id {sid!r}; known: {sorted(scenes)}")
    tw, th = tile
    label_h = 34
    rows = (len(ids) + cols - 1) // cols
    sheet = Image.new("RGB", (cols * tw, rows * (th + label_h)), (255, 255, 255))
    draw = ImageDraw.Draw(sheet)
    font = _label_font(12)
    for k, sid in enumerate(ids):
        s = scenes[sid]
        x, y = (k % cols) * tw, (k // cols) * (th + label_h)
        sheet.paste(Image.fromarray(render_scene(sid, object_id, tw, th)), (x, y))
        draw.text((x + 4, y + th + 2), f"{sid}  ({s.room})", fill=(0, 0, 0), font=font)
        draw.text((x + 4, y + th + 17),
                  f"{mats[s.material].name} | {s.edge} edge | {s.table_size[0]:g}x{s.table_size[1]:g} m, h {s.table_height:g} m",
                  fill=(60, 60, 140), font=font)
    return _save_png(sheet, out_png)


def main(argv: list[str] | None = None) -> int:
    """Stand-alone entry point: ``python -m flatlab_lerobot.assets_cli {list,validate,contact-sheet,scene-sheet}``."""
    import argparse

    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["report"]:  # the validation report has its own parser (flatlab assets report --help)
        from flatlab_lerobot.evaluation.asset_validation import main as report_main

        return report_main(argv[1:])
    p = argparse.ArgumentParser(prog="flatlab assets")
    sub = p.add_subparsers(dest="cmd", required=True)
    sub.add_parser("report", help="run every strategy on every object and write the validation report (see --help)")
    pl = sub.add_parser("list", help="list the catalog objects")
    pl.add_argument("--split")
    pl.add_argument("--category")
    pv = sub.add_parser("validate", help="validate envs/ and compile every object")
    pv.add_argument("--no-compile", action="store_true")
    pc = sub.add_parser("contact-sheet", help="render all objects into one PNG")
    pc.add_argument("out", nargs="?", default="outputs/contact_sheet.png")
    pc.add_argument("--cols", type=int, default=10)
    pc.add_argument("--tile", type=int, default=200)
    ps = sub.add_parser("scene-sheet", help="render all scenes (room, table, arms, a reference object) into one PNG")
    ps.add_argument("--out", default="outputs/scene_sheet.png")
    ps.add_argument("--cols", type=int, default=6)
    ps.add_argument("--tile", default="360x270", help="tile size WxH in pixels")
    ps.add_argument("--object", default=None, help="object on the table (default: ref_box)")
    ps.add_argument("--scenes", default=None, help="comma-separated scene ids (default: all)")
    a = p.parse_args(argv)
    if a.cmd == "list":
        print("\n".join(list_objects(a.split, a.category)))
        return 0
    if a.cmd == "validate":
        problems = validate(compile_models=not a.no_compile)
        print("\n".join(problems) if problems else "ok: catalog, materials and scenes are valid")
        return 1 if problems else 0
    if a.cmd == "scene-sheet":
        try:
            tw, th = (int(v) for v in a.tile.lower().split("x"))
        except ValueError:
            p.error(f"--tile must look like 360x270, got {a.tile!r}")
        ids = [s.strip() for s in a.scenes.split(",")] if a.scenes else None
        print(scene_sheet(a.out, cols=a.cols, tile=(tw, th), object_id=a.object, scene_ids=ids))
        return 0
    print(contact_sheet(a.out, cols=a.cols, tile=a.tile))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
