"""Figures are checked by the numbers they plot; each file exists and is not empty."""

from __future__ import annotations

import numpy as np
import pytest

from hil import figures
from hil.analysis import autocorrelation, autocorrelation_peak, footfall_std_by_step


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
