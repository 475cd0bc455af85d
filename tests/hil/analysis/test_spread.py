"""R3's statistics: within-run s.d., seeded bootstrap intervals, a permutation test that finds a
planted trend and does not invent one, and the command's one-line refusals."""

from __future__ import annotations

import json

import numpy as np
import pytest

from hil.analysis import spread


def _trials(rng, sd_m_by_step, n=150):
    """Trials whose last four footfalls scatter with the given s.d. [m] (k = 1 first)."""
    return [{"success": True, "footfalls_m": [float(rng.normal(-0.2 * k, sd)) for k, sd in
                                              reversed(list(enumerate(sd_m_by_step, start=1)))]}
            for _ in range(n)]


def _groups(slope_sd_per_m, seeds=10, heights=(0.04, 0.06, 0.08, 0.10), seed=1):
    rng = np.random.default_rng(seed)
    return {h: [{"seed": s, "trials": _trials(rng, [0.05 + slope_sd_per_m * (h - 0.07), 0.07, 0.10, 0.10])}
                for s in range(seeds)] for h in heights}


def test_run_sd_by_step_takes_the_late_window_and_the_kth_last_footfall():
    trials = [{"footfalls_m": [-0.9, -0.5, x]} for x in (-0.1, -0.3)] + [{"footfalls_m": []}]
    sd = spread.run_sd_by_step(trials, 1, 3, steps=4)
    assert sd[0] == pytest.approx(0.1) and sd[1] == 0.0 and sd[2] == 0.0 and np.isnan(sd[3])
    assert np.isnan(spread.run_sd_by_step(trials, 2, 3)[0])  # one trial with a footfall: no s.d.


def test_a_planted_decrease_with_size_is_found_and_none_is_invented():
    found = spread.analyse(_groups(-0.3, seed=0), 101, 150, resamples=2000)
    last = found["size_trend"][0]
    assert last["steps_before"] == 1 and last["slope"] < -0.2 and last["p_decrease"] < 0.01
    # no trend planted: over 5 data sets x 4 steps, p < 0.05 about once by chance, never often
    flat = [t for s in range(5) for t in spread.analyse(_groups(0.0, seed=s), 101, 150, resamples=500)["size_trend"]]
    assert sum(t["p_two_sided"] < 0.05 for t in flat) <= 3 and all(abs(t["slope"]) < 0.2 for t in flat)


def test_the_intervals_are_seeded_bracket_the_mean_and_the_approach_narrows():
    groups = _groups(-0.3)
    a = spread.analyse(groups, 101, 150, seed=3, resamples=1000)
    assert a == spread.analyse(groups, 101, 150, seed=3, resamples=1000)
    row = a["by_height"]["0.04"]
    for m, (lo, hi) in zip(row["mean_sd_m"], row["ci95_m"]):
        assert lo <= m <= hi and hi - lo < 0.02
    assert row["mean_sd_m"][0] == pytest.approx(0.059, abs=0.003)
    n = a["approach_narrowing"]
    assert n["runs"] == 40 and n["runs_narrowing"] == 40 and n["mean_sd4_minus_sd1_m"] > 0.03


def test_a_single_height_is_refused():
    with pytest.raises(spread.InputError, match="2 heights"):
        spread.analyse({0.08: _groups(0.0)[0.08]}, 101, 150)


def _cell(root, seed, height, trials, method="paper", heights=None):
    folder = root / "cells" / f"{method}_h{height}_s{seed}"
    folder.mkdir(parents=True)
    config = {"method": method, "seed": seed, "learning": True, "obstacle_height_m": height,
              "obstacle_heights_m": heights}
    (folder / "metrics.json").write_text(json.dumps({"config": config, "trials": trials, "summary": {}}))


def test_the_command_writes_the_figure_and_refuses_bad_input_in_one_line(tmp_path, capsys):
    rng = np.random.default_rng(0)
    for h in (0.06, 0.10):
        for s in range(3):
            _cell(tmp_path / "sweep", s, h, _trials(rng, [0.05, 0.07, 0.1, 0.1], n=20))
    assert spread.main([str(tmp_path / "sweep"), "--out", str(tmp_path / "out"), "--first", "5", "--last", "20",
                        "--resamples", "200"]) == 0
    assert (tmp_path / "out" / "fig3_spread.png").stat().st_size > 1000
    saved = json.loads((tmp_path / "out" / "spread.json").read_text())
    assert saved["heights_m"] == [0.06, 0.1] and saved["runs"] == 6
    assert "| 0.06 m | 3 |" in capsys.readouterr().out

    assert spread.main([str(tmp_path / "nothing"), "--out", str(tmp_path / "o2")]) == 3
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no cells/ folder" in err[0]
    _cell(tmp_path / "mixed", 0, 0.08, _trials(rng, [0.05] * 4, n=5), heights=[0.04, 0.08])
    assert spread.main([str(tmp_path / "mixed"), "--out", str(tmp_path / "o3")]) == 3
    assert "mixed heights" in capsys.readouterr().err
    assert spread.main([str(tmp_path / "sweep"), "--out", str(tmp_path / "o4"), "--method", "improved"]) == 3
    assert "no improved cells" in capsys.readouterr().err
