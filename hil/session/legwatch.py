"""A light watcher of the axes' Heartbeat frames on a SocketCAN channel, for safe-state timing.

:class:`HeartbeatWatcher` opens its own socket with a kernel filter that lets only the axes'
Heartbeat frames through (10 Hz per axis, so it costs next to nothing beside the 2,300 frames/s
on the bus), drains it every ``poll_s`` and keeps, per frame, the kernel's receive timestamp and
the reported axis state and error. The timestamps are python-can's SocketCAN ones:
``SO_TIMESTAMPNS``, i.e. CLOCK_REALTIME (``time.time()``), not the monotonic clock.

:func:`safe_state` answers: after an event at ``t_event`` [s, CLOCK_REALTIME], when did every
axis's Heartbeat first report IDLE?
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass
from typing import Any

import can

from protocol import AxisState, BusContract, arbitration_id

log = logging.getLogger(__name__)

HEARTBEAT_CMD = 0x01


@dataclass(frozen=True)
class Beat:
    """One Heartbeat as received: its time [s; for :class:`HeartbeatWatcher` the kernel timestamp,
    CLOCK_REALTIME; the lockstep fault matrix uses the simulated clock], axis, state, error bits."""

    t_unix: float
    axis: str
    state: int
    error: int


class HeartbeatWatcher(threading.Thread):
    """Records every Heartbeat of ``axes`` (name -> node id) on ``channel``.

    ``beats`` grows for the watcher's life (20 frames/s for two axes); read it after
    :meth:`stop`, or through :meth:`snapshot` while running.
    """

    def __init__(self, channel: str, axes: dict[str, int], poll_s: float = 0.005) -> None:
        super().__init__(name="heartbeat-watcher", daemon=True)
        from controller.daemon.fastbus import lean

        self.axes_by_id = {arbitration_id(node, HEARTBEAT_CMD): name for name, node in axes.items()}
        filters = [{"can_id": arb, "can_mask": 0x7FF, "extended": False} for arb in self.axes_by_id]
        self.raw = can.Bus(interface="socketcan", channel=channel, can_filters=filters)
        self.bus = lean(self.raw)  # with kernel timestamps
        self.codec = BusContract.load().codec("Heartbeat")
        self.poll_s = poll_s
        self.channel = channel
        self.beats: list[Beat] = []
        self.malformed = 0
        self.error: str | None = None
        self._lock = threading.Lock()
        self._halt = threading.Event()

    def _drain(self) -> None:
        recv = self.bus.recv
        msg = recv(0)
        while msg is not None:
            name = self.axes_by_id.get(msg.arbitration_id)
            if name is not None and not msg.is_remote_frame and len(msg.data) >= self.codec.dlc:
                error, state = self.codec.unpack(msg.data)[:2]
                with self._lock:
                    self.beats.append(Beat(msg.timestamp, name, int(state), int(error)))
            else:
                self.malformed += 1
            msg = recv(0)

    def run(self) -> None:
        try:
            while not self._halt.is_set():
                time.sleep(self.poll_s)
                self._drain()
            self._drain()
        except Exception as exc:  # noqa: BLE001 - reported in the metrics
            self.error = repr(exc)
            log.error("heartbeat watcher on %s: %s", self.channel, exc)

    def snapshot(self) -> list[Beat]:
        with self._lock:
            return list(self.beats)

    def stop(self) -> None:
        self._halt.set()
        self.join(timeout=5)
        self.raw.shutdown()


def safe_state(beats: list[Beat], axes: list[str], t_event_unix: float) -> dict[str, Any]:
    """When every axis's Heartbeat first reported IDLE after ``t_event_unix`` [s, on the beats' clock].

    Returns ``safe_state_ms`` (the latest of the axes' first IDLE heartbeats, from the event
    [ms]; None if some axis never reported IDLE), ``axes_idle_ms`` (per axis, None: never),
    ``states_before`` (each axis's last reported state before the event, by name) and
    ``heartbeats_after`` (beats seen after the event).
    """
    first: dict[str, float | None] = {a: None for a in axes}
    before: dict[str, str | None] = {a: None for a in axes}
    after = 0
    for b in sorted(beats, key=lambda b: b.t_unix):
        if b.axis not in first:
            continue
        if b.t_unix < t_event_unix:
            before[b.axis] = _state_name(b.state)
            continue
        after += 1
        if first[b.axis] is None and b.state == AxisState.IDLE:
            first[b.axis] = (b.t_unix - t_event_unix) * 1e3
    reached = all(v is not None for v in first.values())
    return {
        "safe_state_ms": max(first.values()) if reached and first else None,  # type: ignore[type-var]
        "axes_idle_ms": first,
        "states_before": before,
        "heartbeats_after": after,
    }


def _state_name(state: int) -> str:
    try:
        return AxisState(state).name
    except ValueError:
        return str(state)


__all__ = ["Beat", "HeartbeatWatcher", "safe_state"]
