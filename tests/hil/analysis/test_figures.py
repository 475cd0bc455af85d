"""Figures are checked by the numbers they plot; each file exists and is not empty."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from hil.analysis import figures
from hil.analysis.metrics import autocorrelation, autocorrelation_peak, footfall_std_by_step


def trials_from(successes, footfalls=None):
    return [{"success": s, "footfalls_m": (footfalls or [[-1.0, -0.6, -0.3, -0.1]])[i % len(footfalls or [0])]}
            for i, s in enumerate(successes)]


def test_learning_curve_plots_success_and_its_running_mean(tmp_path):
    data = figures.learning_curve(trials_from([False, True, True, False, True]), tmp_path, window=2)
    assert data["success"] == [0, 1, 1, 0, 1]
    assert data["running_mean"] == pytest.approx([0.0, 0.5, 1.0, 0.5, 0.5])
    for ext in ("png", "svg"):
        assert (tmp_path / f"learning_curve.{ext}").stat().st_size > 1000


def test_weights_figure_orders_cells_by_distance(tmp_path):
    data = figures.weights_by_distance(np.array([0.1, -0.2, 0.0]), 0.04, tmp_path)
    assert data["distance_m"] == pytest.approx([0.02, 0.06, 0.10])
    assert data["weight_s"] == pytest.approx([0.1, -0.2, 0.0])
    assert (tmp_path / "weights.png").stat().st_size > 1000


def test_a_context_learners_weights_are_drawn_one_panel_per_height_context(tmp_path):
    weights = np.array([[0.0, 0.1], [-0.3, 0.0], [0.0, 0.0]])
    data = figures.weights_by_context(weights, 0.04, (0.05, 0.09), tmp_path)
    assert data["context"] == ["obstacle below 0.05 m", "obstacle 0.05-0.09 m", "obstacle above 0.09 m"]
    assert data["distance_m"] == pytest.approx([0.02, 0.06]) and data["weight_s"] == weights.tolist()
    assert (tmp_path / "weights.png").stat().st_size > 1000
    with pytest.raises(ValueError, match="3 rows of weights but 4 height contexts"):
        figures.weights_by_context(weights, 0.04, (0.05, 0.09, 0.13), tmp_path)


def test_footfall_spread_is_the_std_k_steps_before_the_obstacle(tmp_path):
    runs = [{"trials": [{"footfalls_m": [-1.2, -0.8, -0.5, -0.15]}, {"footfalls_m": [-1.0, -0.7, -0.45, -0.15]}]}]
    std = footfall_std_by_step(runs, 1, 2)
    assert std == pytest.approx([0.0, 0.025, 0.05, 0.1])
    data = figures.footfall_spread(std, tmp_path)
    assert data["steps_before"] == [1, 2, 3, 4]
    assert (tmp_path / "footfall_spread.svg").stat().st_size > 1000


def test_autocorrelation_finds_the_period_of_periodic_weights():
    cells = np.arange(40)
    w = np.sin(2 * np.pi * cells / 9.0)
    ac = autocorrelation(w, 20)
    assert ac[0] == pytest.approx(1.0)
    peak = autocorrelation_peak(w, 0.04, max_range_m=1.6)
    assert peak["lag_cells"] == 9 and peak["period_m"] == pytest.approx(0.36)
    assert autocorrelation_peak(np.zeros(40), 0.04)["lag_cells"] is None


# -- the paper's figures ------------------------------------------------------------------------

STRIDE_M = 0.35


def swing_trace(n_steps: int = 6, start_x_m: float = -2.0, lift_m: float = 0.06, contact_at: int | None = None):
    """A foot that lands every STRIDE_M (first landing at start_x_m + STRIDE_M), 100 Hz, burst
    growing by 0.01 s per step: stance 20 samples flat on the ground, swing 30 samples in an arc."""
    t, x, z, burst = [], [], [], []
    for k in range(n_steps):
        x0 = start_x_m + k * STRIDE_M
        for i in range(20):
            x.append(x0), z.append(0.0), burst.append(0.30 + 0.01 * k)
        for i in range(1, 31):
            x.append(x0 + STRIDE_M * i / 30), z.append(lift_m * np.sin(np.pi * i / 30)), burst.append(0.30 + 0.01 * k)
    t = [i / 100 for i in range(len(x))]
    contact = [contact_at is not None and i >= contact_at for i in range(len(x))]
    return {"t_s": t, "foot_x_m": x, "foot_z_m": z, "burst_s": burst, "contact": contact}


def assert_files(out, name):
    for ext in ("png", "svg"):
        assert (out / f"{name}.{ext}").stat().st_size > 1000


def test_success_curves_average_the_running_success_over_seeds(tmp_path):
    curves = {"learning": [[False, True, True], [True, True, True]], "no learning": [[False, False, True]]}
    data = figures.success_curves(curves, tmp_path, window=1)
    m = data["learning"]
    assert m["trial"] == [1, 2, 3] and m["seeds"] == 2
    assert m["mean"] == pytest.approx([0.5, 1.0, 1.0])
    # two seeds: t(1 dof) = 12.706 times the standard error 0.5, clipped to [0, 1]
    assert m["ci95_low"] == pytest.approx([0.0, 1.0, 1.0]) and m["ci95_high"] == pytest.approx([1.0, 1.0, 1.0])
    # three seeds ending at 0.75, 1 and 0.5 over 4 trials: mean 0.75, s.e. 0.25 / sqrt(3), t(2) = 4.303
    three = figures.success_curves({"x": [[False, True, True, True], [True] * 4, [False, False, True, True]]},
                                   tmp_path, name="three", window=4)["x"]
    assert three["mean"][-1] == pytest.approx(0.75)
    assert three["ci95_low"][-1] == pytest.approx(0.75 - 4.303 * 0.25 / np.sqrt(3))
    assert three["ci95_high"][-1] == 1.0
    one = data["no learning"]
    assert one["mean"] == one["ci95_low"] == one["ci95_high"] == pytest.approx([0.0, 0.0, 1.0])
    assert figures.success_curves({"x": [[False, True, True, True]]}, tmp_path, name="w2", window=2)["x"]["mean"] \
        == pytest.approx([0.0, 0.5, 1.0, 1.0])
    assert_files(tmp_path, "learning_curve_seeds")


@pytest.mark.parametrize("curves", [{}, {"a": []}, {"a": [[True], []]}])
def test_success_curves_reject_empty_input(tmp_path, curves):
    with pytest.raises(ValueError):
        figures.success_curves(curves, tmp_path)


def test_touchdowns_are_found_where_the_foot_lands_after_a_swing():
    trace = swing_trace()
    idx = figures.trace_touchdowns(trace)
    # the trace starts in stance (no touchdown); each of the 6 swings ends on the next footfall
    assert [trace["foot_x_m"][i] for i in idx] == pytest.approx([-2.0 + STRIDE_M * k for k in range(1, 7)])
    # a landing on the obstacle's top counts: put a 5 cm block under the third footfall
    raised = dict(trace, foot_z_m=[z + (0.05 if -1.31 <= x <= -1.29 else 0.0)
                                   for x, z in zip(trace["foot_x_m"], trace["foot_z_m"])])
    shifted = {k: ([x + 1.3 for x in v] if k == "foot_x_m" else v) for k, v in raised.items()}
    assert len(figures.trace_touchdowns(shifted, obstacle_height_m=0.05, obstacle_depth_m=0.01)) == 6
    assert len(figures.trace_touchdowns(shifted)) == 5  # ground only: the landing on the block is missed


def test_foot_trajectories_draw_both_paths_touchdowns_and_the_contact(tmp_path):
    before = swing_trace(contact_at=100)
    after = swing_trace(start_x_m=-1.9, lift_m=0.12)
    data = figures.foot_trajectories(before, after, 0.08, 0.10, tmp_path)
    assert data["before"]["x_m"] == pytest.approx(before["foot_x_m"])
    assert data["after"]["z_m"] == pytest.approx(after["foot_z_m"])
    assert max(data["after"]["z_m"]) == pytest.approx(0.12, abs=1e-3)
    assert data["after"]["touchdown_x_m"] == pytest.approx([-1.9 + STRIDE_M * k for k in range(1, 7)])
    assert data["before"]["contact_x_m"] == pytest.approx(before["foot_x_m"][100])
    assert data["after"]["contact_x_m"] is None
    assert_files(tmp_path, "foot_trajectories")
    given = figures.foot_trajectories(before, after, 0.08, 0.10, tmp_path, name="given",
                                      before_touchdowns_x_m=[-0.5, -0.2])
    assert given["before"]["touchdown_x_m"] == [-0.5, -0.2] and given["before"]["touchdown_z_m"] == [0.0, 0.0]
    with pytest.raises(ValueError, match="foot_z_m"):
        figures.foot_trajectories({"t_s": [0.0], "foot_x_m": [0.0]}, after, 0.08, 0.10, tmp_path)


def runs_with_spread(spread_m: float, n_trials: int = 4):
    """Runs whose last footfall is -0.15 +/- spread_m and the one before it twice as spread."""
    trials = [{"footfalls_m": [-0.5 + 2 * sign * spread_m, -0.15 + sign * spread_m]}
              for sign in (1, -1) * (n_trials // 2)]
    return [{"trials": trials}]


def test_footfall_spread_by_size_is_one_line_per_height(tmp_path, caplog):
    groups = {0.12: runs_with_spread(0.01), 0.06: runs_with_spread(0.04), 0.08: runs_with_spread(0.02)}
    data = figures.footfall_spread_by_size(groups, tmp_path, 1, 4, steps=3)
    assert data["heights_m"] == [0.06, 0.08, 0.12] and data["steps_before"] == [1, 2, 3]
    assert data["std_m"][0.06] == pytest.approx([0.04, 0.08, None])
    assert data["std_m"][0.12][:2] == pytest.approx([0.01, 0.02])
    assert data["runs"] == {0.06: 1, 0.08: 1, 0.12: 1}
    assert not [r for r in caplog.records if r.levelname == "WARNING"]
    assert_files(tmp_path, "footfall_spread_by_size")
    figures.footfall_spread_by_size({0.08: runs_with_spread(0.02)}, tmp_path, 1, 4, name="one")
    assert "1 obstacle height" in caplog.text
    with pytest.raises(ValueError):
        figures.footfall_spread_by_size({}, tmp_path, 1, 4)


def test_weights_autocorrelation_marks_the_period_in_metres(tmp_path):
    w = np.sin(2 * np.pi * np.arange(40) / 9.0)
    data = figures.weights_autocorrelation(w, 0.04, tmp_path, max_range_m=1.6)
    assert data["peak_lag_m"] == pytest.approx(0.36)
    assert data["lag_m"][9] == pytest.approx(0.36) and data["autocorrelation"][0] == pytest.approx(1.0)
    assert data["peak"] == pytest.approx(max(data["autocorrelation"][5:]))
    assert_files(tmp_path, "weights_autocorrelation")
    flat = figures.weights_autocorrelation(np.zeros(40), 0.04, tmp_path, name="flat")
    assert flat["peak_lag_m"] is None
    assert_files(tmp_path, "flat")


def test_burst_over_approach_marks_touchdowns_and_the_crossing(tmp_path):
    trace = swing_trace(n_steps=8)  # footfalls up to -2.0 + 8 * 0.35 = 0.8: crosses x = 0
    data = figures.burst_over_approach(trace, tmp_path, before=swing_trace())
    assert data["burst_s"] == pytest.approx(trace["burst_s"])
    assert len(data["touchdown_t_s"]) == 8
    assert data["touchdown_t_s"][0] == pytest.approx(0.49)  # the last of 20 stance + 30 swing samples
    assert data["touchdown_burst_s"] == pytest.approx([0.30 + 0.01 * k for k in range(8)])
    first_over = next(i for i, x in enumerate(trace["foot_x_m"]) if x >= 0)
    assert data["over_edge_t_s"] == pytest.approx(trace["t_s"][first_over])
    assert len(data["before_t_s"]) == len(swing_trace()["t_s"])
    assert_files(tmp_path, "burst_over_approach")


def write_learn_folder(folder, height_m, seed, learning=True, n_trials=6, traced=False, weights=None):
    import json

    from controller.stepping.weights import save_weights

    trials = []
    for i in range(n_trials):
        spread = 0.01 * (seed + 1) * (1 if i % 2 else -1) / (height_m * 10)
        t = {"index": i, "success": i >= n_trials // 2, "obstacle_height_m": height_m,
             "footfalls_m": [-0.85 + 2 * spread, -0.5 + 1.5 * spread, -0.15 + spread]}
        if traced and i in (0, n_trials - 1):
            t["trace"] = swing_trace(n_steps=8, contact_at=150 if i == 0 else None)
        trials.append(t)
    folder.mkdir(parents=True)
    config = {"seed": seed, "learning": learning, "method": "learner", "obstacle_height_m": height_m,
              "obstacle_heights_m": [], "obstacle_depth_m": 0.10}
    (folder / "metrics.json").write_text(json.dumps({"config": config, "trials": trials, "summary": {}}))
    if weights is not None:
        save_weights(folder / "weights.npz", weights, 0.04)
    return folder


def test_paper_figures_draw_all_the_data_allows(tmp_path, caplog):
    w = np.sin(2 * np.pi * np.arange(40) / 9.0)
    folders = [write_learn_folder(tmp_path / f"h{h}_s{s}", h, s, traced=(h == 0.08 and s == 0), weights=w)
               for h in (0.06, 0.08, 0.12) for s in (0, 1)]
    folders.append(write_learn_folder(tmp_path / "frozen", 0.08, 0, learning=False))
    out = tmp_path / "figs"
    written = figures.paper_figures(folders, out)
    expected = {"learning_curve_seeds", "footfall_spread_by_size", "foot_trajectories", "burst_over_approach"}
    expected |= {f"{kind}_h{h}cm" for kind in ("weights", "weights_autocorrelation") for h in (6, 8, 12)}
    assert set(written) == expected
    for name, paths in written.items():
        assert [p.name for p in paths] == [f"{name}.png", f"{name}.svg"]
        assert all(p.stat().st_size > 1000 for p in paths)
    assert "WARNING" not in [r.levelname for r in caplog.records]


def test_paper_figures_with_one_height_and_no_traces_warn_and_write_what_they_can(tmp_path, caplog):
    folders = [write_learn_folder(tmp_path / f"s{s}", 0.08, s) for s in (0, 1)]
    written = figures.paper_figures(folders, tmp_path / "figs")
    assert set(written) == {"learning_curve_seeds", "footfall_spread_by_size"}
    assert "1 obstacle height" in caplog.text and "traced" in caplog.text
    with pytest.raises(FileNotFoundError):
        figures.paper_figures([tmp_path / "missing"], tmp_path / "figs")
    with pytest.raises(ValueError):
        figures.paper_figures([], tmp_path / "figs")


def test_figures_command_lists_what_it_wrote(tmp_path, capsys):
    import json

    from hil.cli import main

    folder = write_learn_folder(tmp_path / "run", 0.08, 0, traced=True)
    assert main(["figures", str(folder), "--out", str(tmp_path / "figs")]) == 0
    listed = json.loads(capsys.readouterr().out)
    assert {"learning_curve_seeds", "foot_trajectories", "burst_over_approach"} <= listed.keys()
    assert main(["figures", str(tmp_path / "nothing"), "--out", str(tmp_path / "figs")]) == 3  # input: exit 3
    assert "no metrics.json" in capsys.readouterr().err


def test_figures_compare_draws_one_curve_per_folder_labelled_by_its_name(tmp_path, capsys):
    import json

    from hil.cli import main

    hil = write_learn_folder(tmp_path / "HIL", 0.08, 0, n_trials=6)
    lockstep = write_learn_folder(tmp_path / "lockstep", 0.08, 0, n_trials=8)
    out = tmp_path / "figs"
    assert main(["figures", str(hil), str(lockstep), "--out", str(out), "--compare", "hil_vs_lockstep"]) == 0
    assert json.loads(capsys.readouterr().out) == {"hil_vs_lockstep": [str(out / "hil_vs_lockstep.png"),
                                                                       str(out / "hil_vs_lockstep.svg")]}
    assert (out / "hil_vs_lockstep.png").stat().st_size > 1000
    svg = (out / "hil_vs_lockstep.svg").read_text()
    assert "HIL (1 seed)" in svg and "lockstep (1 seed)" in svg and "learning_curve" not in svg
    assert not (out / "learning_curve_seeds.png").exists()  # instead of the paper's figures, not beside them
    twin = write_learn_folder(tmp_path / "other" / "HIL", 0.08, 1)
    assert main(["figures", str(hil), str(twin), "--out", str(out), "--compare", "x"]) == 3
    assert "two are the same" in capsys.readouterr().err
    assert main(["figures", str(hil), "--out", str(out), "--compare", "a/b"]) == 3


@pytest.mark.parametrize("method", [None, "paper"])  # learn's default (improved), and the paper's learner
def test_learn_records_the_first_and_last_trial_for_the_figures(tmp_path, method):
    import json

    from hil.cli import main

    run = tmp_path / "run"
    chosen = [] if method is None else ["--method", method]
    assert main(["learn", "--trials", "3", "--seed", "2", "--out", str(run), "--quiet", "--no-figures", *chosen]) == 0
    assert json.loads((run / "metrics.json").read_text())["config"]["method"] == (method or "improved")
    trials = json.loads((run / "metrics.json").read_text())["trials"]
    assert ["trace" in t for t in trials] == [True, False, True]
    trace = trials[-1]["trace"]
    assert len(trace["t_s"]) == len(trace["foot_x_m"]) > 100
    written = figures.paper_figures([run], tmp_path / "figs")
    assert {"foot_trajectories", "burst_over_approach", "footfall_spread_by_size", "weights_h8cm"} <= written.keys()
    # the touchdowns found in the real trace are the footfalls the plant's foot switch recorded
    found = [trace["foot_x_m"][i] for i in figures.trace_touchdowns(trace, 0.08, 0.10)]
    for x in trials[-1]["footfalls_m"][1:]:
        assert min(abs(x - f) for f in found) < 0.02


# -- drawn without pyplot, the same files as pyplot's -----------------------------------------------


def _python(code: str, **env: str) -> str:
    done = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True, text=True,
                          timeout=120, env={**os.environ, **env})
    assert done.returncode == 0, done.stderr
    return done.stdout.strip().splitlines()[-1]


def test_figures_and_the_report_draw_without_importing_pyplot(tmp_path):
    seen = json.loads(_python(f"""
        import json, sys
        from pathlib import Path
        from hil.analysis import figures, report
        figures.learning_curve([{{"success": True}}, {{"success": False}}], Path({str(tmp_path)!r}))
        print(json.dumps(sorted(m for m in sys.modules if m.startswith("matplotlib.pyplot"))))
    """))
    assert seen == []
    assert (tmp_path / "learning_curve.png").stat().st_size > 1000


def test_subplots_and_save_write_the_bytes_pyplot_writes(tmp_path):
    # the same drawing through pyplot (Agg) and through figures.subplots/_save; fixed SVG ids and date
    same = json.loads(_python(f"""
        import json
        from pathlib import Path
        import matplotlib
        matplotlib.use("Agg")
        matplotlib.rcParams["svg.hashsalt"] = "test"
        import matplotlib.pyplot as plt
        from hil.analysis import figures

        def draw(fig, axes):
            axes[0].plot([1, 2, 3], [0.2, 0.9, 0.5], "o-", label="a line")
            axes[1].bar([0.5, 1.5], [1.0, -0.5], width=0.8, color="C1")
            axes[0].set(xlabel="x [m]", title="pyplot or not")
            axes[0].legend(loc="lower right")
            fig.suptitle("the same figure")

        out = Path({str(tmp_path)!r})
        fig, axes = plt.subplots(1, 2, figsize=(6, 3.2), sharey=True)
        draw(fig, axes)
        for ext in ("png", "svg"):
            fig.savefig(out / f"pyplot.{{ext}}", dpi=120, bbox_inches="tight")
        fig, axes = figures.subplots(1, 2, figsize=(6, 3.2), sharey=True)
        draw(fig, axes)
        figures._save(fig, out, "oo")
        print(json.dumps({{ext: (out / f"pyplot.{{ext}}").read_bytes() == (out / f"oo.{{ext}}").read_bytes()
                          for ext in ("png", "svg")}}))
    """, SOURCE_DATE_EPOCH="0"))
    assert same == {"png": True, "svg": True}
    assert (tmp_path / "oo.png").stat().st_size > 1000
