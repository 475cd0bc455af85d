"""Bring-up and supervision: the controller's lifecycle, its phases and what moves it between them.

=============  ===========  ==================================================================
phase          lifecycle    what it is, and what leaves it
=============  ===========  ==================================================================
WAIT_NODES     inactive     until every axis and the sensor board has sent a heartbeat and every
                            axis an encoder estimate (-> INACTIVE); nothing is sent. No node
                            after ``bringup_timeout_s``: FAULT.
INACTIVE       inactive     every node heard, the axes IDLE (an axis whose heartbeat says
                            otherwise is sent IDLE, every 0.1 s): waiting for an arm command
                            (:meth:`controller.loop.ControlLoop.request_arm`; with
                            ``auto_arm`` the loop requests it itself in the tick it enters
                            INACTIVE from WAIT_NODES). A silent node is a FAULT; an axis
                            reporting an error is not (it is IDLE) but blocks arming.
ARMING         active       Set_Controller_Mode(POSITION_CONTROL, PASSTHROUGH), Set_Limits (the
                            axis's configured velocity and current limits) and
                            Set_Axis_State(CLOSED_LOOP_CONTROL) to each axis, repeated every
                            0.5 s, holding the measured position, until every heartbeat reports
                            CLOSED_LOOP_CONTROL with no error (-> RAMP). Never Clear_Errors: an
                            axis with a latched error is refused at the arm command, and an
                            axis that reports an error while arming, a silent node, or no closed
                            loop after ``bringup_timeout_s`` is a FAULT. With the first arming
                            frames each axis is also sent RxSdo writing the drivers' watchdog
                            timeout (``ControlLoop.drivers_watchdog_timeout_s``: the deploy file's
                            ``[drivers] watchdog_timeout_s``) and reading it back; arming never
                            waits for the TxSdo reply, but a reply with another value, or none
                            within 0.5 s, is a FAULT (:meth:`Supervisor.check_watchdog_confirmations`).
RAMP           active       a smooth move from the pose found at arming to the gait's start pose.
WALK           active       the CPG runs.
FAULT          fault        an axis left closed loop or reported an error while armed (its
                            heartbeat's error, by name, in the tick it arrives), a driver's
                            health reading beyond its bound in an active phase
                            (:mod:`controller.io.health`), a node went silent, another master commanded our nodes, or the operator's
                            Estop: every axis is sent IDLE (repeated each heartbeat period), no
                            position target is sent again and learning is paused (the premotor
                            hears no more gates or reflexes). The cause and the time are kept
                            (``fault_cause``, ``fault_t_s``) and logged. FAULT is latched: only
                            clearing the faults (:meth:`~controller.loop.ControlLoop.
                            request_clear_faults`: Clear_Errors to every axis, the one place it
                            is sent) or a restart of the controller leaves it, for WAIT_NODES.
=============  ===========  ==================================================================

The operator's commands (:class:`controller.loop.ControlLoop`): arm (INACTIVE -> ARMING),
disarm (ARMING/RAMP/WALK -> INACTIVE, axes IDLE, not a fault), estop (any phase: ODrive's
Estop to every axis, which latches ESTOP_REQUESTED in the drivers, and FAULT), clear faults
(FAULT, INACTIVE or WAIT_NODES: Clear_Errors to every axis; from FAULT back to WAIT_NODES, where
every node must send a heartbeat again, after the clearing, before INACTIVE).

A node is silent when no valid frame at all has come from it for ``silence_timeout_s`` (any
accepted frame is a sign of life: an axis's encoder estimates at 500 Hz, the sensor board's
readings at 50-200 Hz, so random frame loss does not look like silence), or when its heartbeat
alone has not come for ``stale_heartbeat_s`` (its reported state would no longer be known).
"""

from __future__ import annotations

import enum
import logging
import math
from typing import ClassVar, Final

from controller.io.axis import AxisLink
from controller.io.health import HealthConfig, health_fault
from controller.io.sensors import SensorLink
from protocol.contract import sdo_bits_value, sdo_value_bits
from protocol.endpoints import WATCHDOG_TIMEOUT
from protocol import AxisError, AxisState

log = logging.getLogger(__name__)


class Phase(enum.Enum):
    WAIT_NODES = "wait_nodes"
    INACTIVE = "inactive"
    ARMING = "arming"
    RAMP = "ramp"
    WALK = "walk"
    FAULT = "fault"


LIFECYCLE = {Phase.WAIT_NODES: "inactive", Phase.INACTIVE: "inactive", Phase.ARMING: "active",
             Phase.RAMP: "active", Phase.WALK: "active", Phase.FAULT: "fault"}
"""Each phase's lifecycle state, in ros2_control's words ("unconfigured" is the daemon before its
bus is open: the loop never reports it)."""

ACTIVE_PHASES: Final = (Phase.ARMING, Phase.RAMP, Phase.WALK)
"""The phases in which the axes are (being) armed. A tuple, not a set: ``in`` a tuple compares by
identity, in C; ``in`` a set calls ``Enum.__hash__`` (Python code) on every test, every tick."""


def error_text(bits: int) -> str:
    """ODrive 0.6 error bits by name with their value, e.g. "ESTOP_REQUESTED (0x2000000)"."""
    return f"{'|'.join(error_names(bits)) or 'none'} ({bits:#x})"


def error_names(bits: int) -> list[str]:
    """The names of ODrive 0.6 error bits set in ``bits`` (bits it does not define: "0x..")."""
    names: list[str] = [e.name for e in AxisError if e.value and bits & e.value]  # type: ignore[misc]  # a member with a value has a name
    unknown = bits & ~_KNOWN_ERRORS
    if unknown:
        names.append(f"{unknown:#x}")
    return names


_KNOWN_ERRORS = int(sum(e.value for e in AxisError))
# Bound once: a member read through its enum class goes through the metaclass's attribute hook
# (about 1,000 instructions), and this one is read every tick.
_CLOSED_LOOP: Final = AxisState.CLOSED_LOOP_CONTROL


def _latest(a_s: float, b_s: float) -> float:
    """``max(a_s, b_s)`` (the same choice: ``b_s`` only if greater), without the builtin's generic
    call, which compiled boxes both floats (every tick)."""
    return b_s if b_s > a_s else a_s


class Supervisor:
    ARM_RETRY_S: ClassVar[float] = 0.5

    def __init__(self, axes: list[AxisLink], sensors: SensorLink, silence_timeout_s: float,
                 bringup_timeout_s: float, stale_heartbeat_s: float = math.inf,
                 health: HealthConfig = HealthConfig()) -> None:
        self.axes = axes
        self.pending_watchdog: dict[str, tuple] = {}  # name -> (axis, written, first sent, last sent, last read)
        self.health = health
        self.sensors = sensors
        self.silence_timeout_s = silence_timeout_s
        self.stale_heartbeat_s = max(stale_heartbeat_s, silence_timeout_s)
        self.bringup_timeout_s = bringup_timeout_s
        self.phase = Phase.WAIT_NODES
        self.phase_t_s = math.nan
        self.fault_cause = ""
        self.fault_t_s = math.nan
        self.last_arm_request_s = -math.inf
        # WAIT_NODES takes only heartbeats later than this (after clearing faults: fresh ones)
        self.heard_after_s = -math.inf

    @property
    def lifecycle(self) -> str:
        return LIFECYCLE[self.phase]

    def enter(self, phase: Phase, now_s: float) -> None:
        log.info("phase %s -> %s at t=%.3f s", self.phase.value, phase.value, now_s)
        self.phase = phase
        self.phase_t_s = now_s

    def fault(self, cause: str, now_s: float) -> None:
        if self.phase is not Phase.FAULT:
            self.fault_cause = cause
            self.fault_t_s = now_s
            log.error("safe stop at t=%.3f s: %s", now_s, cause)
            self.enter(Phase.FAULT, now_s)

    def arm(self, now_s: float) -> None:
        """INACTIVE -> ARMING (the caller checked that it may); the first arming frames are due at once."""
        self.last_arm_request_s = -math.inf
        self.enter(Phase.ARMING, now_s)

    def disarm(self, now_s: float) -> None:
        """ARMING/RAMP/WALK -> INACTIVE (the caller sends IDLE)."""
        self.enter(Phase.INACTIVE, now_s)

    def clear_fault(self, now_s: float) -> None:
        """FAULT -> WAIT_NODES: every node must send a heartbeat again, after ``now_s``."""
        log.warning("fault cleared at t=%.3f s (was: %s at t=%.3f s)", now_s, self.fault_cause, self.fault_t_s)
        self.fault_cause = ""
        self.fault_t_s = math.nan
        self.heard_after_s = now_s
        self.enter(Phase.WAIT_NODES, now_s)

    def _last_seen(self) -> list[tuple[str, float, float]]:
        """(node, last valid frame of any kind, last heartbeat) for every node [s]."""
        s = self.sensors
        out = [(a.name, _latest(a.heartbeat_t_s, a.encoder_t_s), a.heartbeat_t_s) for a in self.axes]
        board_s = _latest(_latest(_latest(s.heartbeat_t_s, s.range_t_s), s.contacts_t_s), s.profile_t_s)
        out.append(("sensor_board", board_s, s.heartbeat_t_s))
        return out

    def silent_nodes(self, now_s: float) -> list[str]:
        """Nodes silent (no valid frame for ``silence_timeout_s``) or whose heartbeat is stale."""
        return [name for name, seen, beat in self._last_seen()
                if now_s - seen > self.silence_timeout_s or now_s - beat > self.stale_heartbeat_s]

    def _fault_if_silent(self, now_s: float) -> bool:
        silent = self.silent_nodes(now_s)
        if silent:
            self.fault(f"node(s) silent for more than {self.silence_timeout_s:g} s (or no heartbeat for "
                       f"{self.stale_heartbeat_s:g} s): {silent}", now_s)
        return bool(silent)

    def update(self, now_s: float) -> None:
        """Move between phases on what the bus has said; never sends anything itself."""
        if math.isnan(self.phase_t_s):
            self.phase_t_s = now_s
        phase = self.phase
        if phase in ACTIVE_PHASES:
            for a in self.axes:  # the drivers' health readings against their bounds
                cause = health_fault(self.health, a)
                if cause is not None:
                    self.fault(cause, now_s)
                    return
        if phase is Phase.WAIT_NODES:
            after = self.heard_after_s
            heard = all(now_s - beat <= self.silence_timeout_s and beat > after for _, _, beat in self._last_seen())
            if heard and all(math.isfinite(a.pos_rad) for a in self.axes):
                self.enter(Phase.INACTIVE, now_s)
            elif now_s - self.phase_t_s > self.bringup_timeout_s:
                self.fault(f"no heartbeat or encoder from {self.silent_nodes(now_s) or 'an axis'}", now_s)
        elif phase is Phase.INACTIVE:
            self._fault_if_silent(now_s)
        elif phase is Phase.ARMING:
            if all(a.closed_loop for a in self.axes):
                self.enter(Phase.RAMP, now_s)
                return
            for a in self.axes:
                if a.error:
                    self.fault(f"axis {a.name} reported {error_text(a.error)} while arming "
                               f"(state {a.state.name})", now_s)
                    return
            if self._fault_if_silent(now_s):
                return
            if now_s - self.phase_t_s > self.bringup_timeout_s:
                states = {a.name: (a.state.name, hex(a.error)) for a in self.axes}
                self.fault(f"axes did not reach closed loop: {states}", now_s)
        elif phase in (Phase.RAMP, Phase.WALK):
            if self._fault_if_silent(now_s):
                return
            for a in self.axes:
                if a.error and a.state is _CLOSED_LOOP:  # acted on in the tick it is drained
                    self.fault(f"axis {a.name} reported {error_text(a.error)} in closed loop", now_s)
                    return
                if not a.closed_loop:
                    self.fault(f"axis {a.name} left closed loop: state {a.state.name}, error {error_text(a.error)}", now_s)
                    return

    # -- the drivers' watchdog timeout, written with the arming frames and read back ---------------
    SDO_REPLY_TIMEOUT_S: ClassVar[float] = 0.5
    """The write and read-back of the watchdog timeout must agree within this long of the first
    write, else a FAULT [s]."""
    SDO_RETRY_S: ClassVar[float] = 0.1
    """No read-back this long after the last exchange, or one with another value (the write may
    have been lost on the bus): write and read again [s]."""

    def expect_watchdog(self, axis: AxisLink, written_s: float, now_s: float) -> None:
        """``axis`` was sent RxSdo writing ``written_s`` (as the float32 on the bus) to
        axis0.config.watchdog_timeout and a read of it at ``now_s``: :meth:`check_watchdog_confirmations`
        checks the reply when it comes (a repeated exchange keeps the first one's deadline). Arming
        does not wait for it."""
        written = sdo_bits_value(sdo_value_bits(written_s))
        first = self.pending_watchdog.get(axis.name, (axis, written, now_s, now_s, None))[2]
        self.pending_watchdog[axis.name] = (axis, written, first, now_s, None)

    def check_watchdog_confirmations(self, now_s: float) -> list[AxisLink]:
        """Each expected read-back: the same value confirms it (logged). No reply within
        :attr:`SDO_RETRY_S` of the last exchange, or another value, before
        :attr:`SDO_REPLY_TIMEOUT_S` has passed since the first: the axes returned, for the loop to
        write and read again (frames get lost; a lost write reads back the old value). At the
        deadline, a latched FAULT naming what was written and what was read. Outside the active
        phases the expectations are dropped (a disarm or a fault ends the arming they belonged to)."""
        pending = self.pending_watchdog
        if not pending:
            return []
        if self.phase not in ACTIVE_PHASES:
            pending.clear()
            return []
        again = []
        for name, (axis, written, first_s, last_s, last_read) in list(pending.items()):
            read = axis.sdo_reply(WATCHDOG_TIMEOUT, since_s=last_s)
            if read is not None and read == written:
                del pending[name]
                log.info("watchdog timeout confirmed: %s reads %g s", name, read)
                continue
            if read is not None:
                last_read = read
                pending[name] = (axis, written, first_s, last_s, read)
            if now_s - first_s > self.SDO_REPLY_TIMEOUT_S:
                pending.clear()
                got = (f"no reply within {self.SDO_REPLY_TIMEOUT_S:g} s" if last_read is None else
                       f"read {last_read:g} s (written and read again for {self.SDO_REPLY_TIMEOUT_S:g} s)")
                self.fault(f"watchdog timeout not confirmed: {name} wrote {written:g} s, {got}", now_s)
                return []
            if read is not None or now_s - last_s >= self.SDO_RETRY_S:
                again.append(axis)
        return again

    def arm_due(self, now_s: float) -> bool:
        if now_s - self.last_arm_request_s >= self.ARM_RETRY_S:
            self.last_arm_request_s = now_s
            return True
        return False
