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
    r = tuning.run_seed(3, 2, {"spread_fade": 5.0}, (0.08,))
    assert r["seed"] == 3 and len(r["late_by_height"]) == 2 and 0.0 <= r["success"] <= 1.0
