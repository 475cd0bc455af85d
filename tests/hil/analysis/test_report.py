"""Reading a sweep folder: stamped files and those of before stamps; anything else refused in one line."""

from __future__ import annotations

import json

import pytest

from controller.errors import InputError, stamp
from hil.analysis.report import load_sweep, read_summary_rows, write_report
from hil.cli import main
from hil.experiments.conditions import Conditions
from hil.experiments.sweep import Cell, conditions_json, read_sweep_config, summary_row

CONFIG = {"methods": ["paper"], "obstacle_heights_m": [0.08], "mixed_heights": False, "seeds": [0, 1], "trials": 12}


def _sweep(tmp_path, stamped: bool):
    out = tmp_path / ("new" if stamped else "old")
    rows = []
    for seed in (0, 1):
        cell = Cell("paper", 0.08, seed, 12)
        success = [False] * (2 + seed) + [True] * (10 - seed)
        cell.folder(out).mkdir(parents=True)
        metrics = {"config": {"method": "paper"}, "trials": [{"success": s} for s in success], "summary": {}}
        (cell.folder(out) / "metrics.json").write_text(json.dumps(
            {**stamp("learn-metrics", 1), **metrics} if stamped else metrics))
        rows.append(summary_row(cell, success))
    (out / "config.json").write_text(json.dumps({**stamp("sweep-config", 1), **CONFIG} if stamped else CONFIG))
    (out / "summary.json").write_text(json.dumps({**stamp("sweep-summary", 1), "rows": rows} if stamped else rows))
    return out, rows


def test_a_stamped_sweep_and_one_of_before_stamps_read_and_report_the_same(tmp_path):
    new, rows = _sweep(tmp_path, stamped=True)
    old, _ = _sweep(tmp_path, stamped=False)
    # the stamp is not part of the configuration; a config.json without conditions has the defaults'
    assert load_sweep(new) == load_sweep(old) == ({**CONFIG, "conditions": conditions_json(Conditions())}, rows)
    a, b = write_report(new), write_report(old)
    assert a["table"] == b["table"] and a["curves"] == b["curves"] and not a["missing"]
    assert (new / "report.md").read_text().replace(str(new), "X") == (old / "report.md").read_text().replace(
        str(old), "X")


@pytest.mark.parametrize("name,data,words", [
    ("summary.json", {**stamp("sweep-summary", 3), "rows": []}, "sweep-summary format version 3"),
    ("summary.json", {**stamp("learn-metrics", 1), "rows": []}, "a 'learn-metrics' file, not a sweep-summary file"),
    ("summary.json", {**stamp("sweep-summary", 1), "rows": {"a": 1}}, "'rows' is not a list"),
    ("summary.json", [{"method": "paper"}], "row 0 is not a sweep summary row"),
    ("summary.json", {"rows": []}, "not a sweep-summary file (no 'format' stamp)"),
    ("config.json", {**stamp("sweep-config", 2), **CONFIG}, "sweep-config format version 2"),
    ("config.json", {"methods": ["paper"]}, "not a sweep configuration ('obstacle_heights_m'"),
    ("config.json", {**CONFIG, "seeds": 3}, "must be lists"),
    ("config.json", [1], "not a sweep-config file"),
])
def test_a_sweep_file_of_an_unknown_version_or_structure_is_refused(tmp_path, capsys, name, data, words):
    out, _ = _sweep(tmp_path, stamped=True)
    (out / name).write_text(json.dumps(data))
    with pytest.raises(InputError) as err:
        load_sweep(out)
    assert str(out / name) in str(err.value) and words in str(err.value)
    assert main(["sweep", "--out", str(out), "--report-only"]) == 3
    msg = capsys.readouterr().err
    assert words in msg and "Traceback" not in msg


def test_a_cell_whose_metrics_are_of_an_unknown_version_is_refused(tmp_path):
    out, rows = _sweep(tmp_path, stamped=True)
    path = out / "cells" / rows[1]["cell"] / "metrics.json"
    path.write_text(json.dumps({**stamp("learn-metrics", 9), "trials": []}))
    with pytest.raises(InputError, match="learn-metrics format version 9"):
        write_report(out)


def test_damaged_json_is_an_input_error_and_a_missing_file_is_not_found(tmp_path):
    (tmp_path / "summary.json").write_text("[{")
    with pytest.raises(InputError, match="summary.json: not valid JSON"):
        read_summary_rows(tmp_path / "summary.json")
    with pytest.raises(FileNotFoundError, match="is .* a sweep folder"):
        read_sweep_config(tmp_path / "config.json")
