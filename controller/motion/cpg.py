"""The central pattern generator: a ring oscillator after Lewis (1996).

A ring of rate-coded units. The active unit bursts while its adaptation variable charges from 0
to 1; at threshold it inhibits itself and releases the next unit in the ring (post-inhibitory
rebound), so activity travels round the ring once per step cycle. The first half of the ring
drives the extensors (stance), the second half the flexors (swing). Each unit charges at
``units_per_half / duration``, so the flexor half bursts for ``burst_s``: the burst length is
the CPG's parameter that the premotor module modulates, and it may change at any tick (the
modulation is smooth because the adaptation keeps its charge and only its rate changes).

Outputs per tick (:class:`CpgOutput`): each unit's smooth rate output, the flexor drive (the
flexor units' summed rate times the amplitude, which the lift reflex raises), the phase within
the current half, and the *step onset* signal: one tick at the onset of the first extensor
unit, i.e. at touchdown, which gates the range encoder into short-term memory.

Modelling choice: the paper gives no equations. Units here are leaky integrators of a binary
burst (time constant ``activation_tau_s``); the handoff is the threshold event. This keeps the
ring's defining property (a burst travelling round a ring, one parameter per unit setting its
burst length) with a period that is exactly stance_s + burst_s.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

from controller.settings.schema import check_settings, setting
from protocol.compiled import interpreted


@interpreted  # a configuration: plain Python even when compiled (protocol.compiled)
@dataclass(frozen=True)
class CpgConfig:
    """The ring oscillator. The premotor module's burst is clipped to ``[burst_min_s, burst_max_s]``."""

    stance_s: float = setting(0.40, "s", 0.05, 5.0, "extension (stance) half of the ring")
    burst_s: float = setting(0.30, "s", 0.05, 5.0, "base burst length (swing)")
    burst_min_s: float = setting(0.15, "s", 0.05, 5.0, "shortest burst the premotor may ask for")
    burst_max_s: float = setting(0.60, "s", 0.05, 5.0, "longest burst the premotor may ask for")
    activation_tau_s: float = setting(0.02, "s", 0.001, 1.0, "time constant of each unit's output")
    units_per_half: int = setting(2, "units", 1, 8, "ring units per half")

    def __post_init__(self) -> None:
        check_settings(self, "cpg")
        if not self.burst_min_s <= self.burst_max_s:
            raise ValueError(f"cpg.burst_max_s must be at least cpg.burst_min_s = {self.burst_min_s} s, "
                             f"got {self.burst_max_s!r}")
        if not self.burst_min_s <= self.burst_s <= self.burst_max_s:
            raise ValueError(f"cpg.burst_s must be in [cpg.burst_min_s, cpg.burst_max_s] = "
                             f"[{self.burst_min_s}, {self.burst_max_s}] s, got {self.burst_s!r}")


class CpgOutput(NamedTuple):
    """What the CPG emits on one tick (immutable: a NamedTuple rather than a frozen dataclass,
    because one is built every tick and a frozen dataclass takes four times as long to build).

    Attributes:
        onset: True on the one tick a new step cycle (stance) begins.
        flexing: True while a flexor unit is active (swing).
        phase: progress through the current half, 0..1 (stance or swing).
        flexor_drive: summed rate of the flexor units times the amplitude, 0..amplitude.
        step_index: number of step onsets so far.
    """

    onset: bool
    flexing: bool
    phase: float
    flexor_drive: float
    step_index: int


class RingOscillator:
    """A ring of ``2 * units_per_half`` units; unit 0 starts the stance half."""

    def __init__(self, config: CpgConfig) -> None:
        self.config = config
        # the frozen config's times, read every tick, as typed attributes (compiled: C doubles, not
        # an attribute lookup on the config, a plain Python object)
        self._stance_s: float = config.stance_s
        self._burst_min_s: float = config.burst_min_s
        self._burst_max_s: float = config.burst_max_s
        self._activation_tau_s: float = config.activation_tau_s
        self.n_half = config.units_per_half
        self.n_units = 2 * self.n_half
        self.burst_s = config.burst_s
        self.amplitude = 1.0
        self.reset()

    def reset(self, start_unit: int = 0) -> None:
        self.active = start_unit
        self.adaptation = 0.0
        self.rates = [0.0] * self.n_units
        self.rates[start_unit] = 1.0
        self.step_index = 0
        self._pending_onset = start_unit == 0

    def set_burst_s(self, burst_s: float) -> float:
        """Set the flexion burst length, clipped to the configured safe bounds; returns it."""
        lo, hi = self._burst_min_s, self._burst_max_s
        # min(hi, max(lo, burst_s)) without the calls (every tick), the same choices: max keeps its
        # first argument unless the second is greater, min unless it is less
        burst_s = burst_s if burst_s > lo else lo
        self.burst_s = burst_s if burst_s < hi else hi
        return self.burst_s

    def _duration_s(self, unit: int) -> float:
        half = self._stance_s if unit < self.n_half else self.burst_s
        return half / self.n_half

    def step(self, dt_s: float) -> CpgOutput:
        """Advance by ``dt_s`` (one tick: callers never split a late tick into several)."""
        onset = self._pending_onset
        self._pending_onset = False
        remaining = dt_s
        # (500 Hz: the state in locals)
        n_half = self.n_half
        n_units = self.n_units
        active = self.active
        adaptation = self.adaptation
        # The handoff may happen inside this tick; carry the rest of dt into the next unit.
        for _ in range(n_units):
            rate = 1.0 / self._duration_s(active)
            need = (1.0 - adaptation) / rate
            if remaining < need:
                adaptation += remaining * rate
                break
            remaining -= need
            active = (active + 1) % n_units
            adaptation = 0.0
            if active == 0:
                self.step_index += 1
                onset = True
        self.active = active
        self.adaptation = adaptation
        tau = self._activation_tau_s
        k = 1.0 if tau <= 0.0 else dt_s / tau
        if not k < 1.0:  # min(1.0, dt_s / tau): 1.0 unless the quotient is less (NaN too)
            k = 1.0
        rates = self.rates
        for i in range(n_units):
            target = 1.0 if i == active else 0.0
            rates[i] += k * (target - rates[i])
        flexing = active >= n_half
        phase = ((active % n_half) + adaptation) / n_half
        drive = self.amplitude * sum(rates[n_half:])
        # CpgOutput(onset, ...) without its __new__, which is generated Python code (every tick)
        return tuple.__new__(CpgOutput, (onset, flexing, phase, drive, self.step_index))
