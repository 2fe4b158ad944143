"""Crash-safe single-file writes (flatlab_lerobot.atomic): a failed write leaves the old file and no
temporary file; a written file has the permissions of any new file (a dataset card is for reading)."""

import json
import os

import pytest

from flatlab_lerobot.atomic import replacing, write_json, write_text


def test_write_text_and_json_replace_the_file_with_normal_permissions(tmp_path):
    old = os.umask(0o022)
    try:
        write_text(tmp_path / "sub" / "card.md", "# card\n")  # the folder is created
        write_json(tmp_path / "r.json", {"a": 1})
    finally:
        os.umask(old)
    assert (tmp_path / "sub" / "card.md").read_text() == "# card\n"
    assert (tmp_path / "sub" / "card.md").stat().st_mode & 0o777 == 0o644
    assert json.loads((tmp_path / "r.json").read_text()) == {"a": 1}
    write_text(tmp_path / "r.json", "{}")
    assert (tmp_path / "r.json").read_text() == "{}"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.json", "sub"]


def test_a_failed_write_keeps_the_old_file_and_leaves_no_temporary_file(tmp_path):
    path = tmp_path / "results.json"
    path.write_text("old")
    with pytest.raises(RuntimeError):
        with replacing(path) as tmp:
            assert tmp.parent == tmp_path and tmp.suffix == ".json" and tmp.name.startswith(".")
            tmp.write_text("half of a new fi")
            raise RuntimeError("killed mid-write")
    assert path.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["results.json"]


def test_two_writers_of_one_target_get_their_own_temporary_files(tmp_path):
    with replacing(tmp_path / "x.txt") as a, replacing(tmp_path / "x.txt") as b:
        assert a != b
        a.write_text("a")
        b.write_text("b")
    assert (tmp_path / "x.txt").read_text() == "a"  # the outer block ends last: its replace wins
