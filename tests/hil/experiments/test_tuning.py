"""Tuning the improved learner: only tuning seeds, only real settings."""

from __future__ import annotations

import pytest

from hil.experiments import tuning


def test_tuning_refuses_the_held_out_seeds():
    assert tuning.parse_seeds("0-2,99") == [0, 1, 2, 99]
    for text in ("1000", "90-100", "1000-1019"):
        with pytest.raises(ValueError, match="seeds 0-99 only"):
            tuning.parse_seeds(text)
    assert tuning.main(["--seeds", "1000-1019"]) == 2


def test_settings_are_checked_by_the_learners_configuration():
    assert tuning.parse_settings(["spread_fade=5", "learning=false"]) == {"spread_fade": 5, "learning": False}
    with pytest.raises(TypeError):
        tuning.parse_settings(["no_such_setting=1"])
    with pytest.raises(ValueError, match="spread_cells"):
        tuning.parse_settings(["spread_cells=-1"])
    assert tuning.main(["--set", "spread_cells"]) == 2
    with pytest.raises(ValueError, match="landing_on_top=maybe.*number, true or false"):
        tuning.parse_settings(["landing_on_top=maybe"])  # not JSON: named, not a bare decoder message


def test_one_tuning_run_goes_through_the_whole_stack():
    # the half-sine start (tucked_contexts 0): trial 0, from zero weights, fails on this seed
    r = tuning.run_seed(3, 2, {"spread_fade": 5.0, "tucked_contexts": 0}, (0.08,), failures_after=0)
    assert r["seed"] == 3 and len(r["late_by_height"]) == 2 and 0.0 <= r["success"] <= 1.0
    # one line per failed trial (trial 0 starts from zero weights), none without --failures-after
    assert r["failed"] and len(r["failures"]) == len(r["failed"])
    assert all(line.startswith("seed 3 trial ") for line in r["failures"])
    defaults = tuning.run_seed(3, 2, {}, (0.08,))
    assert defaults["failures"] == []
    assert defaults["blended_steps"] == 0  # at 0.08 m the contexts that start tucked read one-hot (rule 13)


def test_a_failure_line_names_the_last_gates_with_the_weights_held_as_the_trial_began():
    import numpy as np

    weights = np.zeros((4, 28))
    weights[1, 17], weights[1, 7] = 0.25, 0.5
    trial = {"index": 54, "obstacle_height_m": 0.08, "gated_cells": [None, 27, 17, 7, None],
             "gated_contexts": [None, 1, 1, 1, None],
             "gated_range_m": [1.8, 1.458, 1.111, 0.298, None], "footfalls_m": [-1.5, -1.187, -0.769, -0.377],
             "reflexes": [{"kind": "extension", "cause": "foot_on_top", "phase": 0.894, "swing": True, "t_s": 3.0}]}
    assert tuning.describe_failure(46, trial, weights) == (
        "seed 46 trial 54 (0.08 m): gates (cell@range:weight) 27@1.458:0.000 17@1.111:0.250 7@0.298:0.500 -@-:-; "
        "footfalls -1.187 -0.769 -0.377; reflex extension foot_on_top phase 0.89 swing")
    met = [((26, 17, 7), True), ((27, 17, 7), False), ((27, 17, 7), True), ((25, 15, 6), True)]
    assert tuning.describe_failure(46, trial, weights, met).endswith(
        "swing; path met before 2 (1 ok), last cell 3 (2 ok)")
    assert tuning.path_of(trial) == (27, 17, 7)


def test_controller_settings_are_named_checked_and_reach_the_run():
    assert tuning.parse_controller(["encoder.cell_width_m=0.02", "gait.tuck_full_amplitude=3.2"]) == {
        "encoder": {"cell_width_m": 0.02}, "gait": {"tuck_full_amplitude": 3.2}}
    assert tuning.controller_config({"encoder": {"cell_width_m": 0.02}}).encoder.n_cells == 56
    for item, message in (("encoder.cell_width_m", "section.name=value"), ("cell_width_m=0.02", "section.name=value"),
                          ("nowhere.x=1", "no controller section 'nowhere'"),
                          ("encoder.width=1", "encoder has no setting 'width'"),
                          ("encoder.cell_width_m=-1", "cell_width_m"), ("encoder.cell_width_m=x", "number")):
        with pytest.raises(ValueError, match=message):
            tuning.parse_controller([item])
    assert tuning.main(["--controller", "encoder.cell_width_m=-1"]) == 2
    r = tuning.run_seed(3, 2, {}, (0.08,), controller={"encoder": {"cell_width_m": 0.02}})
    assert r["per_50"] == [sum(1 for i in range(2) if i not in r["failed"])] and r["n_cells"] == 56


def test_conditions_are_named_checked_and_reach_the_run():
    assert tuning.parse_conditions(["rail_speed_m_s=0.45", "believed_rail_speed_m_s=0.5"]) == {
        "rail_speed_m_s": 0.45, "believed_rail_speed_m_s": 0.5}
    for item, message in (("rail_speed_m_s", "name=value"), ("seed=1000", "name one of"),
                          ("trials=5", "name one of"), ("range_noise_m=x", "number"),
                          ("rail_speed_m_s=-1", "ground_speed_m_s")):
        with pytest.raises(ValueError, match=message):
            tuning.parse_conditions([item])
    assert tuning.main(["--condition", "seed=1000"]) == 2  # no way round the held-out rule
    r = tuning.run_seed(3, 1, {}, (0.08,), conditions={"rail_speed_m_s": 0.45, "believed_rail_speed_m_s": 0.5})
    assert r["conditions"]["rail_speed_m_s"] == 0.45 and r["conditions"]["believed_rail_speed_m_s"] == 0.5
    assert tuning.run_seed(3, 1, {}, (0.08,))["conditions"]["rail_speed_m_s"] == 0.5


def test_a_descent_the_gait_would_not_take_is_refused_before_any_run(capsys):
    """Rule 18's phase must lie after the gait's rise (the swing would otherwise keep the gait's
    descent, silently): the builder refuses it, and the tool says so in one line before any run."""
    from hil.experiments.methods import build_improved

    with pytest.raises(ValueError, match="lifting_descend_phase must be 0 .* after gait.tuck_rise_phase = 0.2"):
        build_improved(tuning.controller_config({}), lifting_descend_phase=0.1)
    assert build_improved(tuning.controller_config({}), lifting_descend_phase=0.0).config.lifting_descend_phase == 0.0
    assert tuning.main(["--seeds", "3", "--set", "lifting_descend_phase=0.15"]) == 2
    assert tuning.main(["--seeds", "3", "--set", "lifting_descend_phase=0.4",
                        "--controller", "gait.tuck_rise_phase=0.45"]) == 2  # after 0.2, before that rise
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and all(line.startswith("tuning: error: improved.lifting_descend_phase") for line in err)
