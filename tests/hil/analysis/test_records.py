"""``compare``: identical records are told apart from a single changed field, wall-clock figures aside."""

from __future__ import annotations

import copy
import json

from hil.analysis.records import compare, read
from hil.cli import main


def _run(seed: float) -> dict:
    trials = [{"index": i, "success": i % 2 == 0, "footfalls_m": [seed + i, seed + 2 * i], "sim_s": 5.0,
               "trace": {"t_s": [0.0, 0.01]}} for i in range(4)]
    return {"config": {"seed": 0}, "trials": trials, "summary": {"success_rate": 0.5, "wall_s": 3.2}}


def test_the_same_records_with_other_wall_clock_figures_are_the_same():
    a, b = _run(0.1), _run(0.1)
    b["summary"]["wall_s"] = 9.9
    b["config"]["method"] = "paper"  # a new config field with its default is not a new behaviour
    assert compare(a, b)["same"] is True


def test_one_changed_number_deep_in_one_trial_is_found_and_named():
    a = _run(0.1)
    b = copy.deepcopy(a)
    b["trials"][2]["trace"]["t_s"][1] = 0.010000000000000002
    result = compare(a, b)
    assert result["same"] is False and result["differing_trials"] == [2]
    assert result["first_difference"] == ".trials[2].trace.t_s[1]: 0.01 vs 0.010000000000000002"
    assert compare(a, {**a, "trials": a["trials"][:3]})["same"] is False  # a trial missing


def test_the_verb_exits_0_same_1_different_2_unreadable(tmp_path, capsys):
    (tmp_path / "a").mkdir()
    (tmp_path / "a" / "metrics.json").write_text(json.dumps(_run(0.1)))
    (tmp_path / "b.json").write_text(json.dumps(_run(0.2)))
    (tmp_path / "bad.json").write_text("{not json")
    assert read(tmp_path / "a") == _run(0.1)
    assert main(["compare", str(tmp_path / "a"), str(tmp_path / "a" / "metrics.json")]) == 0
    assert main(["compare", str(tmp_path / "a"), str(tmp_path / "b.json")]) == 1
    assert "first difference: .trials[0].footfalls_m[0]: 0.1 vs 0.2" in capsys.readouterr().err
    assert main(["compare", str(tmp_path / "a"), str(tmp_path / "bad.json")]) == 2
    err = capsys.readouterr().err
    assert "not valid JSON" in err and "Traceback" not in err
