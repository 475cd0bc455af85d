"""The ring oscillator, the muscle filter and the leg's kinematics."""

from __future__ import annotations

import math

import pytest

from controller.motion.cpg import CpgConfig, RingOscillator
from controller.motion.kinematics import LegGeometry, forward, inverse
from controller.motion.muscle import LowPass


def run(cpg: RingOscillator, seconds: float, dt: float = 0.002):
    onsets, flex = [], []
    for i in range(int(round(seconds / dt))):
        out = cpg.step(dt)
        if out.onset:
            onsets.append((i + 1) * dt)
        flex.append(out.flexing)
    return onsets, flex


@pytest.mark.parametrize("burst_s", [0.2, 0.3, 0.45])
def test_period_is_stance_plus_burst_and_onset_fires_once_per_cycle(burst_s):
    cpg = RingOscillator(CpgConfig(stance_s=0.4, burst_s=burst_s))
    onsets, flex = run(cpg, 5.0)
    periods = [b - a for a, b in zip(onsets[1:], onsets[2:])]
    assert periods and all(p == pytest.approx(0.4 + burst_s, abs=0.0021) for p in periods)
    assert sum(flex) * 0.002 / 5.0 == pytest.approx(burst_s / (0.4 + burst_s), abs=0.02)


def test_burst_is_clipped_to_safe_bounds():
    cpg = RingOscillator(CpgConfig(burst_min_s=0.15, burst_max_s=0.6))
    assert cpg.set_burst_s(5.0) == 0.6
    assert cpg.set_burst_s(0.0) == 0.15


def test_a_late_tick_advances_the_ring_once_by_its_dt():
    a, b = RingOscillator(CpgConfig()), RingOscillator(CpgConfig())
    for _ in range(10):
        a.step(0.002)
    b.step(0.02)
    assert (a.active, a.adaptation) == (b.active, pytest.approx(b.adaptation))


def test_ring_rates_are_smooth_and_flexor_drive_scales_with_amplitude():
    cpg = RingOscillator(CpgConfig())
    cpg.amplitude = 2.0
    drives = [cpg.step(0.002).flexor_drive for _ in range(500)]
    assert max(drives) == pytest.approx(2.0, abs=0.05)
    assert max(abs(b - a) for a, b in zip(drives, drives[1:])) < 0.25  # no jumps


def test_low_pass_is_rate_independent():
    fast, slow = LowPass(0.05), LowPass(0.05)
    for _ in range(100):
        fast(1.0, 0.001)
    for _ in range(10):
        slow(1.0, 0.01)
    assert fast.y == pytest.approx(slow.y, rel=1e-9)
    assert fast.y == pytest.approx(1 - math.exp(-0.1 / 0.05))


@pytest.mark.parametrize("x,z", [(0.1, -0.455), (-0.1, -0.455), (0.0, -0.37), (0.12, -0.33), (-0.05, -0.25)])
def test_inverse_kinematics_round_trips(x, z):
    g = LegGeometry()
    hip, knee = inverse(g, x, z)
    assert knee <= 0.0
    assert forward(g, hip, knee) == pytest.approx((x, z), abs=1e-9)


def test_unreachable_targets_give_a_valid_pose_along_the_same_direction():
    g = LegGeometry()
    hip, knee = inverse(g, 0.0, -2.0)
    x, z = forward(g, hip, knee)
    assert math.isfinite(hip) and math.isfinite(knee)
    assert x == pytest.approx(0.0, abs=1e-9) and z == pytest.approx(-0.4995, abs=1e-3)
