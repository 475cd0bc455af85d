"""The figures every report shares, defined once (hil.analysis.metrics), and reading a learn folder."""

from __future__ import annotations

import json

import pytest

from controller.errors import InputError, stamp
from hil.analysis.metrics import last_window, late_window, load_run, read_metrics, success_last, window_success

T, F = True, False


def test_success_last_is_over_the_last_n_trials_or_all_of_them_when_fewer():
    assert success_last([F] * 10 + [T] * 50) == 1.0
    assert success_last([F] * 10 + [T] * 49) == 49 / 50
    assert success_last([F, T, T, T]) == 0.75  # fewer than 50: all of them
    assert success_last([]) is None
    assert success_last([{"success": F}, {"success": T}], n=1) == 1.0  # trial dicts or booleans
    trials = [{"success": x} for x in [F] * 60 + [T] * 90]
    assert success_last(trials, 50) == window_success(trials, 101, 150)
    with pytest.raises(ValueError):
        success_last([T], n=0)


def test_the_late_windows():
    assert last_window(150) == (101, 150) and last_window(20) == (1, 20) and last_window(60, 10) == (51, 60)
    assert late_window(200) == (101, 150) and late_window(120) == (71, 120)


# ---- reading a learn folder: stamped, of before stamps, or refused -------------------------------------------

def _metrics(**top) -> dict:
    trials = [{"index": i, "success": i > 0, "footfalls_m": [-0.6, -0.3]} for i in range(3)]
    return {**top, "config": {"seed": 2, "learning": True}, "trials": trials, "summary": {"wall_s": 1.0, "sim_s": 9.0}}


def _folder(tmp_path, data, name="run"):
    folder = tmp_path / name
    folder.mkdir()
    (folder / "metrics.json").write_text(json.dumps(data))
    return folder


def test_a_stamped_folder_and_one_written_before_stamps_both_load(tmp_path):
    new = load_run(_folder(tmp_path, _metrics(**stamp("learn-metrics", 1)), "new"))
    old = load_run(_folder(tmp_path, _metrics(), "old"))
    assert new["trials"] == old["trials"] and new["format_version"] == 1 and "format" not in old


@pytest.mark.parametrize("data,words", [
    (_metrics(**stamp("learn-metrics", 2)), "learn-metrics format version 2"),
    (_metrics(**stamp("sweep-summary", 1)), "a 'sweep-summary' file, not a learn-metrics file"),
    ([], "not a learn-metrics file (a JSON object expected, got list)"),
    ({"config": {"seed": "zero"}, "trials": "many", "summary": 3}, "'trials' is a str, a list expected"),
    ({**_metrics(), "summary": []}, "'summary' is a list, an object expected"),
    ({**_metrics(), "trials": [{"index": 0, "success": 1}]}, "trial 0 is not a trial record"),
    ({**_metrics(), "trials": [{"index": 0, "success": True}]}, "trial 0 has no 'footfalls_m'"),
    ({**_metrics(), "config": {"seed": 1}}, "config has no 'learning'"),
])
def test_an_unknown_version_or_a_wrong_structure_is_an_input_error_naming_the_file(tmp_path, data, words):
    folder = _folder(tmp_path, data)
    with pytest.raises(InputError) as err:
        load_run(folder)
    assert str(folder / "metrics.json") in str(err.value) and words in str(err.value)


def test_weights_of_a_row_per_height_context_need_the_beams_that_bound_the_contexts(tmp_path):
    import numpy as np

    from controller.stepping.weights import save_weights

    folder = _folder(tmp_path, _metrics())
    save_weights(folder / "weights.npz", np.zeros((4, 3)), 0.04, generations=1)
    with pytest.raises(InputError, match="metrics.json: config has no 'controller.height.beam_heights_m'"):
        load_run(folder)
    with_beams = {**_metrics(), "config": {"seed": 2, "learning": True,
                                           "controller": {"height": {"beam_heights_m": [0.05, 0.09, 0.13]}}}}
    (folder / "metrics.json").write_text(json.dumps(with_beams))
    assert load_run(folder)["weights"].shape == (4, 3)
    save_weights(folder / "weights.npz", np.zeros(3), 0.04, generations=1)  # one row: no beams needed
    (folder / "metrics.json").write_text(json.dumps(_metrics()))
    assert load_run(folder)["weights"].shape == (3,)


def test_damaged_json_and_damaged_weights_are_input_errors(tmp_path):
    folder = _folder(tmp_path, _metrics())
    (folder / "weights.npz").write_bytes(b"PK\x03\x04 not a zip")
    with pytest.raises(InputError, match="weights.npz"):
        load_run(folder)
    (folder / "metrics.json").write_text('{"config": ')
    with pytest.raises(InputError, match="metrics.json: not valid JSON"):
        read_metrics(folder / "metrics.json")
    with pytest.raises(FileNotFoundError, match="no metrics.json"):
        load_run(tmp_path)
