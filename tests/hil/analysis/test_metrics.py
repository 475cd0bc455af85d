"""The figures every report shares, defined once (hil.analysis.metrics)."""

from __future__ import annotations

import pytest

from hil.analysis.metrics import last_window, late_window, success_last, window_success

T, F = True, False


def test_success_last_is_over_the_last_n_trials_or_all_of_them_when_fewer():
    assert success_last([F] * 10 + [T] * 50) == 1.0
    assert success_last([F] * 10 + [T] * 49) == 49 / 50
    assert success_last([F, T, T, T]) == 0.75  # fewer than 50: all of them
    assert success_last([]) is None
    assert success_last([{"success": F}, {"success": T}], n=1) == 1.0  # trial dicts or booleans
    trials = [{"success": x} for x in [F] * 60 + [T] * 90]
    assert success_last(trials, 50) == window_success(trials, 101, 150)
    with pytest.raises(ValueError):
        success_last([T], n=0)


def test_the_late_windows():
    assert last_window(150) == (101, 150) and last_window(20) == (1, 20) and last_window(60, 10) == (51, 60)
    assert late_window(200) == (101, 150) and late_window(120) == (71, 120)
