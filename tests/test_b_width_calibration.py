"""scripts/b_width_calibration.py: its slabs are reference objects in a copy of envs/, never benchmark objects."""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parents[1] / "scripts"))

import b_width_calibration  # noqa: E402

from flatlab_lerobot.catalog import benchmark_objects, load_objects  # noqa: E402


def test_slabs_load_as_reference_objects_outside_every_split(tmp_path):
    envs = tmp_path / "envs"
    b_width_calibration.write_envs(envs)
    objects = load_objects(envs / "objects")
    slabs = b_width_calibration.slabs()
    assert set(slabs) <= set(objects)
    for oid, size in slabs.items():
        assert objects[oid].split == "reference" and tuple(objects[oid].size) == size and objects[oid].material == "rigid"
    assert not set(slabs) & {o.id for o in benchmark_objects(directory=envs / "objects")}
    assert min(min(s[:2]) for s in slabs.values()) < 0.08 < 0.1 < max(min(s[:2]) for s in slabs.values())
