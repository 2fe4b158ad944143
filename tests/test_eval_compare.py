"""`flatlab eval-compare`: two flatlab eval runs paired trial by trial."""

import json
import math

import pytest

from flatlab_lerobot.cli import main as cli_main
from flatlab_lerobot.evaluation.compare import CompareError, compare, main, sign_test_p

ENV = {"task": "grasp", "image_size": 128, "n_points": 4096}


def _run(folder, policy, outcomes, seed=1000, env=ENV, strategy="B", partial_tail=False):
    """A fake `flatlab eval --out` folder: outcomes[(object, trial)] = G."""
    folder.mkdir(parents=True)
    (folder / "run.json").write_text(json.dumps({"policy": policy, "seed": seed, "env": env, "policy_args": []}))
    lines = []
    for (obj, t), g in outcomes.items():
        split = "test_beta" if obj.startswith("towel") else "train"
        lines.append(json.dumps({"policy": policy, "object_id": obj, "trial": t, "seed": seed + t, "split": split,
                                 "label": "C" if split == "test_beta" else "B", "strategy": strategy, "G": g}))  # fmt: skip
    text = "\n".join(lines) + "\n"
    if partial_tail:
        text += '{"policy": "x", "object_'
    (folder / "results.jsonl").write_text(text)
    return folder


def test_sign_test_matches_the_binomial_and_is_symmetric():
    assert sign_test_p(0, 0) == 1.0
    assert sign_test_p(5, 5) == 1.0
    assert sign_test_p(0, 6) == pytest.approx(2 / 64)
    assert sign_test_p(11, 20) == sign_test_p(20, 11)
    assert sign_test_p(11, 20) == pytest.approx(2 * sum(math.comb(31, i) for i in range(12)) / 2**31)
    assert 0.14 < sign_test_p(11, 20) < 0.16  # the stop-32 executor checkpoint-mean experiment


def test_pairs_counted_per_split_and_objects_ranked(tmp_path):
    a = {("box", 0): True, ("box", 1): True, ("book", 0): False, ("book", 1): True, ("towel", 0): False}
    b = {("box", 0): True, ("box", 1): False, ("book", 0): True, ("book", 1): True, ("towel", 0): True,
         ("towel", 1): True}  # fmt: skip
    res = compare(*_as_trials(a, b))
    p = res["paired"]
    assert (p["trials"], p["G_a"], p["G_b"], p["both"], p["only_a"], p["only_b"], p["neither"]) == (5, 3, 4, 2, 1, 2, 0)
    assert res["per_split"]["train"]["trials"] == 4 and res["per_split"]["test_beta"]["only_b"] == 1
    assert res["only_in_b"] == 1 and res["only_in_a"] == 0
    assert res["objects_b_minus_a"] == {"book": 1, "towel": 1, "box": -1}


def _as_trials(a, b):
    def conv(d):
        return {k: {"G": g, "split": "test_beta" if k[0] == "towel" else "train", "label": "B", "strategy": "B"}
                for k, g in d.items()}  # fmt: skip

    return conv(a), conv(b)


def test_cli_on_two_folders_writes_json_and_ignores_a_half_written_line(tmp_path, capsys):
    ra = _run(tmp_path / "a", "pa", {("box", 0): False, ("box", 1): False, ("towel", 0): True}, partial_tail=True)
    rb = _run(tmp_path / "b", "pb", {("box", 0): True, ("box", 1): True, ("towel", 0): True}, strategy="C")
    out = tmp_path / "cmp.json"
    assert cli_main(["eval-compare", str(ra), str(rb), "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "| all | 3 | 1 (33.3 %) | 3 (100.0 %) | 1 | 0 | 2 | 0 | 0.500 |" in text
    res = json.loads(out.read_text())
    assert res["policy_a"] == "pa" and res["same_strategy"] == 0
    assert res["label_to_chosen_lifted"]["b"] == {"B->C": "2/2", "C->C": "1/1"}


def test_refuses_runs_with_other_seed_or_env_flags_naming_them(tmp_path):
    ra = _run(tmp_path / "a", "pa", {("box", 0): True})
    rb = _run(tmp_path / "b", "pb", {("box", 0): True}, seed=2000, env={**ENV, "image_size": 64})
    with pytest.raises(CompareError, match=r"seed, env\.image_size"):
        main([str(ra), str(rb)])
    assert main([str(ra), str(rb), "--allow-different-settings"]) == 0


def test_clear_errors_for_a_missing_folder_and_a_corrupt_line(tmp_path):
    ra = _run(tmp_path / "a", "pa", {("box", 0): True})
    with pytest.raises(CompareError, match="RUN_B .*nowhere: no results.jsonl"):
        main([str(ra), str(tmp_path / "nowhere")])
    bad = _run(tmp_path / "bad", "pb", {("box", 0): True, ("box", 1): True})
    lines = (bad / "results.jsonl").read_text().splitlines()
    (bad / "results.jsonl").write_text("not json\n" + "\n".join(lines) + "\n")
    with pytest.raises(CompareError, match="results.jsonl: line 1 is not a trial record"):
        main([str(ra), str(bad)])
    other = _run(tmp_path / "other", "pc", {("book", 0): True})
    with pytest.raises(CompareError, match="share no"):
        main([str(ra), str(other)])
