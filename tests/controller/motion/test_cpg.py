"""The ring oscillator, the muscle filter and the leg's kinematics."""

from __future__ import annotations

import math
import random

import pytest

from controller.motion.cpg import CpgConfig, CpgOutput, RingOscillator
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


class _ReferenceRing:
    """The ring's state, step and clip as written before their 500 Hz tuning (attribute reads,
    _duration_s, min/max), to compare with bit for bit. A class of its own, not a subclass of
    RingOscillator: a compiled (mypyc) class cannot be subclassed by an interpreted one."""

    def __init__(self, config: CpgConfig) -> None:
        self.config = config
        self.n_half = config.units_per_half
        self.n_units = 2 * self.n_half
        self.burst_s = config.burst_s
        self.amplitude = 1.0
        self.active = 0
        self.adaptation = 0.0
        self.rates = [0.0] * self.n_units
        self.rates[0] = 1.0
        self.step_index = 0
        self._pending_onset = True

    def _duration_s(self, unit: int) -> float:
        half = self.config.stance_s if unit < self.n_half else self.burst_s
        return half / self.n_half

    def set_burst_s(self, burst_s: float) -> float:
        c = self.config
        self.burst_s = min(c.burst_max_s, max(c.burst_min_s, burst_s))
        return self.burst_s

    def step(self, dt_s: float):
        onset = self._pending_onset
        self._pending_onset = False
        remaining = dt_s
        for _ in range(self.n_units):
            rate = 1.0 / self._duration_s(self.active)
            need = (1.0 - self.adaptation) / rate
            if remaining < need:
                self.adaptation += remaining * rate
                break
            remaining -= need
            self.active = (self.active + 1) % self.n_units
            self.adaptation = 0.0
            if self.active == 0:
                self.step_index += 1
                onset = True
        tau = self.config.activation_tau_s
        k = 1.0 if tau <= 0.0 else min(1.0, dt_s / tau)
        for i in range(self.n_units):
            target = 1.0 if i == self.active else 0.0
            self.rates[i] += k * (target - self.rates[i])
        flexing = self.active >= self.n_half
        phase = ((self.active % self.n_half) + self.adaptation) / self.n_half
        drive = self.amplitude * sum(self.rates[self.n_half :])
        return (onset, flexing, phase, drive, self.step_index)


@pytest.mark.parametrize("config", [CpgConfig(), CpgConfig(units_per_half=3, activation_tau_s=0.001)],
                         ids=["default", "three-units-fast"])
def test_step_and_clip_are_the_reference_bit_for_bit(config):
    """Random tick lengths (late and zero ones too), burst requests (NaN and infinite too) and
    amplitudes: every output and the state equal the reference's exactly (==, not approx)."""
    rng = random.Random(11)
    ring, ref = RingOscillator(config), _ReferenceRing(config)
    for i in range(20000):
        dt = rng.choice([0.002, 0.002, 0.002, 0.0, 0.0041, rng.uniform(0.0, 0.5)])
        out = ring.step(dt)
        assert tuple(out) == ref.step(dt) and type(out) is CpgOutput and out.step_index == ref.step_index
        burst = rng.choice([rng.uniform(0.0, 1.0), math.nan, math.inf, -math.inf, 0.15, 0.6])
        assert ring.set_burst_s(burst) == ref.set_burst_s(burst)
        ring.amplitude = ref.amplitude = rng.choice([1.0, 1.9])
        assert (ring.active, ring.adaptation, ring.rates, ring.burst_s) == (ref.active, ref.adaptation, ref.rates,
                                                                         ref.burst_s)
    assert ring.step_index > 100
