"""Fault injection on a python-can bus: a wrapper that cuts the bus.

:class:`CutBus` wraps a bus and drops everything sent through it and everything waiting to be
received, as if the cable were pulled. The harness swaps it in only when a fault is injected,
so the healthy hot path carries no wrapper.
"""

from __future__ import annotations

import can


class CutBus(can.BusABC):
    def __init__(self, inner: can.BusABC) -> None:
        self.inner = inner
        self.dropped = 0
        super().__init__(channel=getattr(inner, "channel_info", "cut"))

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self.dropped += 1

    def _recv_internal(self, timeout: float | None):
        while self.inner.recv(timeout=0.0) is not None:
            self.dropped += 1
        return None, False

    def shutdown(self) -> None:
        super().shutdown()
