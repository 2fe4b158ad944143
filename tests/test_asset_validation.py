"""The asset validation report: grounded labels, category bars, the wrong-strategy pattern.

The analysis is tested on synthetic trial records (the runs themselves are ``flatlab eval``
runs, tested in test_protocol.py); one end-to-end run on two objects checks the plumbing."""

import json
import subprocess
import sys

import pytest

from flatlab_lerobot.evaluation.asset_validation import analyse, grounded_label, markdown, read_runs
from flatlab_lerobot.catalog import get_object


def test_grounded_label_rules():
    assert grounded_label("A", {"A": 0.8, "B": 0.2, "C": 0.0}) == "A"
    assert grounded_label("A", {"A": 0.2, "B": 0.8, "C": 0.0}) == "B"  # B works better: relabelled
    assert grounded_label("B", {"A": 0.6, "B": 0.6, "C": 0.0}) == "B"  # a tie keeps the catalog label
    assert grounded_label("C", {"A": 0.0, "B": 0.0, "C": 0.0}) == "C"  # nothing works: keep the label
    assert grounded_label("A", {"A": None, "B": None, "C": None}) == "A"
    assert grounded_label("A", {"A": 0.6, "B": 0.8, "C": 0.0}) == "A"  # one trial better: within the margin
    assert grounded_label("C", {"A": 1.0, "B": 0.0, "C": 0.6}) == "A"  # two trials better: relabelled


def _write(d, strategy, results):
    d.mkdir(parents=True)
    with open(d / "results.jsonl", "w") as f:
        for obj, gs in results.items():
            for t, g in enumerate(gs):
                f.write(json.dumps({"object_id": obj, "trial": t, "strategy": strategy, "G": g, "wall_s": 1.0}) + "\n")
        f.write('{"object_id": "half-writ')  # a crash mid-line is ignored


def test_analysis_and_markdown(tmp_path):
    book, box = "book_paperback_novel", "box_shoe"
    _write(tmp_path / "A", "A", {book: [1, 1, 1, 1, 0], box: [0, 0, 0, 0, 0]})
    _write(tmp_path / "B", "B", {book: [0, 0, 1, 0, 0], box: [1, 1, 1, 1, 1]})
    _write(tmp_path / "C", "C", {book: [0] * 5, box: [0] * 5})
    runs = read_runs({s: tmp_path / s for s in "ABC"})
    res = analyse(runs, [get_object(book), get_object(box)])
    rows = {r["object_id"]: r for r in res["rows"]}
    assert rows[book]["successes"] == {"A": 4, "B": 1, "C": 0} and rows[book]["grounded"] == "A"
    assert rows[box]["grounded"] == "B"
    assert res["categories"]["Book"]["labelled"] == [4, 5]  # 80 %: below the bar
    assert res["categories"]["Box"]["labelled"] == [5, 5]
    assert res["pattern"]["A on boxes"] == (0.0, 5)
    md = markdown(res, {"date": "x", "objects": 2, "trials": 5, "seed": 0, "workers": 1, "wall_s": {"A": 60.0}})
    assert "| Book | 1 | A | 4/5 | 80% | **no** |" in md
    assert "| Box | 1 | B | 5/5 | 100% | yes |" in md
    assert "0 of 2 objects have a grounded label other than their current catalog label" in md
    assert "0 objects have a grounded label other than the thin" in md


def test_wrong_strategy_in_a_run_is_an_error(tmp_path):
    _write(tmp_path / "A", "B", {"box_shoe": [1]})
    with pytest.raises(ValueError, match="results.jsonl:1: field strategy"):
        read_runs({"A": tmp_path / "A"})


@pytest.mark.slow
def test_report_end_to_end(tmp_path):
    """The real CLI: three forced-strategy eval runs on the reference book, then the report."""
    out = tmp_path / "v"
    cmd = [sys.executable, "-m", "flatlab_lerobot.cli", "assets", "report", "--objects", "ref_book", "--trials", "1",
           "--workers", "1", "--out", str(out)]  # fmt: skip
    subprocess.run(cmd, check=True, timeout=600)
    md = (out / "report.md").read_text()
    rep = json.loads((out / "report.json").read_text())
    (row,) = rep["rows"]
    assert row["object_id"] == "ref_book" and row["trials"] == {"A": 1, "B": 1, "C": 1}
    assert row["successes"]["C"] == 0  # folding a rigid book does not lift it
    runs = {s: [json.loads(x) for x in (out / f"strategy_{s}" / "results.jsonl").read_text().splitlines()] for s in "ABC"}
    assert {s: r[0]["strategy"] for s, r in runs.items()} == {"A": "A", "B": "B", "C": "C"}
    assert {s: int(r[0]["G"]) for s, r in runs.items()} == row["successes"]
    assert (out / "timing.json").exists()
    assert "## Wrong-strategy matrix" in md and "ref_book" in md


def test_apply_labels_edits_only_the_label_lines(tmp_path):
    """--apply-labels: the grounded label goes into the object's YAML with the evidence, the paper's
    label is kept as paper_strategy, comments and other objects stay; relabelling back removes it."""
    import shutil

    from flatlab_lerobot import catalog
    from flatlab_lerobot.evaluation import asset_validation as V

    src = catalog.get_object("disk_cork_coaster").source
    path = tmp_path / "disk.yaml"
    shutil.copy(src, path)
    original = path.read_text()
    row = {"object_id": "disk_cork_coaster", "label": "A", "paper": "A", "grounded": "C", "source": str(path),
           "successes": {"A": 0, "B": 0, "C": 3}, "trials": {"A": 5, "B": 5, "C": 5}}  # fmt: skip
    assert V.apply_labels([row], "test run") == ["disk_cork_coaster"]
    objs = catalog.load_objects(tmp_path)
    cork = objs["disk_cork_coaster"]
    assert (cork.strategy, cork.paper_strategy) == ("C", "A")
    assert "strategy: C  # grounded: A 0/5, B 0/5, C 3/5 (test run)" in path.read_text()
    assert all(o.strategy == "A" and not o.relabelled for o in objs.values() if o.id != "disk_cork_coaster")
    assert path.read_text().splitlines()[0] == original.splitlines()[0]  # the header comment stays
    back = {**row, "label": "C", "grounded": "A"}
    assert V.apply_labels([back], "test run") == ["disk_cork_coaster"]
    assert path.read_text() == original
