"""``compare``: identical records are told apart from a single changed field, wall-clock figures aside."""

from __future__ import annotations

import copy
import json

import pytest

from controller.errors import InputError, stamp
from hil.analysis.records import compare, first_difference, read
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
    assert main(["compare", str(tmp_path / "a"), str(tmp_path / "bad.json")]) == 3
    err = capsys.readouterr().err
    assert "not valid JSON" in err and "Traceback" not in err


def test_stamps_are_not_records_so_a_stamped_run_equals_one_of_before_stamps(tmp_path):
    old = _run(0.1)
    new = {**stamp("learn-metrics", 1), **_run(0.1)}
    new["project_version"] = "9.9.9"
    assert compare(old, new)["same"] is True
    walk = {"steps": 3, "t_s": [0.0, 0.5]}
    assert compare(walk, {**stamp("walk", 1), **walk})["same"] is True
    assert compare(walk, {**walk, "steps": 4})["first_difference"] == ".steps: 3 vs 4"


def test_nan_is_the_same_record_and_the_sign_of_zero_is_not():
    a = _run(0.1)
    a["trials"][1]["gated_range_m"] = [float("nan"), 1.0]
    b = copy.deepcopy(a)
    assert compare(a, b)["same"] is True
    b["trials"][1]["gated_range_m"][1] = 1  # an int is not the float 1.0 that was written
    assert compare(a, b)["differing_trials"] == [1]
    assert first_difference(0.0, -0.0, "x") == "x: 0.0 vs -0.0"


@pytest.mark.parametrize("data,words", [
    ({**stamp("learn-metrics", 5), **_run(0.1)}, "learn-metrics format version 5"),
    ({"config": {}, "trials": "all of them", "summary": {}}, "'trials' is a str"),
    ([1, 2], "not a learn-metrics file"),
])
def test_a_learn_folder_of_an_unknown_version_or_structure_is_refused(tmp_path, capsys, data, words):
    (tmp_path / "a").mkdir()
    (tmp_path / "a" / "metrics.json").write_text(json.dumps(data))
    with pytest.raises(InputError, match="metrics.json"):
        read(tmp_path / "a")
    assert main(["compare", str(tmp_path / "a"), str(tmp_path / "a")]) == 3
    err = capsys.readouterr().err
    assert words in err and "Traceback" not in err


def test_a_json_file_with_trials_that_are_not_a_list_is_refused(tmp_path):
    (tmp_path / "x.json").write_text(json.dumps({"trials": 3}))
    with pytest.raises(InputError, match="x.json: 'trials' is a int"):
        read(tmp_path / "x.json")


def test_a_field_only_the_newer_run_records_is_an_addition_not_a_difference(tmp_path, capsys):
    old, new = _run(0.1), _run(0.1)
    for t in new["trials"]:
        t["rail_speed_m_s"] = 0.5  # a field a later version added to every trial
    new["summary"]["missed_contacts"] = 0
    result = compare(old, new)
    assert result["same"] is True and result["added_fields"] == [".trials[*].rail_speed_m_s", ".summary.missed_contacts"]
    assert compare(new, old)["same"] is False  # the newer run lost a field: a difference
    assert compare(new, old)["first_difference"] == ".trials[0].rail_speed_m_s: only in the first"
    new["trials"][1]["sim_s"] = 6.0  # an existing field that changed is still a difference
    assert compare(old, new)["differing_trials"] == [1]
    assert compare({"a": 1}, {"a": 1, "b": 2}) == {"kind": "json", "same": True, "first_difference": None,
                                                     "added_fields": [".b"]}
    (tmp_path / "old.json").write_text(json.dumps(_run(0.1)))
    newer = _run(0.1)
    newer["trials"][0]["extra"] = 1
    (tmp_path / "new.json").write_text(json.dumps(newer))
    assert main(["compare", str(tmp_path / "old.json"), str(tmp_path / "new.json"), "--json", "-"]) == 0
    assert json.loads(capsys.readouterr().out)["added_fields"] == [".trials[*].extra"]
