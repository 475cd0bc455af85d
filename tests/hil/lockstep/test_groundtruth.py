"""The ground truth's footfall tracker, on a scripted plant (contacts and foot positions given)."""

from __future__ import annotations

import math

import pytest

from hil.lockstep.groundtruth import FootfallTracker


class ScriptedPlant:
    """A plant stepping through a script of (foot switch, foot x, foot z) per physics step (1 kHz);
    counts the foot-position queries."""

    def __init__(self, script: list[tuple[bool, float, float]]) -> None:
        self.script = script
        self.k = 0
        self.t_s = 0.0
        self.foot_queries = 0

    def step(self) -> None:
        self.k += 1
        self.t_s = self.k * 0.001

    def contacts(self) -> tuple[bool, bool]:
        return self.script[self.k][0], False

    def foot_position(self) -> tuple[float, float]:
        self.foot_queries += 1
        _, x, z = self.script[self.k]
        return x, z


def gait(steps: int = 3, stance: int = 300, swing: int = 200) -> list[tuple[bool, float, float]]:
    """Stance on the ground, then a swing whose height is a sine (peak 0.05 m); x advances in the air."""
    out, x = [], 0.0
    for _ in range(steps):
        out += [(True, x, 0.0)] * stance
        for i in range(swing):
            x += 0.001
            out.append((False, x, 0.05 * math.sin(math.pi * (i + 1) / (swing + 1))))
    out += [(True, x, 0.0)] * stance
    return out


def track(clearance: bool) -> tuple[FootfallTracker, ScriptedPlant]:
    plant = ScriptedPlant(gait())
    tracker = FootfallTracker(plant, clearance=clearance)
    for _ in range(len(plant.script) - 1):
        tracker.update()
        plant.step()
    return tracker, plant


def test_footfalls_and_clearance_of_a_scripted_gait():
    tracker, plant = track(clearance=True)
    assert tracker.touchdown_t_s == pytest.approx([0.5, 1.0, 1.5])
    assert tracker.footfalls_x_m == pytest.approx([0.2, 0.4, 0.6])
    # mid-swing is the middle half: its lowest point is at a quarter of the swing, sin(pi/4) * 0.05
    assert tracker.swing_clearance_m == pytest.approx([0.05 * math.sin(math.pi * 0.25)] * 3, abs=5e-4)
    assert plant.foot_queries > 3 * 150  # every step in the air


def test_without_clearance_the_same_footfalls_with_one_query_a_touchdown():
    full, _ = track(clearance=True)
    lean, plant = track(clearance=False)
    assert lean.footfalls_x_m == full.footfalls_x_m and lean.touchdown_t_s == full.touchdown_t_s
    assert lean.swing_clearance_m == [] and plant.foot_queries == 3
