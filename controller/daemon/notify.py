"""What the controller daemon tells systemd, phase by phase (through :class:`controller.daemon.sdnotify.Notifier`).

- ``STATUS=`` on every phase change (``systemctl status`` shows it): the lifecycle state
  (``inactive``, ``active``, ``fault``), then the phase in words; the fault's cause in FAULT.
- ``READY=1`` once, when the daemon is first "inactive and healthy": the supervisor has left
  WAIT_NODES for INACTIVE (every axis and the sensor board heard, every axis's position known, the
  axes IDLE), or for a later phase in the same tick (``auto_arm`` arms in the tick INACTIVE is
  reached). The leg does not move at READY: it waits for ``elegant-stepping-leg arm``. Until
  READY the unit is "activating": a bring-up that fails (a node never heard: FAULT from
  WAIT_NODES) never sends READY, so systemd's ``TimeoutStartSec`` stops the daemon and
  ``Restart=on-failure`` retries (a leg that was not moving).
- ``WATCHDOG=1`` from the control loop itself, in every phase, FAULT included: a ping means that
  the loop ran (it is never sent from a thread). In FAULT the loop still runs and keeps the axes
  IDLE (resent every heartbeat period) and the fault is latched on purpose: a leg that faulted
  waits for a person (``elegant-stepping-leg status``, ``clear-faults``, ``arm``), so systemd must
  not restart a loop that is alive and safe. Only a loop that stops ticking stops pinging.
- ``STOPPING=1`` at the start of the shutdown (SIGTERM, SIGINT, SIGHUP, SIGUSR1 or the end of
  ``--seconds``), before the axes are sent IDLE and the weights saved.
"""

from __future__ import annotations

from controller.supervisor import Phase
from controller.daemon.sdnotify import Notifier

READY_PHASES = frozenset({Phase.INACTIVE, Phase.ARMING, Phase.RAMP, Phase.WALK})  # the first sends READY=1

STATUS = {
    Phase.WAIT_NODES: "inactive: waiting for the nodes' heartbeats",
    Phase.INACTIVE: "inactive: every node heard, axes IDLE; waiting for `elegant-stepping-leg arm`",
    Phase.ARMING: "active: arming the axes (POSITION_CONTROL/PASSTHROUGH, CLOSED_LOOP_CONTROL)",
    Phase.RAMP: "active: axes in closed loop, ramping to the start pose",
    Phase.WALK: "active: walking",
}


def phase_status(phase: Phase, fault_cause: str = "") -> str:
    """The one-line ``STATUS=`` for a phase: its lifecycle state, then the phase in words."""
    if phase is Phase.FAULT:
        return (f"fault: axes IDLE (latched: `elegant-stepping-leg clear-faults`, then `arm`): "
                f"{fault_cause or 'unknown cause'}")
    return STATUS[phase]


class DaemonNotify:
    """The daemon's notifications. Call :meth:`tick` every control tick, :meth:`phase` on each
    phase change, :meth:`stopping` when the shutdown begins."""

    def __init__(self, notifier: Notifier | None = None) -> None:
        self.notifier = Notifier() if notifier is None else notifier
        self.ready_sent = False

    def tick(self, now_s: float) -> None:
        self.notifier.watchdog(now_s)

    def phase(self, phase: Phase, fault_cause: str = "") -> None:
        status = phase_status(phase, fault_cause)
        if phase in READY_PHASES and not self.ready_sent:
            self.ready_sent = True
            self.notifier.ready(status)
        else:
            self.notifier.status(status)

    def stopping(self, stopped_by: str) -> None:
        self.notifier.stopping(f"stopping ({stopped_by}): axes to IDLE, saving the weights")

    def summary(self) -> dict[str, object]:
        return {**self.notifier.summary(), "ready_sent": self.ready_sent}

    def close(self) -> None:
        self.notifier.close()


__all__ = ["DaemonNotify", "phase_status", "READY_PHASES"]
