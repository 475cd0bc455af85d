"""The fixed-rate control loop: one :meth:`ControlLoop.tick` per period.

The loop is driven by a clock it does not own: the lockstep harness calls ``tick`` with the
simulated time, the daemon with the monotonic clock. Each tick integrates the CPG once with the
measured dt (capped at ``max_dt_factor`` periods), so a late tick never double-steps the CPG;
a tick whose measured period exceeds ``late_factor`` periods is counted in ``late_ticks``.

A tick: drain the bus, update the supervisor, then by phase: hold (arming), ramp, or walk
(CPG -> premotor burst length -> foot trajectory -> inverse kinematics -> muscle low-pass ->
Set_Input_Pos for each axis). While walking, every tick also runs the range filter, the
height estimator and the contact reflexes; every step onset gates the encoded range (with the
height context) into the premotor's memory and sets the lift reflex's amplitude for the coming
swing.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import can

from controller.io.axis import AxisLink
from controller.io.bus import BusIO
from controller.config import ControllerConfig
from controller.motion.cpg import CpgOutput, RingOscillator
from controller.motion.gait import FootTrajectory
from controller.stepping.height import HeightEstimator
from controller.stepping.encoder import RangeEncoder
from controller.motion.kinematics import forward, inverse
from controller.stepping.learner import AdaptivePremotor
from controller.motion.muscle import LowPass
from controller.stepping.premotor import Premotor
from controller.stepping.range_filter import RangeFilter
from controller.stepping.reflexes import ContactReflexes, Reflex, lift_amplitude
from controller.io.sensors import SensorLink
from controller.supervisor import Phase, Supervisor
from protocol import AxisState, BusContract, ControlMode, InputMode


@dataclass
class StepRecord:
    """One step cycle as the controller lived it.

    Attributes:
        index: step number (0 = the first stance after the ramp).
        onset_s: time of the step onset (stance start) [s].
        burst_s: burst length commanded when the swing of this cycle began [s] (NaN until then).
        swing_s: measured swing duration [s] (NaN until the next onset).
        gated_range_m: the filtered range gated at the onset [m] (None: no target in view).
        cell: the encoder cell gated into memory (None: none).
        modulation_s: the gated cell's weight, the burst change the gate asked for [s].
        amplitude: the CPG amplitude for this cycle (above 1: the lift reflex fired).
        context: the obstacle-height context passed to the premotor at the gate (None: unknown
            or no target in view; see :mod:`controller.stepping.height`).
    """

    index: int
    onset_s: float
    burst_s: float = math.nan
    swing_s: float = math.nan
    swing_start_s: float = math.nan
    gated_range_m: float | None = None
    cell: int | None = None
    modulation_s: float = 0.0
    amplitude: float = 1.0
    context: int | None = None


@dataclass
class LoopStats:
    ticks: int = 0
    command_ticks: int = 0
    late_ticks: int = 0
    max_period_s: float = 0.0
    steps: list[StepRecord] = field(default_factory=list)
    reflexes: list[Reflex] = field(default_factory=list)


class ControlLoop:
    def __init__(self, config: ControllerConfig, bus: can.BusABC, premotor: Premotor | None = None,
                 contract: BusContract | None = None) -> None:
        self.config = config
        contract = contract or BusContract.load()
        self.axes = [AxisLink(a, contract) for a in config.axes]
        self.hip = next(a for a in self.axes if a.name == "hip")
        self.knee = next(a for a in self.axes if a.name == "knee")
        self.sensors = SensorLink(config.sensor_node_id)
        self.io = BusIO(bus, contract, self.axes, self.sensors)
        self.supervisor = Supervisor(self.axes, self.sensors, config.heartbeat_timeout_s, config.bringup_timeout_s,
                                     config.stale_heartbeat_s)
        self.cpg = RingOscillator(config.cpg)
        self.encoder = RangeEncoder(config.encoder)
        self.range_filter = RangeFilter(config.range_filter)
        self.height = HeightEstimator(config.height)
        self._profile_samples_seen = 0
        self.reflexes = ContactReflexes(config.reflexes)
        self.premotor: Premotor = premotor or AdaptivePremotor(
            self.encoder.n_cells, config.cpg.burst_s, config.learner
        )
        self._range_samples_seen = 0
        self.trajectory = FootTrajectory(config.gait, config.cpg, config.geometry)
        self.muscles = {a.name: LowPass(config.gait.muscle_tau_s) for a in self.axes}
        self.stats = LoopStats()
        self.last_cpg: CpgOutput | None = None
        self._last_tick_s = math.nan
        self._ramp_from: dict[str, float] = {}
        self._ramp_to = dict(zip(("hip", "knee"), inverse(config.geometry, *self.trajectory.start_pose())))
        self._last_idle_s = -math.inf
        self._was_flexing = False

    @property
    def phase(self) -> Phase:
        return self.supervisor.phase

    def tick(self, now_s: float) -> None:
        period = self.config.period_s
        if math.isnan(self._last_tick_s):
            dt = period
        else:
            dt = now_s - self._last_tick_s
            if dt > self.config.late_factor * period:
                self.stats.late_ticks += 1
            self.stats.max_period_s = max(self.stats.max_period_s, dt)
        self._last_tick_s = now_s
        self.stats.ticks += 1
        dt = min(max(dt, 0.0), self.config.max_dt_factor * period)

        self.io.drain(now_s)
        sup = self.supervisor
        before = sup.phase
        sup.update(now_s)
        phase = sup.phase
        if phase is Phase.ARMING:
            self._arm(now_s)
        elif phase is Phase.RAMP:
            if before is not Phase.RAMP:
                self._ramp_from = {a.name: a.pos_rad for a in self.axes}
                for a in self.axes:
                    self.muscles[a.name].reset(a.pos_rad)
            self._ramp(now_s)
        elif phase is Phase.WALK:
            self._walk(now_s, dt)
        elif phase is Phase.FAULT:
            self._safe_stop(now_s)

    # -- phases ----------------------------------------------------------------------------
    def _arm(self, now_s: float) -> None:
        if self.supervisor.arm_due(now_s):
            for a in self.axes:
                if not a.closed_loop:
                    self.io.send(a.clear_errors_frame())
                    self.io.send(a.mode_frame(ControlMode.POSITION_CONTROL, InputMode.PASSTHROUGH))
                    self.io.send(a.limits_frame())
                    self.io.send(a.state_frame(AxisState.CLOSED_LOOP_CONTROL))
        # hold the measured position (an armed axis then stays put, and its watchdog is fed)
        for a in self.axes:
            self.io.send(a.pos_frame(a.pos_rad))
        self.stats.command_ticks += 1

    def _ramp(self, now_s: float) -> None:
        ramp_s = self.config.gait.ramp_s
        s = 1.0 if ramp_s <= 0 else min(1.0, (now_s - self.supervisor.phase_t_s) / ramp_s)
        w = 0.5 * (1.0 - math.cos(math.pi * s))
        for a in self.axes:
            q0 = self._ramp_from[a.name]
            self.io.send(a.pos_frame(q0 + (self._ramp_to[a.name] - q0) * w))
        self.stats.command_ticks += 1
        if s >= 1.0:
            self.cpg.reset()
            for a in self.axes:
                self.muscles[a.name].reset(self._ramp_to[a.name])
            self.supervisor.enter(Phase.WALK, now_s)

    def _sense(self, now_s: float) -> None:
        """Feed the range filter: predict every tick, correct on each new range sample; give each
        new profile sample to the height estimator with the filtered range (no target: cleared)."""
        f = self.range_filter
        f.predict(now_s)
        s = self.sensors
        if s.range_samples != self._range_samples_seen:
            self._range_samples_seen = s.range_samples
            f.reading(s.range_m, s.range_valid, s.range_t_s)
        estimate = f.estimate_m
        if s.profile_samples != self._profile_samples_seen:
            self._profile_samples_seen = s.profile_samples
            self.height.update(s.profile_m, estimate)
        elif estimate is None:
            self.height.clear()

    def foot_height_m(self) -> float:
        """Foot height above the ground from the encoders (NaN before the first reading)."""
        g = self.config.geometry
        _x, z = forward(g, self.hip.pos_rad, self.knee.pos_rad)
        return z + g.hip_height_m - g.foot_radius_m

    def _gate(self, now_s: float) -> StepRecord:
        gated = self.range_filter.estimate_m
        cell = self.encoder.cell(gated)
        context = self.height.context
        self.premotor.on_step_onset(now_s, cell, context=context)
        self.cpg.amplitude = lift_amplitude(self.config.reflexes, gated)
        return StepRecord(index=len(self.stats.steps), onset_s=now_s, gated_range_m=gated, cell=cell,
                          modulation_s=self.premotor.gated_weight(), amplitude=self.cpg.amplitude, context=context)

    def _walk(self, now_s: float, dt: float) -> None:
        self._sense(now_s)
        out = self.cpg.step(dt)
        steps = self.stats.steps
        if out.onset:
            if steps and not math.isnan(steps[-1].swing_start_s):
                steps[-1].swing_s = now_s - steps[-1].swing_start_s
            steps.append(self._gate(now_s))
        reflex = self.reflexes.update(now_s, out, self.sensors.foot, self.sensors.shin, self.foot_height_m)
        if reflex is not None:
            self.stats.reflexes.append(reflex)
            self.premotor.on_reflex(reflex.kind, now_s)
        burst = self.cpg.set_burst_s(self.premotor.burst_s(now_s))
        if out.flexing and not self._was_flexing and steps:
            steps[-1].burst_s = burst
            steps[-1].swing_start_s = now_s
        self._was_flexing = out.flexing
        self.last_cpg = out
        x, z = self.trajectory.target(out)
        hip, knee = inverse(self.config.geometry, x, z)
        self.io.send(self.hip.pos_frame(self.muscles["hip"](hip, dt)))
        self.io.send(self.knee.pos_frame(self.muscles["knee"](knee, dt)))
        self.stats.command_ticks += 1

    def _safe_stop(self, now_s: float) -> None:
        if now_s - self._last_idle_s >= 0.1:
            self._last_idle_s = now_s
            for a in self.axes:
                self.io.send(a.state_frame(AxisState.IDLE))
