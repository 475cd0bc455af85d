"""R5: the burst's excess after the crossing read off a trace; the paper learner run both ways;
the command's refusals."""

from __future__ import annotations

import numpy as np
import pytest

from hil.experiments import relaxation


def _trace(relax: bool):
    t = np.arange(0.0, 4.0, 0.01)
    x = -1.0 + 0.5 * t  # the foot passes the near edge at t = 2 s
    base = 0.3
    burst = np.full_like(t, base)
    held = (t >= 1.5) & ((t < 2.2) | relax)
    burst[held] = base + 0.1 * np.exp(-(t[held] - 1.5))
    return {"t_s": t.tolist(), "foot_x_m": x.tolist(), "burst_s": burst.tolist()}


def test_the_excess_is_read_at_the_times_after_the_foot_passes_the_near_edge():
    on = relaxation.excess_after_crossing(_trace(True), 0.3, (0.0, 1.0, 3.0))
    assert on[0] == pytest.approx(0.1 * np.exp(-0.5), abs=2e-3) and on[1] == pytest.approx(0.1 * np.exp(-1.5), abs=2e-3)
    assert on[2] is None  # past the trace's end
    off = relaxation.excess_after_crossing(_trace(False), 0.3, (0.0, 1.0))
    assert off[0] > 0.05 and off[1] == 0.0
    never = {"t_s": [0.0, 1.0], "foot_x_m": [-1.0, -0.5], "burst_s": [0.3, 0.3]}
    assert relaxation.excess_after_crossing(never, 0.3) == [None] * len(relaxation.AFTER_S)


def test_the_summary_separates_the_variants_and_the_table_names_them():
    runs = [{"seed": s, "relax": r, "success": 0.9, "success_last50": 1.0, "base_burst_s": 0.3, "trace": _trace(r)}
            for s in (1, 2) for r in (False, True)]
    summary = relaxation.summarize(runs)
    on, off = summary["variants"]["relax"], summary["variants"]["default"]
    assert on["seeds"] == off["seeds"] == [1, 2]
    assert on["mean_excess_after_crossing_s"][2] > 0.01 and off["mean_excess_after_crossing_s"][2] == 0.0
    table = relaxation.markdown(summary)
    assert "| relax |" in table and "| default |" in table


def test_a_run_sets_the_option_on_the_paper_learner_and_traces_the_last_trial(monkeypatch):
    import hil.experiments.learn as learn

    seen = []

    def fake_run_learning(config):
        seen.append(config)
        trials = [{"success": i % 2 == 0} for i in range(config.trials)]
        trials[-1]["trace"] = _trace(config.controller.learner.relax_out_of_view)
        return {"trials": trials}

    monkeypatch.setattr(learn, "run_learning", fake_run_learning)
    on, off = relaxation.run_one(1000, 4, True), relaxation.run_one(1000, 4, False)
    assert [c.controller.learner.relax_out_of_view for c in seen] == [True, False]
    assert all(c.method == "paper" and c.trace_trials == (-1,) and c.seed == 1000 for c in seen)
    assert on["success"] == off["success"] == 0.5 and on["trace"] != off["trace"]


def test_bad_options_are_one_line_and_exit_2(tmp_path, capsys):
    assert relaxation.main(["--seeds", "5-1", "--out", str(tmp_path)]) == 2
    assert relaxation.main(["--trials", "0", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and all(line.startswith("relaxation: ") for line in err)
