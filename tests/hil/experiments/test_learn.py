"""The learning experiment end to end, through the whole stack in lockstep."""

from __future__ import annotations

import json

import numpy as np
import pytest

from hil.cli import main
from hil.experiments.learn import LearnConfig, run_learning

TRIAL_KEYS = {"index", "success", "reflexes", "footfalls_m", "burst_s", "gated_decisions"}


@pytest.mark.slow
def test_a_short_run_learns_and_the_frozen_baseline_does_not():
    learned = run_learning(LearnConfig(trials=40, seed=3))
    frozen = run_learning(LearnConfig(trials=40, seed=3, learning=False))
    s_learned = learned["summary"]["success_21_40"]
    s_frozen = frozen["summary"]["success_21_40"]
    assert s_learned >= 0.8, learned["summary"]
    assert s_frozen <= 0.6, frozen["summary"]
    # the learner changed its strides because of reflexes, the baseline never did
    assert sum(t["gated_decisions"] for t in learned["trials"][20:]) > 20
    assert all(t["gated_decisions"] == 0 for t in frozen["trials"])
    kinds = {r["kind"] for t in learned["trials"] for r in t["reflexes"]}
    assert kinds == {"extension", "placement"}


def _without_wall_clock(metrics: dict) -> str:
    m = json.loads(json.dumps(metrics))
    for key in ("wall_s", "trials_per_minute"):
        m["summary"].pop(key)
    return json.dumps(m, sort_keys=True)


def test_same_seed_same_metrics_and_another_seed_differs():
    a = run_learning(LearnConfig(trials=3, seed=11))
    b = run_learning(LearnConfig(trials=3, seed=11))
    c = run_learning(LearnConfig(trials=3, seed=12))
    assert _without_wall_clock(a) == _without_wall_clock(b)
    assert _without_wall_clock(a) != _without_wall_clock(c)


def test_learn_command_writes_metrics_and_weights(tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["learn", "--trials", "2", "--seed", "1", "--out", str(out), "--quiet",
                 "--obstacle-height-m", "0.07", "--range-noise-m", "0.01"]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["config"]["obstacle_height_m"] == 0.07 and metrics["config"]["range_noise_m"] == 0.01
    assert [t["index"] for t in metrics["trials"]] == [0, 1]
    for trial in metrics["trials"]:
        assert TRIAL_KEYS <= trial.keys()
        assert all(r["kind"] in ("extension", "placement") for r in trial["reflexes"])
        assert all(x < 0 for x in trial["footfalls_m"]) and len(trial["footfalls_m"]) >= 4
    assert {"wall_s", "sim_s"} <= metrics["summary"].keys()
    with np.load(out / "weights.npz", allow_pickle=False) as data:
        assert data["weights"].shape == (28,) and float(data["cell_width_m"]) == 0.04
    assert "wrote" in capsys.readouterr().out
    assert main(["learn", "--trials", "2", "--seed", "1", "--out", str(out), "--quiet", "--obstacle-height-m", "0.07",
                 "--range-noise-m", "0.01"]) == 0  # the same command again: finished, nothing runs
    assert "already holds this finished run" in capsys.readouterr().out


@pytest.mark.parametrize("argv,code,match", [
    (["--obstacle-height-m", "0.02"], 2, "obstacle_height_m"),  # a condition out of its range: argparse's
    (["--trials", "0"], 2, "argument --trials"),  # a malformed option: usage, argparse names it
    (["--seed", "-5"], 2, "argument --seed"),
])
def test_bad_learn_arguments_get_a_clear_error(tmp_path, capsys, argv, code, match):
    try:
        got = main(["learn", "--out", str(tmp_path / "x"), "--quiet", *argv])
    except SystemExit as exc:  # argparse's usage error
        got = exc.code
    assert got == code
    err = capsys.readouterr().err
    assert match in err and "Traceback" not in err
    assert not (tmp_path / "x").exists()  # refused before anything was written


def test_analyze_reads_learn_folders_and_refuses_others(tmp_path, capsys):
    out = tmp_path / "run"
    run_learning(LearnConfig(trials=2, seed=2), out_dir=out)
    assert main(["analyze", str(out), "--json", str(tmp_path / "a.json")]) == 0
    figures = json.loads((tmp_path / "a.json").read_text())
    assert figures["runs"][0]["trials"] == 2 and len(figures["footfall_std_m_by_steps_before"]) == 4
    assert main(["analyze", str(tmp_path / "nothing")]) == 3
    assert "no metrics.json" in capsys.readouterr().err
