"""An in-process CAN bus for the lockstep: python-can's ``BusABC``, without the costs lockstep never needs.

python-can's ``virtual`` bus (the reference, still selectable: :data:`BUSES`) deep-copies every
frame it delivers, puts it in a thread-safe ``queue.Queue`` and stamps it with ``time.time()``: what
threads and wall-clock readers need. The lockstep has neither: one thread steps the plant and
ticks the controller in turn, and nothing in the stack reads a frame's timestamp (the run is the
same for a seed whatever the wall clock). :class:`LocalBus` keeps python-can's semantics that
matter here (a frame sent reaches every *other* bus on the channel, each through its own queue,
in send order; a bus never hears its own frames; ``recv`` returns None when nothing waits) and
drops the rest: no copy (a frame is not changed after it is sent: senders build a new
``can.Message`` per frame, and a fault that changes a frame copies it first,
:class:`hil.faults.model.FaultInjector`), no lock, no clock read, no blocking (``recv``'s timeout
is not waited: in one thread nothing could arrive meanwhile).

Which bus a lockstep uses is its ``bus`` argument (:class:`hil.lockstep.harness.Lockstep`):
``"local"`` (the default) or ``"virtual"``; tests check both give the same records.
"""

from __future__ import annotations

from collections import deque
from typing import Any

import can
import can.bus  # (the base's own module: mypyc's code for a non-native subclass refers to it)

from protocol.compiled import interpreted

_CHANNELS: dict[str, list["LocalBus"]] = {}


@interpreted  # made by ABCMeta itself, with its own isinstance cache (protocol.compiled: compiled, it shared
# BusABC's, so that a virtual bus, once checked against BusABC, passed for a LocalBus and vice versa)
class LocalBus(can.bus.BusABC):
    """One node's end of an in-process channel (see the module doc). ``channel``: any name; the
    buses made with the same name hear each other."""

    def __init__(self, channel: str, **kwargs: Any) -> None:
        self.channel_id = channel
        self.channel_info = f"local channel {channel}"
        self._queue: deque[can.Message] = deque()
        self._peers = _CHANNELS.setdefault(channel, [])
        self._peers.append(self)
        super().__init__(channel=channel, **kwargs)

    def send(self, msg: can.Message, timeout: float | None = None) -> None:  # noqa: ARG002
        if self._is_shutdown:
            raise can.CanOperationError("the bus is shut down")
        for peer in self._peers:
            if peer is not self:
                peer._queue.append(msg)

    def recv(self, timeout: float | None = None) -> can.Message | None:  # noqa: ARG002
        """The next frame sent by another bus on the channel, or None (never waits)."""
        queue = self._queue
        return queue.popleft() if queue else None

    def _recv_internal(self, timeout: float | None):  # BusABC's hook; recv above does the work
        return self.recv(timeout), False

    def shutdown(self) -> None:
        if self._is_shutdown:
            return
        super().shutdown()
        if self in self._peers:
            self._peers.remove(self)
        if not self._peers:
            _CHANNELS.pop(self.channel_id, None)


def _virtual(channel: str) -> can.BusABC:
    return can.Bus(interface="virtual", channel=channel)


BUSES = {"local": LocalBus, "virtual": _virtual}
"""The in-process buses a lockstep can run on, by name: the one place a new one is added."""

__all__ = ["LocalBus", "BUSES"]
