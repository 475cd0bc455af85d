"""The course: its layout (seeded, the same for every method, within its ranges and the leg's
limit), the walk over it through the whole stack, resume after a stop, and its figure."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from hil.analysis.records import compare, read
from hil.experiments import course as course_mod
from hil.experiments.course import (COURSE_FIELDS, GAP_FLOOR_M, CourseConfig, CourseRun, course_into, course_layout,
                                    rolling_success)
from hil.experiments.journal import TRIALS_FILE
from hil.experiments.learn import RunStopped, learn_into
from hil.experiments.methods import METHODS

SEED, OBSTACLES = 4, 3


# ---- the layout (no simulation) ------------------------------------------------------------------------------


def test_the_same_seed_lays_out_the_same_course_for_every_method():
    layouts = [course_layout(CourseConfig(trials=50, seed=SEED, method=m)) for m in METHODS]
    assert all(layout == layouts[0] for layout in layouts[1:])
    assert course_layout(CourseConfig(trials=50, seed=SEED + 1)) != layouts[0]
    # a longer course starts with the shorter one
    assert course_layout(CourseConfig(trials=80, seed=SEED))[:50] == layouts[0]


@pytest.mark.parametrize("gap,heights,depths", [((GAP_FLOOR_M, 3.0), (0.04, 0.12), (0.05, 0.15)),
                                                ((1.5, 1.5), (0.2, 0.2), (0.1, 0.1)),
                                                ((0.8, 6.0), (0.031, 0.05), (0.01, 0.3))])
def test_the_layout_keeps_its_ranges_and_the_minimum_gap(gap, heights, depths):
    for seed in range(3):
        config = CourseConfig(trials=400, seed=seed, gap_m=gap, heights_m=heights, depths_m=depths)
        layout = course_layout(config)
        assert [o.index for o in layout] == list(range(400))
        assert config.start_min_m <= layout[0].near_m <= config.start_max_m and layout[0].gap_m is None
        for a, b in zip(layout, layout[1:]):
            assert gap[0] <= b.gap_m <= gap[1]
            assert math.isclose(b.near_m - (a.near_m + a.depth_m), b.gap_m, abs_tol=1e-9)
        for o in layout:
            assert heights[0] - 5e-5 <= o.height_m <= heights[1] + 5e-5 and o.height_m > 0.03
            assert depths[0] - 5e-5 <= o.depth_m <= depths[1] + 5e-5
            assert o.height_m == round(o.height_m, 4) and o.depth_m == round(o.depth_m, 4)
        # the run-wide values the learn configuration checks: the tallest and the deepest
        assert (config.obstacle_height_m, config.obstacle_depth_m, config.obstacle_heights_m) == \
            (heights[1], depths[1], ())


@pytest.mark.parametrize("kwargs,words", [
    ({"gap_m": (GAP_FLOOR_M - 0.1, 3.0)}, f"below {GAP_FLOOR_M:g} m, the closest spacing the leg recovers from"),
    ({"gap_m": (2.0, 1.0)}, "gap_m: MIN must not exceed MAX"),
    ({"heights_m": (0.03, 0.1)}, "heights_m: 0.03,0.1 m is outside (0.03, 0.5] m"),
    ({"heights_m": (0.05, 0.25)}, "above the leg's"),
    ({"heights_m": (0.05, 0.22), "depths_m": (0.05, 0.3)}, "for the deepest block, 0.3 m"),
    ({"depths_m": (0.05, 0.4)}, "depths_m: 0.05,0.4 m is outside [0.01, 0.3] m"),
    ({"depths_m": (0.1,)}, "depths_m: (0.1,) is not MIN,MAX"),
    ({"heights_m": (0.05, float("nan"))}, "heights_m"),
])
def test_bad_ranges_are_refused_naming_the_range(kwargs, words):
    with pytest.raises(ValueError) as exc:
        CourseConfig(trials=5, **kwargs)
    assert words in str(exc.value)


def test_rolling_success_is_over_the_last_window():
    trials = [{"success": s} for s in (True, False, True, True, False, False)]
    assert rolling_success(trials, 2) == [1.0, 0.5, 0.5, 1.0, 0.5, 0.0]
    assert rolling_success(trials, 10) == pytest.approx([1, 1 / 2, 2 / 3, 3 / 4, 3 / 5, 3 / 6])


# ---- the walk --------------------------------------------------------------------------------------------------


def test_the_course_is_walked_in_order_with_the_next_obstacles_in_the_world():
    config = CourseConfig(trials=OBSTACLES, seed=SEED, method="oracle", gap_m=(GAP_FLOOR_M, GAP_FLOOR_M + 0.2))
    run = CourseRun(config)
    try:
        run.bring_up()
        placed = []
        for i in range(OBSTACLES):
            run.trials.append(run.trial(i))
            placed.append([o.index for o in run._placed])
        with pytest.raises(ValueError, match="in order"):
            run.trial(0)
    finally:
        run.close()
    layout = course_layout(config)
    for t, o in zip(run.trials, layout):
        assert set(COURSE_FIELDS) <= set(t)
        assert (t["obstacle_height_m"], t["obstacle_depth_m"], t["course_near_m"], t["gap_m"]) == \
            (o.height_m, o.depth_m, o.near_m, o.gap_m)
        # the trial ends past_obstacle_m past the far edge (one physics step's travel at most beyond)
        assert o.near_m + o.depth_m + config.past_obstacle_m <= t["walked_m"] < o.near_m + o.depth_m + 0.46
    # while crossing one the next ones were already there (the sensor could see them); passed ones are gone
    assert placed[0] == [1, 2] and placed[-1] == []
    assert all(t["success"] for t in run.trials)  # the oracle, low blocks, gaps the leg recovers from


def test_the_rail_rewinds_with_the_obstacles_in_place(monkeypatch):
    monkeypatch.setattr(CourseRun, "REWIND_AFTER_M", 3.0)
    config = CourseConfig(trials=4, seed=SEED, method="oracle", heights_m=(0.05, 0.06))
    run = CourseRun(config)
    try:
        run.bring_up()
        x = []
        for i in range(4):
            run.trials.append(run.trial(i))
            x.append(run.ls.plant.carriage_x_m)
    finally:
        run.close()
    assert max(x) < 6.0  # the rig was moved back...
    walked = [t["walked_m"] for t in run.trials]
    assert walked == sorted(walked) and walked[-1] > 8.0  # ...but the course's distance goes on
    assert all(t["success"] for t in run.trials)


def _same_records(a: Path, b: Path) -> None:
    result = compare(read(a), read(b))
    assert result["same"], result["first_difference"]


def test_a_stopped_course_resumes_to_the_records_of_an_uninterrupted_one(tmp_path, monkeypatch):
    base = CourseConfig(trials=OBSTACLES, seed=SEED, gap_m=(GAP_FLOOR_M, 1.2))
    whole = course_into(base, ("paper",), tmp_path / "whole", figure=False)
    assert whole["summary"]["paper"]["obstacles"] == OBSTACLES

    real_trial = CourseRun.trial

    def stop_at_second(self, index, on_step=None):
        if index == 1:
            raise KeyboardInterrupt
        return real_trial(self, index, on_step)

    monkeypatch.setattr(CourseRun, "trial", stop_at_second)
    with pytest.raises(RunStopped) as exc:
        course_into(base, ("paper",), tmp_path / "stopped", figure=False)
    assert exc.value.recorded == 1
    assert len((tmp_path / "stopped" / "paper" / TRIALS_FILE).read_text().splitlines()) == 2  # header + 1
    monkeypatch.setattr(CourseRun, "trial", real_trial)
    again = course_into(base, ("paper",), tmp_path / "stopped", figure=False)
    _same_records(tmp_path / "whole" / "paper", tmp_path / "stopped" / "paper")
    assert again["summary"] == whole["summary"] and again["layout"] == whole["layout"]


def test_every_method_walks_the_same_course_and_the_figure_is_written(tmp_path):
    base = CourseConfig(trials=2, seed=SEED)
    course = course_into(base, ("none", "oracle"), tmp_path, window=2)
    near = {m: [t["course_near_m"] for t in learn_into(course_mod.method_config(base, m), tmp_path / m).metrics[
        "trials"]] for m in ("none", "oracle")}
    assert near["none"] == near["oracle"] == [o["near_m"] for o in course["layout"]]
    for name in ("course.png", "course.svg"):
        assert (tmp_path / "figures" / name).stat().st_size > 1000
    saved = json.loads((tmp_path / "course.json").read_text())
    assert saved["format"] == "course" and saved["methods"] == ["none", "oracle"]
    assert set(saved["summary"]) == {"none", "oracle"} and saved["summary"]["oracle"]["obstacles"] == 2


def test_a_course_folder_with_other_files_is_refused(tmp_path):
    (tmp_path / "thesis.tex").write_text("precious")
    with pytest.raises(course_mod.InputError, match="not a course's"):
        course_into(CourseConfig(trials=1), ("none",), tmp_path)
    assert (tmp_path / "thesis.tex").read_text() == "precious"


def test_the_figure_draws_each_methods_rolling_success_against_distance(tmp_path):
    from hil.analysis.course_figures import success_by_distance

    runs = {"paper": [{"success": s, "walked_m": 2.0 * (i + 1)} for i, s in enumerate((False, True, True))],
            "oracle": [{"success": True, "walked_m": 2.1 * (i + 1)} for i in range(3)]}
    layout = course_layout(CourseConfig(trials=3, seed=SEED))
    drawn = success_by_distance(runs, tmp_path, window=2, layout=layout)
    assert drawn["paper"] == {"walked_m": [2.0, 4.0, 6.0], "success": [0.0, 0.5, 1.0]}
    assert drawn["layout"]["near_m"] == [o.near_m for o in layout]
    assert (tmp_path / "course.png").exists() and (tmp_path / "course.svg").exists()
