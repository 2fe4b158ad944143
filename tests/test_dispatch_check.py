"""``scripts/dispatch_check.py``: bad input stops before any training, naming the flag (the trainings themselves
take minutes; the check was run by hand: docs/results/cpu_dispatch_xeon.json, its ``check``)."""

import json

import pytest


def test_a_set_that_is_not_there_is_named(script, tmp_path):
    mod = script("dispatch_check")
    with pytest.raises(SystemExit, match=r"--sets: .*strategy_export_orig is not a learning set"):
        mod.main(["--sets", str(tmp_path), "--out", str(tmp_path / "o")])


def test_a_compare_record_is_checked_before_training(script, tmp_path):
    mod = script("dispatch_check")
    rec = tmp_path / "r.json"
    rec.write_text(json.dumps({"what": "no check"}))
    with pytest.raises(SystemExit, match='--compare: .* has no "check" entry'):
        mod.main(["--sets", str(tmp_path), "--compare", str(rec)])
    rec.write_text(json.dumps({"check": {"steps": 50}}))
    with pytest.raises(SystemExit, match="made with --steps 50, not 200"):
        mod.main(["--sets", str(tmp_path), "--compare", str(rec)])


def test_an_unknown_setting_is_named_before_training(script, tmp_path, capsys):
    mod = script("dispatch_check")
    with pytest.raises(SystemExit):
        mod.main(["--sets", str(tmp_path), "--settings", "default,avx3"])
    assert "--settings: unknown ['avx3']" in capsys.readouterr().err


@pytest.mark.parametrize("record", ["cpu_dispatch_xeon.json", "cpu_dispatch_amd.json"])
def test_the_committed_checks_have_every_digest(script, record):
    mod = script("dispatch_check")
    from pathlib import Path

    check = json.loads((Path(__file__).resolve().parents[1] / "docs/results" / record).read_text())["check"]
    assert set(check["sets"]) == {ds for _, ds in mod.TRAININGS.values()}
    ran = {k.rsplit("_", 1)[1] for k in check["models"]}
    assert {"default", "avx2"} <= ran <= set(mod.SETTINGS)
    assert set(check["models"]) == {f"{n}_{s}" for n in mod.TRAININGS for s in ran}
    assert all(len(h) == 64 for h in [*check["sets"].values(), *check["models"].values()])
