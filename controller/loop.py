"""The fixed-rate control loop: one :meth:`ControlLoop.tick` per period.

The loop is driven by a clock it does not own: the lockstep harness calls ``tick`` with the
simulated time, the daemon with the monotonic clock. Each tick integrates the CPG once with the
measured dt (capped at ``max_dt_factor`` periods), so a late tick never double-steps the CPG;
a tick whose measured period exceeds ``late_factor`` periods is counted in ``late_ticks``.

A tick: drain the bus (a frame from another master, one only a master sends to our nodes, is a
latched FAULT in that very tick), update the supervisor, then by phase: IDLE to an axis not idle
(inactive; with ``auto_arm``, the arm request in the tick INACTIVE is reached from WAIT_NODES),
hold (arming), ramp, or walk (CPG -> premotor burst length -> foot trajectory -> inverse
kinematics -> muscle low-pass -> Set_Input_Pos for each axis), or IDLE (fault). While
walking, every tick also runs the range filter, the height estimator and the contact reflexes;
every step onset gates the encoded range (with the height context) into the premotor's memory
and sets the lift reflex's amplitude for the coming swing.

**The operator's commands** (:meth:`ControlLoop.request_arm`, :meth:`~ControlLoop.request_disarm`,
:meth:`~ControlLoop.request_estop`, :meth:`~ControlLoop.request_clear_faults`) are called
between ticks, from the loop's own thread. Each returns None when accepted or a one-line reason
when refused, and logs what it did. Arming never sends Clear_Errors: an axis that reports an
error (a latched Estop, a watchdog trip, ...) refuses the arm, named with its error, until the
faults are cleared on purpose (:meth:`~ControlLoop.request_clear_faults`, the only sender of
Clear_Errors). :meth:`ControlLoop.status` is the loop's state as JSON-serialisable values.
"""

from __future__ import annotations

import logging
import math
from collections import Counter
from dataclasses import dataclass, field, replace
from typing import Callable, Final

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
from controller.settings.file import DriverSettings
from controller.supervisor import ACTIVE_PHASES, Phase, Supervisor, error_names, error_text
from protocol import AxisState, BusContract, ControlMode, InputMode
from protocol.endpoints import WATCHDOG_TIMEOUT

MIN_LIFT_AMPLITUDE: Final = 1.0
"""A premotor's lift never lowers the swing below the CPG's own step height."""
MAX_LIFT_AMPLITUDE: Final = 5.0
"""The largest amplitude ``reflexes.lift_amplitude`` may be set to: a premotor's lift may not exceed it."""

log = logging.getLogger(__name__)

IDLE_RESEND_S = 0.1
"""IDLE is sent again this often [s] to an axis that should be idle (FAULT, INACTIVE) and is not."""


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
                                     config.stale_heartbeat_s, health=config.health)
        self.encoder = RangeEncoder(config.encoder)
        self.range_filter = RangeFilter(config.range_filter)
        self.height = HeightEstimator(config.height)
        self._profile_samples_seen = 0
        self.reflexes = ContactReflexes(config.reflexes)
        self.premotor: Premotor = premotor or AdaptivePremotor(
            self.encoder.n_cells, config.cpg.burst_s, config.learner
        )
        # a premotor that asks for a longer swing than the CPG's configured bound (the improved
        # learner's crossing, controller.stepping.improved rule 24) says how long, and the CPG clips
        # to that instead; the controller's own premotor has none, so the deployed bound holds
        longest: float | None = getattr(self.premotor, "longest_burst_s", None)
        self.cpg = RingOscillator(config.cpg if longest is None else replace(config.cpg, burst_max_s=longest))
        # a premotor that also learns the lift (controller.stepping.premotor.LiftingPremotor) sets the
        # amplitude and hears each reflex in full; any other gets the hardwired lift reflex
        self._premotor_lift: Callable[[float | None, int | None], float] | None = getattr(
            self.premotor, "lift_amplitude", None)
        self._premotor_reflex: Callable[[Reflex], None] | None = getattr(self.premotor, "on_contact_reflex", None)
        # a premotor that shapes a tucked swing's descent (controller.stepping.improved, rule 18) says,
        # at each gate after the lift, where this cycle's tucked swing starts down (NaN: the gait's)
        self._premotor_descend: Callable[[], float] | None = getattr(self.premotor, "tucked_descend_phase", None)
        self._descend_phase = math.nan
        # a premotor that wants the ground speed its range sensor sees gets, at each gate with a
        # target in view, the filter's closing speed and its variance
        self._premotor_speed: Callable[[float, float], None] | None = getattr(
            self.premotor, "observe_closing_speed", None)
        # a premotor that senses the ground speed may tell the stance, at each touchdown, how fast to
        # sweep back (controller.stepping.improved, rule 19; NaN: as it is)
        self._premotor_stance: Callable[[], float] | None = getattr(self.premotor, "stance_speed_m_s", None)
        self._range_samples_seen = 0
        self.trajectory = FootTrajectory(config.gait, config.cpg, config.geometry)
        self.muscles = {a.name: LowPass(config.gait.muscle_tau_s) for a in self.axes}
        self._foot_height_m = self.foot_height_m  # bound once: the reflexes get it every tick
        self._hip_muscle = self.muscles["hip"]
        self._knee_muscle = self.muscles["knee"]
        # tick's constants (the config is frozen): the same products it would compute every tick
        self._period_s = config.period_s
        self._late_period_s = config.late_factor * self._period_s
        self._max_dt_s = config.max_dt_factor * self._period_s
        self._geometry = config.geometry  # read every tick (the config is a plain Python object)
        self.stats = LoopStats()
        self.last_cpg: CpgOutput | None = None
        self._last_tick_s = math.nan
        self._ramp_from: dict[str, float] = {}
        self._ramp_to = dict(zip(("hip", "knee"), inverse(config.geometry, *self.trajectory.start_pose())))
        self._last_idle_s = -math.inf
        self._was_flexing = False
        self.arm_blocked: str | None = None  # why arming is refused now (set by the daemon), or None
        self._foreign_seen = 0  # frames from another master already turned into a fault
        self._foreign_snapshot: Counter[int] = Counter()
        self._auto_arm_pending = False
        self._last_refusal: str | None = None
        # The drivers' command watchdog written at arming (RxSdo) and read back: the deploy file's
        # [drivers] watchdog_timeout_s, which the daemon sets here; its default otherwise.
        self.drivers_watchdog_timeout_s: float = DriverSettings().watchdog_timeout_s
        self._watchdog_written_at = math.nan  # phase_t_s of the arming it was written for
        txsdo = contract.codec("TxSdo")
        for a in self.axes:  # the read-backs: TxSdo from each axis to AxisLink.on_txsdo
            self.io.listen(a.txsdo_id, txsdo, a.on_txsdo)

    @property
    def phase(self) -> Phase:
        return self.supervisor.phase

    @property
    def lifecycle(self) -> str:
        """"inactive" (WAIT_NODES, INACTIVE), "active" (ARMING, RAMP, WALK) or "fault"."""
        return self.supervisor.lifecycle

    def tick(self, now_s: float) -> None:
        stats = self.stats
        if math.isnan(self._last_tick_s):
            dt = self._period_s
        else:
            dt = now_s - self._last_tick_s
            if dt > self._late_period_s:
                stats.late_ticks += 1
            if dt > stats.max_period_s:  # max(stats.max_period_s, dt), without the call
                stats.max_period_s = dt
        self._last_tick_s = now_s
        stats.ticks += 1
        # min(max(dt, 0.0), max_dt_s), without the calls
        if dt < 0.0:
            dt = 0.0
        if dt > self._max_dt_s:
            dt = self._max_dt_s

        io = self.io
        io.drain(now_s)
        sup = self.supervisor
        if io.dropped.get("unexpected_sender", 0) != self._foreign_seen:  # (.get: no Counter.__missing__ call)
            self._another_master(now_s)
        before = sup.phase
        sup.update(now_s)
        for a in sup.check_watchdog_confirmations(now_s):
            self._write_watchdog(a, now_s)  # no read-back yet, or another value: again
        phase = sup.phase
        if phase is Phase.WALK:  # the phase of nearly every tick, tested first
            self._walk(now_s, dt)
            return
        if phase is Phase.INACTIVE:
            if before is Phase.WAIT_NODES:
                self._auto_arm_pending = self.config.auto_arm
                self._last_refusal = None
            if self._auto_arm_pending:
                self._auto_arm(now_s)
                phase = sup.phase
        if phase is Phase.INACTIVE:
            self._idle_if_not(now_s)
        elif phase is Phase.ARMING:
            self._arm(now_s)
        elif phase is Phase.RAMP:
            if before is not Phase.RAMP:
                self._ramp_from = {a.name: a.pos_rad for a in self.axes}
                for a in self.axes:
                    self.muscles[a.name].reset(a.pos_rad)
            self._ramp(now_s)
        elif phase is Phase.FAULT:
            self._safe_stop(now_s)

    # -- the operator's commands -----------------------------------------------------------
    def request_arm(self, now_s: float) -> str | None:
        """INACTIVE -> ARMING. Refused (the reason returned) outside INACTIVE, while
        ``arm_blocked``, with a silent node, an axis reporting an error (named, with its error:
        clear the faults first) or an axis not IDLE. Never sends Clear_Errors."""
        reason = self._arm_refusal(now_s)
        if reason is not None:
            log.warning("arm refused at t=%.3f s: %s", now_s, reason)
            return reason
        self._auto_arm_pending = False
        self._last_refusal = None
        log.info("arm at t=%.3f s: arming %s", now_s, ", ".join(a.name for a in self.axes))
        self.supervisor.arm(now_s)
        return None

    def _arm_refusal(self, now_s: float) -> str | None:
        sup = self.supervisor
        if sup.phase is not Phase.INACTIVE:
            return f"cannot arm in phase {sup.phase.value}: only from inactive"
        if self.arm_blocked:
            return self.arm_blocked
        silent = sup.silent_nodes(now_s)
        if silent:
            return f"node(s) silent: {', '.join(silent)}"
        errors = [f"{a.name}: {error_text(a.error)}" for a in self.axes if a.error]
        if errors:
            return f"axis error(s) {'; '.join(errors)}: clear faults first"
        busy = [f"{a.name}: {a.state.name}" for a in self.axes if a.state is not AxisState.IDLE]
        if busy:
            return f"axis not IDLE ({'; '.join(busy)})"
        return None

    def _auto_arm(self, now_s: float) -> None:
        """``auto_arm``: request the arm in the tick INACTIVE is reached from WAIT_NODES; while it
        is refused, again every ``ARM_RETRY_S`` (each new reason logged once)."""
        sup = self.supervisor
        if now_s - sup.last_arm_request_s < sup.ARM_RETRY_S and self._last_refusal is not None:
            return
        reason = self._arm_refusal(now_s)
        if reason is None:
            log.info("auto_arm: every node heard, arming by itself")
            self.request_arm(now_s)
            return
        sup.last_arm_request_s = now_s
        if reason != self._last_refusal:
            log.warning("auto_arm: arm refused at t=%.3f s: %s (retrying every %g s)", now_s, reason,
                        sup.ARM_RETRY_S)
        self._last_refusal = reason

    def request_disarm(self, now_s: float) -> str | None:
        """ARMING/RAMP/WALK -> INACTIVE: every axis is sent IDLE (not a fault)."""
        sup = self.supervisor
        if sup.phase not in ACTIVE_PHASES:
            reason = f"not armed (phase {sup.phase.value})"
            log.warning("disarm refused at t=%.3f s: %s", now_s, reason)
            return reason
        for a in self.axes:
            self.io.send(a.state_frame(AxisState.IDLE), now_s)
        self._last_idle_s = now_s
        self._auto_arm_pending = False
        log.warning("disarm at t=%.3f s (in %s): IDLE sent to every axis", now_s, sup.phase.value)
        sup.disarm(now_s)
        return None

    def request_estop(self, now_s: float) -> str | None:
        """Any phase: ODrive's Estop to every axis (each disarms and latches ESTOP_REQUESTED until
        Clear_Errors) and FAULT, cause "estop by operator". Never refused."""
        for a in self.axes:
            self.io.send(a.estop_frame(), now_s)
        log.error("estop by operator at t=%.3f s (in %s): Estop sent to every axis", now_s,
                  self.supervisor.phase.value)
        self.supervisor.fault("estop by operator", now_s)
        return None

    def request_clear_faults(self, now_s: float) -> str | None:
        """FAULT, INACTIVE or WAIT_NODES: Clear_Errors to every axis (each axis's error before is
        logged); from FAULT back to WAIT_NODES, where the nodes are heard afresh. Refused while
        armed. The only place Clear_Errors is ever sent."""
        sup = self.supervisor
        if sup.phase in ACTIVE_PHASES:
            reason = f"armed (phase {sup.phase.value}): disarm first"
            log.warning("clear faults refused at t=%.3f s: %s", now_s, reason)
            return reason
        for a in self.axes:
            log.warning("clear faults at t=%.3f s: Clear_Errors to %s (error before: %s, state %s)", now_s, a.name,
                        error_text(a.error), a.state.name)
            self.io.send(a.clear_errors_frame(), now_s)
        self._foreign_seen = self.io.dropped["unexpected_sender"]
        self._foreign_snapshot = Counter(self.io.foreign)
        if sup.phase is Phase.FAULT:
            sup.clear_fault(now_s)
        return None

    def status(self) -> dict:
        """The loop's state, JSON-serialisable."""
        sup = self.supervisor
        axes = {}
        for a in self.axes:
            axes[a.name] = {"state": a.state.name, "error": int(a.error), "error_names": error_names(a.error),
                            "pos_rad": a.pos_rad if math.isfinite(a.pos_rad) else None,
                            "bus_voltage_v": a.bus_voltage_v}
        s = self.stats
        return {"phase": sup.phase.value, "lifecycle": sup.lifecycle, "fault_cause": sup.fault_cause,
                "fault_t_s": sup.fault_t_s if math.isfinite(sup.fault_t_s) else None, "axes": axes,
                "ticks": s.ticks, "late_ticks": s.late_ticks, "max_period_s": s.max_period_s,
                "steps": len(s.steps), "reflexes": len(s.reflexes), "arm_blocked": self.arm_blocked}

    # -- the bus -----------------------------------------------------------------------------
    def _another_master(self, now_s: float) -> None:
        """Frames only a master sends, to our nodes, that we did not send: a latched FAULT."""
        io = self.io
        n = io.dropped["unexpected_sender"] - self._foreign_seen
        self._foreign_seen = io.dropped["unexpected_sender"]
        new = io.foreign - self._foreign_snapshot
        self._foreign_snapshot = Counter(io.foreign)
        ids = ", ".join(f"0x{arb:03x}" for arb in new) or "?"
        self.supervisor.fault(f"another master on the bus: id {ids}, {n} frame(s)", now_s)

    # -- phases ----------------------------------------------------------------------------
    def _idle_if_not(self, now_s: float) -> None:
        """INACTIVE: IDLE to any axis whose heartbeat says it is not (again every IDLE_RESEND_S)."""
        busy = [a for a in self.axes if a.state is not AxisState.IDLE]
        if busy and now_s - self._last_idle_s >= IDLE_RESEND_S:
            self._last_idle_s = now_s
            for a in busy:
                self.io.send(a.state_frame(AxisState.IDLE))

    def _arm(self, now_s: float) -> None:
        sup = self.supervisor
        if sup.arm_due(now_s):
            # The drivers' watchdog timeout: written and read back once per arming, with its first
            # frames and before the closed-loop request; the reply is checked when it comes
            # (Supervisor.check_watchdog_confirmations), arming never waits for it.
            first = self._watchdog_written_at != sup.phase_t_s
            self._watchdog_written_at = sup.phase_t_s
            for a in self.axes:
                if not a.closed_loop:
                    self.io.send(a.mode_frame(ControlMode.POSITION_CONTROL, InputMode.PASSTHROUGH))
                    self.io.send(a.limits_frame())
                if first:
                    self._write_watchdog(a, now_s)
                if not a.closed_loop:
                    self.io.send(a.state_frame(AxisState.CLOSED_LOOP_CONTROL))
        # hold the measured position (an armed axis then stays put, and its watchdog is fed)
        for a in self.axes:
            self.io.send(a.pos_frame(a.pos_rad))
        self.stats.command_ticks += 1

    def _write_watchdog(self, a: AxisLink, now_s: float) -> None:
        """RxSdo: write ``drivers_watchdog_timeout_s`` to the axis's axis0.config.watchdog_timeout,
        then read it back (endpoint id from protocol.endpoints: UNVERIFIED)."""
        value = self.drivers_watchdog_timeout_s
        self.io.send(a.sdo_write_frame(WATCHDOG_TIMEOUT, value))
        self.io.send(a.sdo_read_frame(WATCHDOG_TIMEOUT))
        self.supervisor.expect_watchdog(a, value, now_s)

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
        if s.profile_samples != self._profile_samples_seen:
            self._profile_samples_seen = s.profile_samples
            self.height.update(s.profile_m, f.estimate_m)
        elif not f.active:  # estimate_m is None (read only when a profile sample needs it)
            self.height.clear()

    def foot_height_m(self) -> float:
        """Foot height above the ground from the encoders (NaN before the first reading)."""
        g = self._geometry
        _x, z = forward(g, self.hip.pos_rad, self.knee.pos_rad)
        return z + g.hip_height_m - g.foot_radius_m

    def _gate(self, now_s: float) -> StepRecord:
        gated = self.range_filter.estimate_m
        cell = self.encoder.cell(gated)
        context = self.height.context
        self.premotor.on_step_onset(now_s, cell, context=context)
        amplitude = lift_amplitude(self.config.reflexes, gated)
        if self._premotor_speed is not None and gated is not None:
            rate, variance = self.range_filter.rate_m_s, self.range_filter.rate_var_m2_s2
            if rate is not None and variance is not None:
                self._premotor_speed(-rate, variance)
        if self._premotor_lift is not None:
            asked = self._premotor_lift(gated, context)
            # the CPG's amplitude stays within the reflex setting's declared range whatever a
            # premotor asks (a NaN keeps the hardwired reflex's)
            if asked == asked:
                amplitude = MIN_LIFT_AMPLITUDE if asked < MIN_LIFT_AMPLITUDE else (
                    MAX_LIFT_AMPLITUDE if asked > MAX_LIFT_AMPLITUDE else asked)
        self.cpg.amplitude = amplitude
        self._descend_phase = math.nan if self._premotor_descend is None else self._premotor_descend()
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
        foot, shin = self.sensors.take_contacts()
        reflex = self.reflexes.update(now_s, out, foot, shin, self._foot_height_m)
        if reflex is not None:
            self.stats.reflexes.append(reflex)
            if self._premotor_reflex is not None:
                self._premotor_reflex(reflex)
            else:
                self.premotor.on_reflex(reflex.kind, now_s)
        burst = self.cpg.set_burst_s(self.premotor.burst_s(now_s))
        if out.flexing and not self._was_flexing and steps:
            steps[-1].burst_s = burst
            steps[-1].swing_start_s = now_s
        if self._was_flexing and not out.flexing and self._premotor_stance is not None:
            self.trajectory.follow_ground_speed(self._premotor_stance())  # a touchdown: the stance begins
        self._was_flexing = out.flexing
        self.last_cpg = out
        x, z = self.trajectory.target(out, self.cpg.amplitude, self._descend_phase)
        hip, knee = inverse(self._geometry, x, z)
        send = self.io.send
        send(self.hip.pos_frame(self._hip_muscle(hip, dt)))
        send(self.knee.pos_frame(self._knee_muscle(knee, dt)))
        self.stats.command_ticks += 1

    def _safe_stop(self, now_s: float) -> None:
        if now_s - self._last_idle_s >= IDLE_RESEND_S:
            self._last_idle_s = now_s
            for a in self.axes:
                self.io.send(a.state_frame(AxisState.IDLE))
