"""The sweep command: summary rows, resumability, failed cells, the report, pool vs Dask."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import pytest

from hil.analysis import report
from hil.cli import main
from hil.experiments.sweep import Cell, SweepConfig, parse_seeds, run_sweep, summary_row

T, F = True, False


# ---- rows from synthetic trial lists -------------------------------------------------------------------------


def test_row_of_a_150_trial_run():
    # 12 failures, then success except trials 120 and 130 (1-based); the window of trials 12-21
    # holds 9 successes, so 11 trials ran before it
    success = [F] * 12 + [T] * 138
    success[119] = success[129] = F
    row = summary_row(Cell("paper", 0.08, 3, 150), success)
    assert row == {"method": "paper", "obstacle_height_m": 0.08, "seed": 3, "trials": 150,
                   "trials_to_criterion": 11, "mistakes_after_100": 2, "success_last_50": 48 / 50,
                   "success_rate": 136 / 150, "cell": "paper_h80mm_s3"}


def test_criterion_needs_9_of_10_in_a_window():
    assert summary_row(Cell("rl", 0.06, 0, 13), [F, F, F, T, T, T, T, F, T, T, T, T, T])["trials_to_criterion"] == 3
    eight_of_ten = [T, T, F, T, T, T, F, T, T, T] * 3
    assert summary_row(Cell("rl", 0.06, 0, 30), eight_of_ten)["trials_to_criterion"] is None
    assert summary_row(Cell("rl", 0.06, 0, 9), [T] * 9)["trials_to_criterion"] is None  # no full window


def test_mistakes_after_100_and_the_last_50():
    assert summary_row(Cell("none", 0.1, 0, 100), [F] * 100)["mistakes_after_100"] is None
    row = summary_row(Cell("none", 0.1, 0, 101), [T] * 100 + [F])
    assert row["mistakes_after_100"] == 1 and row["success_last_50"] == pytest.approx(49 / 50)
    short = summary_row(Cell("none", 0.1, 0, 4), [T, F, F, F])
    assert short["success_last_50"] == 0.25 and short["success_rate"] == 0.25
    with pytest.raises(ValueError, match="success"):
        summary_row(Cell("none", 0.1, 0, 1), [])


def test_a_mixed_cell_names_all_its_heights():
    row = summary_row(Cell("context", (0.06, 0.1), 1, 2), [T, F])
    assert row["obstacle_height_m"] == [0.06, 0.1] and row["cell"] == "context_h60mm+100mm_s1"


# ---- configuration and command-line errors ---------------------------------------------------------------------


def test_seeds_lists_and_ranges():
    assert parse_seeds("0-2,7") == (0, 1, 2, 7) and parse_seeds("4") == (4,)
    for bad in ("3-1", "a", "1,,2"):
        with pytest.raises(ValueError, match="seeds"):
            parse_seeds(bad)


@pytest.mark.parametrize("kwargs,field", [
    ({"seeds": (0, 0)}, "seeds"), ({"seeds": (-1,)}, "seeds"), ({"obstacle_heights_m": (0.02,)}, "obstacle_heights_m"),
    ({"methods": ("paper", "magic")}, "methods"), ({"trials": 0}, "trials"), ({"workers": 0}, "workers"),
    ({"methods": ()}, "methods"),
])
def test_bad_config_names_the_field(tmp_path, kwargs, field):
    with pytest.raises(ValueError, match=field):
        SweepConfig(out_dir=tmp_path, **kwargs)


@pytest.mark.parametrize("argv,field", [
    (["--seeds", "2-1"], "seeds"), (["--obstacle-heights-m", "0.06,x"], "obstacle_heights_m"),
    (["--methods", "paper,magic"], "methods"), (["--trials", "0"], "trials"),
])
def test_bad_sweep_arguments_get_a_clear_error(tmp_path, capsys, argv, field):
    with pytest.raises(SystemExit) as exc:  # argparse's usage error names the option
        main(["sweep", "--out", str(tmp_path / "s"), "--quiet", *argv])
    assert exc.value.code == 2
    assert field in capsys.readouterr().err
    assert not (tmp_path / "s").exists()


def test_a_cell_checks_the_config_of_its_metrics():
    cell = Cell("paper", 0.06, 2, 2)
    good = {"config": {"method": "paper", "seed": 2, "trials": 2, "obstacle_height_m": 0.06,
                       "obstacle_heights_m": []}, "trials": [{"success": True}, {"success": False}]}
    assert cell.mismatch(good) is None
    assert "trials" in cell.mismatch({**good, "config": {**good["config"], "trials": 3}})
    assert "obstacle_height_m" in cell.mismatch({**good, "config": {**good["config"], "obstacle_height_m": 0.1}})
    assert cell.mismatch({"config": {}}) is not None and cell.mismatch([]) is not None
    mixed = Cell("paper", (0.06, 0.1), 2, 2)
    assert "obstacle_heights_m" in mixed.mismatch(good)


# ---- the report, from rows -------------------------------------------------------------------------------------


def fake_sweep(out: Path, outcomes: dict[tuple[str, float, int], list[bool]], methods, heights, seeds) -> list[dict]:
    """A sweep folder with synthetic cells, as run_sweep would leave it."""
    config = SweepConfig(out_dir=out, methods=methods, obstacle_heights_m=heights, seeds=seeds,
                         trials=len(next(iter(outcomes.values()))))
    rows = []
    for cell in config.cells():
        success = outcomes[(cell.method, cell.obstacle_height_m, cell.seed)]
        folder = cell.folder(out)
        folder.mkdir(parents=True)
        (folder / "metrics.json").write_text(json.dumps({"config": {}, "trials": [{"success": s} for s in success]}))
        rows.append(summary_row(cell, success))
    (out / "config.json").write_text(json.dumps(config.to_json()))
    (out / "summary.json").write_text(json.dumps(rows))
    return rows


def test_headline_table_sentences_and_figures_come_from_the_rows(tmp_path):
    n = 120
    learner = {0: [F] * 5 + [T] * (n - 5), 1: [F] * 9 + [T] * (n - 10) + [F]}
    rl = {0: [F] * 30 + [T] * (n - 30), 1: ([F, T] * n)[:n]}  # seed 1 never reaches the criterion
    none = {0: ([T, F, F] * n)[:n], 1: ([F, T, F] * n)[:n]}
    oracle = {0: [T] * n, 1: [T] * (n - 1) + [F]}
    outcomes = {}
    for method, by_seed in (("paper", learner), ("none", none), ("oracle", oracle), ("rl", rl)):
        for seed, s in by_seed.items():
            outcomes[(method, 0.06, seed)] = s
            outcomes[(method, 0.1, seed)] = [not x for x in s] if method == "none" else s
    out = tmp_path / "sweep"
    rows = fake_sweep(out, outcomes, ("paper", "none", "oracle", "rl"), (0.1, 0.06), (0, 1))
    assert [(r["method"], r["obstacle_height_m"], r["seed"]) for r in rows][:4] == [
        ("paper", 0.06, 0), ("paper", 0.06, 1), ("paper", 0.1, 0), ("paper", 0.1, 1)]

    table = report.headline_table(rows)
    assert [(e["obstacle_height_m"], e["method"]) for e in table] == [
        (h, m) for h in (0.06, 0.1) for m in ("paper", "none", "oracle", "rl")]
    e = {(e["obstacle_height_m"], e["method"]): e for e in table}
    # a window may start on the last failure: 9 of 10 is enough
    assert e[0.06, "paper"]["trials_to_criterion_mean"] == 6.0
    assert (e[0.06, "paper"]["trials_to_criterion_min"], e[0.06, "paper"]["trials_to_criterion_max"]) == (4, 8)
    assert e[0.06, "paper"]["mistakes_after_100_mean"] == 0.5
    assert e[0.06, "paper"]["seeds_without_mistakes_after_100"] == 1
    assert e[0.06, "paper"]["success_last_50_mean"] == pytest.approx((1.0 + 49 / 50) / 2)
    assert e[0.06, "rl"]["never_reached"] == 1 and e[0.06, "rl"]["trials_to_criterion_mean"] == 29
    assert e[0.06, "none"]["trials_to_criterion_mean"] is None and e[0.06, "none"]["never_reached"] == 2
    assert e[0.06, "oracle"]["success_rate_mean"] == pytest.approx((1.0 + (n - 1) / n) / 2)

    result = report.write_report(out)
    assert result["table"] == table and result["missing"] == []
    md = (out / "report.md").read_text()
    assert "## Obstacle 0.06 m" in md and "## Obstacle 0.1 m" in md
    assert "| paper | 2 | 6.0 (4–8) | 0 | 0.50 | 1 | 99% |" in md
    assert "| rl | 2 | 29.0 (29–29) | 1 |" in md
    assert "The learner (Elegant Stepping) reached the criterion after 6.0 trials on average (range 4–8" in md
    assert "made 0.50 mistakes after trial 100 on average (1 of 2 seeds made none)" in md
    assert "1 of 2 seeds never reached it" in md
    assert "Without adaptation (none), the leg never reached the criterion on any of its 2 seeds" in md
    assert f"The oracle succeeded in {(1 + (n - 1) / n) / 2:.0%} of all trials" in md
    assert "--seeds 0,1 --obstacle-heights-m 0.1,0.06 --methods paper,none,oracle,rl --trials 120" in md
    for name in ("success_curves_60mm", "success_curves_100mm", "criterion_bars"):
        assert f"](figures/{name}.png)" in md
        for ext in ("png", "svg"):
            assert (out / "figures" / f"{name}.{ext}").stat().st_size > 1000

    # the curves: running 10-trial success, mean and t-interval over the seeds
    oracle_curve = result["curves"]["0.06 m"]["oracle"]
    assert oracle_curve["seeds"] == 2 and oracle_curve["mean"][:3] == [1.0, 1.0, 1.0]
    assert oracle_curve["mean"][-1] == pytest.approx(0.95)  # seed 1's last window has one failure in 10
    assert oracle_curve["ci95_low"][-1] < 0.95 < oracle_curve["ci95_high"][-1]
    learner_curve = result["curves"]["0.06 m"]["paper"]
    assert learner_curve["mean"][0] == 0.0 and learner_curve["trial"] == list(range(1, n + 1))
    bars = result["bars"]
    assert bars["methods"] == ["paper", "none", "oracle", "rl"] and bars["heights"] == ["0.06 m", "0.1 m"]
    assert bars["trials_to_criterion_mean"][0] == [6.0, None, 0.0, 29.0]
    assert bars["success_last_50_mean"][1][1] == e[0.1, "none"]["success_last_50_mean"]

    # the report alone, on the existing folder, through the command line
    (out / "report.md").unlink()
    assert main(["sweep", "--out", str(out), "--report-only"]) == 0
    assert (out / "report.md").read_text() == md


def test_report_only_on_a_folder_that_is_not_a_sweep(tmp_path, capsys):
    assert main(["sweep", "--out", str(tmp_path), "--report-only"]) == 3
    assert "config.json" in capsys.readouterr().err


# ---- real runs (small) -----------------------------------------------------------------------------------------


def test_a_second_run_runs_nothing_and_a_damaged_or_mismatched_cell_is_refused_and_kept(tmp_path, caplog, capsys):
    out = tmp_path / "sweep"
    argv = ["sweep", "--out", str(out), "--seeds", "0", "--obstacle-heights-m", "0.07", "--methods", "paper,none",
            "--trials", "2", "--workers", "2", "--quiet"]
    assert main(argv) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert (summary["format"], summary["format_version"]) == ("sweep-summary", 1)
    rows = summary["rows"]
    assert [(r["method"], r["seed"], r["trials"]) for r in rows] == [("paper", 0, 2), ("none", 0, 2)]
    timing = json.loads((out / "timing.json").read_text())
    assert timing["format"] == "sweep-timing"
    assert json.loads((out / "config.json").read_text())["format"] == "sweep-config"
    assert [c["status"] for c in timing["cells"]] == ["ran", "ran"] and timing["executor"] == "pool"
    assert "wall_s" not in (out / "summary.json").read_text()
    assert "2 run, 0 resumed" in capsys.readouterr().err

    config = SweepConfig(out_dir=out, seeds=(0,), obstacle_heights_m=(0.07,), methods=("paper", "none"), trials=2,
                         workers=2)
    again = run_sweep(config, progress=False)
    assert (again["ran"], again["resumed"], again["failed"], again["refused"]) == (0, 2, [], [])
    assert again["rows"] == rows

    damaged = out / "cells" / "paper_h70mm_s0" / "weights.npz"
    damaged.write_bytes(damaged.read_bytes()[:-40])  # truncated: the cell's records no longer verify
    metrics = json.loads((out / "cells" / "none_h70mm_s0" / "metrics.json").read_text())
    metrics["config"]["trials"] = 3
    (out / "cells" / "none_h70mm_s0" / "metrics.json").write_text(json.dumps(metrics))
    kept = {p: p.read_bytes() for p in (out / "cells").rglob("*") if p.is_file()}
    with caplog.at_level(logging.ERROR, logger="hil.experiments.sweep"):
        third = run_sweep(config, progress=False)
    assert (third["ran"], third["resumed"], third["refused"]) == (0, 0, ["paper_h70mm_s0", "none_h70mm_s0"])
    errors = " ".join(r.getMessage() for r in caplog.records)
    assert "weights.npz" in errors and "trials: 3 in the folder, 2 asked" in errors
    assert {p: p.read_bytes() for p in (out / "cells").rglob("*") if p.is_file()} == kept  # nothing deleted
    assert main(argv) == 1
    assert "2 cells hold something else and were kept as they are" in capsys.readouterr().err

    assert main([*argv, "--overwrite"]) == 0  # explicit: clear the sweep and run it again
    assert json.loads((out / "summary.json").read_text())["rows"] == rows  # the runs are deterministic per seed


def test_a_sweep_of_another_configuration_is_refused_and_nothing_is_deleted(tmp_path, capsys):
    out = tmp_path / "sweep"
    (out / "cells" / "none_h80mm_s0").mkdir(parents=True)
    (out / "cells" / "none_h80mm_s0" / "metrics.json").write_text("{}")
    (out / "config.json").write_text(json.dumps({"methods": ["none"], "obstacle_heights_m": [0.08],
                                                 "mixed_heights": False, "seeds": [0], "trials": 3}))  # version 0
    (out / "notes.txt").write_text("mine")
    files = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    argv = ["sweep", "--out", str(out), "--seeds", "0", "--methods", "none", "--trials", "2", "--quiet"]
    assert main(argv) == 3
    err = capsys.readouterr().err
    assert f"--out {out}: holds a sweep of another configuration (trials: 3 in the folder, 2 asked)" in err
    assert "nothing was deleted" in err and "--overwrite" in err
    assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file() and p.name != ".lock"} == files

    # --overwrite clears the sweep's own files only (here: no cell runs, the one cell is busy)
    from hil.experiments.journal import FolderLock

    (out / "cells" / "none_h80mm_s0" / "metrics.json").unlink()
    with FolderLock(out / "cells" / "none_h80mm_s0"):
        assert main([*argv, "--overwrite"]) == 3
        assert "cell none_h80mm_s0 is being written by another process; not clearing" in capsys.readouterr().err
    assert (out / "config.json").exists() and (out / "cells").exists()


def test_overwrite_only_clears_a_sweeps_folder(tmp_path, capsys):
    out = tmp_path / "not_a_sweep"
    (out / "cells").mkdir(parents=True)
    (out / "cells" / "data.csv").write_text("1,2,3")
    assert main(["sweep", "--out", str(out), "--seeds", "0", "--methods", "none", "--trials", "1", "--quiet",
                 "--overwrite"]) == 3
    assert "holds cells but no config.json: not a sweep's folder" in capsys.readouterr().err
    assert (out / "cells" / "data.csv").read_text() == "1,2,3"


def test_a_cell_another_process_writes_is_busy_not_run_twice(tmp_path, capsys):
    from hil.experiments.journal import FolderLock

    out = tmp_path / "sweep"
    cell = out / "cells" / "none_h80mm_s0"
    cell.mkdir(parents=True)
    with FolderLock(cell):
        assert main(["sweep", "--out", str(out), "--seeds", "0", "--methods", "none", "--trials", "1", "--quiet"]) == 1
    assert "1 cells are being written by another process: none_h80mm_s0" in capsys.readouterr().err
    assert [p.name for p in cell.iterdir()] == [".lock"]  # not run
    assert json.loads((out / "timing.json").read_text())["busy"] == ["none_h80mm_s0"]


def test_a_second_sweep_into_a_running_sweeps_folder_is_refused(tmp_path, capsys):
    from hil.experiments.journal import FolderLock

    out = tmp_path / "sweep"
    out.mkdir()
    with FolderLock(out):
        assert main(["sweep", "--out", str(out), "--seeds", "0", "--methods", "none", "--trials", "1", "--quiet"]) == 3
    assert "another run is writing this folder" in capsys.readouterr().err
    assert not (out / "config.json").exists()


def test_a_failing_cell_is_named_and_the_finished_ones_are_kept(tmp_path, capsys):
    out = tmp_path / "sweep"
    (out / "cells").mkdir(parents=True)
    (out / "cells" / "paper_h80mm_s1").write_text("a file where the cell's folder should go")
    argv = ["sweep", "--out", str(out), "--seeds", "0-1", "--obstacle-heights-m", "0.08", "--methods", "paper",
            "--trials", "1", "--workers", "2", "--quiet"]
    assert main(argv) == 1
    err = capsys.readouterr().err
    assert "1 cells failed: paper_h80mm_s1" in err
    assert [r["cell"] for r in json.loads((out / "summary.json").read_text())["rows"]] == ["paper_h80mm_s0"]
    timing = json.loads((out / "timing.json").read_text())
    assert timing["failed"] == ["paper_h80mm_s1"]
    failed = timing["cells"][1]
    assert failed["status"] == "failed" and "Error" in failed["error"] and "Traceback" in failed["traceback"]
    assert "Incomplete: 1 cells have no result** (paper_h80mm_s1)" in (out / "report.md").read_text()

    (out / "cells" / "paper_h80mm_s1").unlink()
    assert main(argv) == 0
    assert json.loads((out / "timing.json").read_text())["resumed"] == 1
    assert len(json.loads((out / "summary.json").read_text())["rows"]) == 2
    assert "Incomplete" not in (out / "report.md").read_text()


def test_mixed_heights_are_one_scenario(tmp_path):
    out = tmp_path / "sweep"
    assert main(["sweep", "--out", str(out), "--seeds", "4", "--obstacle-heights-m", "0.06,0.10", "--mixed-heights",
                 "--methods", "paper", "--trials", "4", "--workers", "1", "--quiet"]) == 0
    [row] = json.loads((out / "summary.json").read_text())["rows"]
    assert row["obstacle_height_m"] == [0.06, 0.1] and row["cell"] == "paper_h60mm+100mm_s4"
    metrics = json.loads((out / "cells" / row["cell"] / "metrics.json").read_text())
    assert metrics["config"]["obstacle_heights_m"] == [0.06, 0.1]
    assert {t["obstacle_height_m"] for t in metrics["trials"]} <= {0.06, 0.1}
    assert "## Obstacle mixed 0.06/0.1 m" in (out / "report.md").read_text()


def test_an_experiment_file_sets_every_cell_and_the_options_win(tmp_path):
    experiment = tmp_path / "e.toml"
    experiment.write_text("rail_speed_m_s = 0.55\nrange_noise_m = 0.04\nobstacle_heights_m = [0.06, 0.1]\n")
    out = tmp_path / "sweep"
    assert main(["sweep", "--out", str(out), "--experiment", str(experiment), "--range-noise-m", "0.03", "--seeds", "1",
                 "--methods", "none", "--trials", "1", "--workers", "1", "--quiet"]) == 0
    rows = json.loads((out / "summary.json").read_text())["rows"]
    assert [r["obstacle_height_m"] for r in rows] == [0.06, 0.1]  # the file's heights are the grid
    for row in rows:
        config = json.loads((out / "cells" / row["cell"] / "metrics.json").read_text())["config"]
        assert (config["rail_speed_m_s"], config["range_noise_m"]) == (0.55, 0.03)
    assert json.loads((out / "config.json").read_text())["conditions"]["rail_speed_m_s"] == 0.55


def test_cells_run_on_a_dask_scheduler_given_by_address(tmp_path):
    import distributed

    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        address = cluster.scheduler_address
        config = SweepConfig(out_dir=tmp_path, seeds=(2,), obstacle_heights_m=(0.08,), methods=("none",), trials=1,
                             workers=1, dask=address)
        stats = run_sweep(config, progress=False)
    assert (stats["ran"], stats["failed"]) == (1, [])
    assert json.loads((tmp_path / "timing.json").read_text())["executor"] == f"dask {address}"
    assert (tmp_path / "cells" / "none_h80mm_s2" / "metrics.json").is_file()


@pytest.mark.slow
def test_pool_and_dask_local_give_the_same_summary(tmp_path):
    """The issue's done criterion: 3 seeds x 2 heights x 4 methods, on the pool and on --dask local."""
    common = ["--seeds", "0-2", "--obstacle-heights-m", "0.06,0.10", "--methods", "paper,none,oracle,rl",
              "--trials", "3", "--workers", "2", "--quiet"]
    assert main(["sweep", "--out", str(tmp_path / "pool"), *common]) == 0
    assert main(["sweep", "--out", str(tmp_path / "dask"), "--dask", "local", *common]) == 0
    pool = json.loads((tmp_path / "pool" / "summary.json").read_text())
    assert pool == json.loads((tmp_path / "dask" / "summary.json").read_text())
    rows = pool["rows"]
    assert len(rows) == 24 and [r["method"] for r in rows[::6]] == ["paper", "none", "oracle", "rl"]
    assert json.loads((tmp_path / "dask" / "timing.json").read_text())["executor"] == "dask local"


def write_finished_sweep(out, config: dict) -> list[dict]:
    """A sweep folder whose every cell finished 12 trials (2 failures, then 10 successes)."""
    from hil.experiments.sweep import cells_from_json

    rows = []
    for cell in cells_from_json(config):
        success = [F] * 2 + [T] * 10
        cell.folder(out).mkdir(parents=True)
        (cell.folder(out) / "metrics.json").write_text(json.dumps({"config": {"method": cell.method},
                                                                   "trials": [{"success": s} for s in success]}))
        rows.append(summary_row(cell, success))
    (out / "config.json").write_text(json.dumps(config))
    (out / "summary.json").write_text(json.dumps(rows))
    return rows


def test_the_reproduce_line_carries_the_changed_conditions(tmp_path):
    """A sweep under changed conditions is reproduced by its report's command only if the command
    names them (it once named the grid alone)."""
    out = tmp_path / "cond"
    conditions = {"rail_speed_m_s": 0.45, "believed_rail_speed_m_s": 0.5, "start_m": [1.5, 3.0],
                  "range_noise_m": 0.02, "range_dropout": 0.2, "obstacle_depth_m": 0.1}
    write_finished_sweep(out, {"methods": ["paper"], "obstacle_heights_m": [0.08], "mixed_heights": False,
                               "seeds": [0], "trials": 12, "conditions": conditions})
    md = report.write_report(out)["report"].read_text()
    assert ("--methods paper --trials 12 --rail-speed-m-s 0.45 --believed-rail-speed-m-s 0.5 --start-m 1.5,3 "
            "--range-dropout 0.2`") in md  # the defaults (noise 0.02 m, depth 0.1 m) are not repeated


def test_an_old_sweep_folder_naming_the_learner_learner_still_reports(tmp_path):
    """Older sweeps called the paper's learner ``learner``: their folders are read with that alias."""
    out = tmp_path / "old"
    rows = write_finished_sweep(out, {"methods": ["learner", "none"], "obstacle_heights_m": [0.08],
                                      "mixed_heights": False, "seeds": [0], "trials": 12})
    assert rows[0]["cell"] == "learner_h80mm_s0" and rows[0]["success_last_50"] == 10 / 12
    result = report.write_report(out)
    md = result["report"].read_text()
    assert not result["missing"]
    assert "The learner (Elegant Stepping) reached the criterion" in md
    assert "--methods paper,none" in md  # the reproduce line names today's method
    with pytest.raises(ValueError, match="unknown method 'learner'"):
        SweepConfig(out_dir=out, methods=("learner",))  # new sweeps: registry names only
