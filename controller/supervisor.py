"""Bring-up and supervision: the controller's phases and what moves it between them.

WAIT_NODES  until every axis and the sensor board has sent a heartbeat (timeout: FAULT).
ARMING      Clear_Errors, Set_Controller_Mode(POSITION_CONTROL, PASSTHROUGH), Set_Limits (the
            axis's configured velocity and current limits) and Set_Axis_State(CLOSED_LOOP_CONTROL)
            to each axis, repeated every 0.5 s, holding the measured position, until every
            heartbeat reports CLOSED_LOOP_CONTROL with no error.
RAMP        a smooth move from the pose found at bring-up to the gait's start pose.
WALK        the CPG runs.
FAULT       an axis left closed loop or reported an error, or a node went silent: every axis is
            sent IDLE (repeated each heartbeat period), no position target is sent again and
            learning is paused (the premotor hears no more gates or reflexes). The cause and
            the time are kept (``fault_cause``, ``fault_t_s``) and logged. FAULT is latched:
            only a restart of the controller leaves it.

A node is silent when no valid frame at all has come from it for ``silence_timeout_s`` (any
accepted frame is a sign of life: an axis's encoder estimates at 500 Hz, the sensor board's
readings at 50-200 Hz, so random frame loss does not look like silence), or when its heartbeat
alone has not come for ``stale_heartbeat_s`` (its reported state would no longer be known).
"""

from __future__ import annotations

import enum
import logging
import math

from controller.io.axis import AxisLink
from controller.io.sensors import SensorLink

log = logging.getLogger(__name__)


class Phase(enum.Enum):
    WAIT_NODES = "wait_nodes"
    ARMING = "arming"
    RAMP = "ramp"
    WALK = "walk"
    FAULT = "fault"


class Supervisor:
    ARM_RETRY_S = 0.5

    def __init__(self, axes: list[AxisLink], sensors: SensorLink, silence_timeout_s: float,
                 bringup_timeout_s: float, stale_heartbeat_s: float = math.inf) -> None:
        self.axes = axes
        self.sensors = sensors
        self.silence_timeout_s = silence_timeout_s
        self.stale_heartbeat_s = max(stale_heartbeat_s, silence_timeout_s)
        self.bringup_timeout_s = bringup_timeout_s
        self.phase = Phase.WAIT_NODES
        self.phase_t_s = math.nan
        self.fault_cause = ""
        self.fault_t_s = math.nan
        self.last_arm_request_s = -math.inf

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

    def _last_seen(self) -> list[tuple[str, float, float]]:
        """(node, last valid frame of any kind, last heartbeat) for every node [s]."""
        s = self.sensors
        out = [(a.name, max(a.heartbeat_t_s, a.encoder_t_s), a.heartbeat_t_s) for a in self.axes]
        out.append(("sensor_board", max(s.heartbeat_t_s, s.range_t_s, s.contacts_t_s, s.profile_t_s), s.heartbeat_t_s))
        return out

    def silent_nodes(self, now_s: float) -> list[str]:
        """Nodes silent (no valid frame for ``silence_timeout_s``) or whose heartbeat is stale."""
        return [name for name, seen, beat in self._last_seen()
                if now_s - seen > self.silence_timeout_s or now_s - beat > self.stale_heartbeat_s]

    def update(self, now_s: float) -> None:
        """Move between phases on what the bus has said; never sends anything itself."""
        if math.isnan(self.phase_t_s):
            self.phase_t_s = now_s
        phase = self.phase
        if phase is Phase.WAIT_NODES:
            heard = all(now_s - beat <= self.silence_timeout_s for _, _, beat in self._last_seen())
            if heard and all(math.isfinite(a.pos_rad) for a in self.axes):
                self.enter(Phase.ARMING, now_s)
            elif now_s - self.phase_t_s > self.bringup_timeout_s:
                self.fault(f"no heartbeat or encoder from {self.silent_nodes(now_s) or 'an axis'}", now_s)
        elif phase is Phase.ARMING:
            if all(a.closed_loop for a in self.axes):
                self.enter(Phase.RAMP, now_s)
            elif now_s - self.phase_t_s > self.bringup_timeout_s:
                states = {a.name: (a.state.name, hex(a.error)) for a in self.axes}
                self.fault(f"axes did not reach closed loop: {states}", now_s)
        elif phase in (Phase.RAMP, Phase.WALK):
            silent = self.silent_nodes(now_s)
            if silent:
                self.fault(f"node(s) silent for more than {self.silence_timeout_s:g} s (or no heartbeat for "
                           f"{self.stale_heartbeat_s:g} s): {silent}", now_s)
                return
            for a in self.axes:
                if not a.closed_loop:
                    self.fault(f"axis {a.name} left closed loop: state {a.state.name}, error {a.error:#x}", now_s)
                    return

    def arm_due(self, now_s: float) -> bool:
        if now_s - self.last_arm_request_s >= self.ARM_RETRY_S:
            self.last_arm_request_s = now_s
            return True
        return False
