"""The ``flatlab assets`` subcommands: ``list``, ``validate`` and ``contact-sheet``.

* :func:`list_objects` -- one line per catalog object (id, category, split, family, size, strategy).
* :func:`validate` -- load objects, materials and scenes, check the paper's per-category counts and
  compile every object in the cell; returns a list of problems (empty = all good).
* :func:`contact_sheet` -- render every object alone on a small plain table (oblique view) into
  one labelled PNG grid, with MuJoCo's offscreen renderer (``MUJOCO_GL=egl`` on headless machines).
"""

from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])

from pathlib import Path

import numpy as np

from flatlab_lerobot.assets import object_xml
from flatlab_lerobot.catalog import (
    BENCHMARK_SPLITS,
    CatalogError,
    ObjectSpec,
    check_counts,
    load_objects,
    load_scenes,
)

PREVIEW_TABLE_HEIGHT = 0.1


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
        load_scenes()
    except CatalogError as exc:
        problems.append(str(exc))
    if compile_models:
        import mujoco

        from flatlab_lerobot.sim.scene import CellConfig, build_model

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
    dist = 1.25 * span + 0.05
    cam = np.array([0.55 * dist, -0.2 * dist, h + 0.95 * dist])
    from flatlab_lerobot.sim.scene import look_at_xyaxes

    xy = " ".join(f"{v:.6g}" for v in look_at_xyaxes(cam, (0, 0, h)))
    if obj.deformable:
        option = '<option timestep="0.004" integrator="discrete" solver="Newton" tolerance="1e-6" cone="elliptic"/>'
    else:
        option = '<option timestep="0.002" integrator="implicitfast" cone="elliptic" impratio="10"/>'
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
    from PIL import Image, ImageDraw, ImageFont

    if objects is None:
        order = {s: i for i, s in enumerate((*BENCHMARK_SPLITS, "reference"))}
        objects = [o for o in load_objects().values() if include_reference or o.split != "reference"]
        objects.sort(key=lambda o: (order[o.split], o.category, o.id))
    rows = (len(objects) + cols - 1) // cols
    label_h = 30
    sheet = Image.new("RGB", (cols * tile, rows * (tile + label_h)), (255, 255, 255))
    draw = ImageDraw.Draw(sheet)
    try:
        font = ImageFont.load_default(size=11)
    except TypeError:  # Pillow < 10.1
        font = ImageFont.load_default()
    colours = {"train": (30, 110, 30), "test_alpha": (20, 70, 170), "test_beta": (170, 60, 20), "reference": (90, 90, 90)}
    for k, o in enumerate(objects):
        img = Image.fromarray(render_object(o, tile, settle_steps=50 if o.deformable else 0))
        x, y = (k % cols) * tile, (k // cols) * (tile + label_h)
        sheet.paste(img, (x, y))
        draw.text((x + 3, y + tile + 1), o.id[:32], fill=(0, 0, 0), font=font)
        draw.text((x + 3, y + tile + 14), f"{o.category} | {o.split} | {o.strategy}", fill=colours[o.split], font=font)
    out = Path(out_png)
    out.parent.mkdir(parents=True, exist_ok=True)
    sheet.save(out)
    return out


def main(argv: list[str] | None = None) -> int:
    """Stand-alone entry point: ``python -m flatlab_lerobot.assets_cli {list,validate,contact-sheet}``."""
    import argparse

    p = argparse.ArgumentParser(prog="flatlab assets")
    sub = p.add_subparsers(dest="cmd", required=True)
    pl = sub.add_parser("list", help="list the catalog objects")
    pl.add_argument("--split")
    pl.add_argument("--category")
    pv = sub.add_parser("validate", help="validate envs/ and compile every object")
    pv.add_argument("--no-compile", action="store_true")
    pc = sub.add_parser("contact-sheet", help="render all objects into one PNG")
    pc.add_argument("out", nargs="?", default="outputs/contact_sheet.png")
    pc.add_argument("--cols", type=int, default=10)
    pc.add_argument("--tile", type=int, default=200)
    a = p.parse_args(argv)
    if a.cmd == "list":
        print("\n".join(list_objects(a.split, a.category)))
        return 0
    if a.cmd == "validate":
        problems = validate(compile_models=not a.no_compile)
        print("\n".join(problems) if problems else "ok: catalog, materials and scenes are valid")
        return 1 if problems else 0
    print(contact_sheet(a.out, cols=a.cols, tile=a.tile))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
