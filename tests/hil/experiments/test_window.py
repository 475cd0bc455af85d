"""The take-off window: measured through the whole stack with the oracle, read honestly."""

from __future__ import annotations

import pytest

from hil.experiments import window
from hil.experiments.window import Landing, Window


def test_the_window_is_the_successful_span_bounded_by_the_nearest_failures():
    w = Window(0.2, (Landing(-0.25, -0.26, False, "foot_on_top"), Landing(-0.22, -0.203, False, "foot_on_top"),
                     Landing(-0.19, -0.185, True, None), Landing(-0.19, -0.178, True, None),
                     Landing(-0.19, -0.180, False, "shin"), Landing(-0.16, -0.16, False, "shin"),
                     Landing(-0.13, None, False, "shin")))
    assert w.inner_m == (-0.185, -0.178)
    assert w.outer_m == (-0.203, -0.16)
    least, most = w.width_m()
    assert least == pytest.approx(0.007) and most == pytest.approx(0.043)
    assert w.failures_inside == 1  # -0.180 failed between two successes: said, not hidden
    table = window.report([w], 0.05)
    assert "| 0.2 | 7 | 2 (1 failed inside) | -18.5 .. -17.8 | 0.7 / 4.3 |" in table
    assert "-20.3 (foot_on_top), -16.0 (shin)" in table and "| 0.14 .. 0.86 |" in table


def test_no_success_is_no_window_and_one_sided_failures_leave_the_bound_open():
    none = Window(0.22, (Landing(-0.2, -0.2, False, "shin"),))
    assert none.inner_m is None and none.width_m() == (None, None) and none.outer_m == (None, None)
    assert "| 0.22 | 1 | 0 | none | - / - |" in window.report([none], 0.04)
    open_near = Window(0.08, (Landing(-0.1, -0.1, True, None), Landing(-0.3, -0.3, False, "foot_on_top")))
    assert open_near.width_m() == (0.0, None)


def test_plans_parse_as_a_range_or_a_list_and_bad_input_is_one_line():
    assert window.parse_plans("-0.06:-0.12:0.03") == (-0.06, -0.09, -0.12)
    assert window.parse_plans("-0.1,-0.2") == (-0.1, -0.2)
    with pytest.raises(ValueError, match="step must be positive"):
        window.parse_plans("-0.06:-0.12:0")
    assert window.main(["--heights", "0.30"]) == 2  # above the leg's limit: refused before any run
    assert window.main(["--plans", "a:b:c"]) == 2
    assert window.main(["--trials", "0"]) == 2


def test_the_oracle_clears_from_inside_the_window_and_lands_on_top_from_too_far():
    # 0.08 m: a take-off 0.13 m before the face clears it; from 0.28 m the swing cannot reach over
    w = window.measure(0.08, (-0.13, -0.28), trials=2, seed=5)
    assert [x.success for x in w.landings] == [True, True, False, False]
    assert all(x.cause == "foot_on_top" for x in w.landings[2:])
    assert all(x.last_footfall_m is not None and abs(x.last_footfall_m - x.plan_m) < 0.05 for x in w.landings)


def test_a_controller_setting_reaches_the_measured_runs_and_a_bad_one_is_one_line(capsys):
    # 0.20 m, fully tucked: from 0.26 m the gait's descent (0.72) comes down on top of the block;
    # starting down at 0.84 of the swing carries the foot beyond it (docs/leg_limits.md)
    plan = (-0.26,)
    own = window.measure(0.20, plan, trials=2, seed=5, lift_margin_m=0.2)
    late = window.measure(0.20, plan, trials=2, seed=5, lift_margin_m=0.2,
                          controller={"gait": {"tuck_descend_phase": 0.84}})
    assert [x.success for x in own.landings] == [False, False]
    assert all(x.cause == "foot_on_top" for x in own.landings)
    assert [x.success for x in late.landings] == [True, True]
    assert window.main(["--controller", "gait.no_such=1"]) == 2
    assert window.main(["--controller", "gait.tuck_descend_phase=0.1"]) == 2  # before the rise: refused
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and all(line.startswith("window: error: ") for line in err)
