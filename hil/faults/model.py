"""Fault injection on a python-can bus: a faulty link, a cut cable, a silenced node.

:class:`FaultSpec` says what a faulty link does to each frame, independently per frame, with
given probabilities: drop it, delay it, duplicate it, reorder it with the next one, corrupt its
payload. :class:`FaultInjector` applies a spec to a stream of frames with a seeded numpy
generator, so a run with the same seed meets the same faults. It is a pure component (frames in,
frames out, on a clock it is given), used by both harnesses:

- lockstep: :class:`FaultyBus` wraps the controller's end of the virtual bus, one injector per
  direction, on the simulated clock; it can also silence nodes (every frame a node sends is
  lost, as if its transceiver died);
- HIL: the man-in-the-middle node (:mod:`hil.faults.mitm`) forwards between two SocketCAN channels
  through an injector per direction, on the monotonic clock.

What the faults model. CAN's CRC makes a corrupted frame on the wire an error frame and a
retransmission, so ``corrupt`` stands for what the CRC cannot catch: a faulty gateway or node
that passes bad payloads on (a byte replaced, or the payload cut short). ``drop`` is a frame
that never arrives (a gateway queue overflow, a receiver overrun), ``delay`` a frame held back
``delay_s`` (overtaken by the frames behind it), ``duplicate`` one delivered twice, ``reorder``
one held until the next frame has passed (or ``reorder_max_s`` has gone by).

:class:`CutBus` drops everything sent through it and everything waiting to be received, as if
the cable were pulled. The harness swaps these wrappers in only when a fault is injected, so the
healthy hot path carries none.
"""

from __future__ import annotations

import copy
import heapq
import itertools
import math
from collections import Counter, deque
from dataclasses import dataclass, fields
from typing import Callable, Iterable

import can
import numpy as np

from protocol import SENSOR_BOARD_NODE_ID

FAULT_KINDS = ("drop", "delay", "duplicate", "reorder", "corrupt")
# the nodes a fault can silence, by name: the leg's axes (firmware_sim.leg.LegHardware's node ids)
# and the sensor board
NODE_IDS = {"hip": 0, "knee": 1, "sensor_board": SENSOR_BOARD_NODE_ID}


@dataclass(frozen=True)
class FaultSpec:
    """What a faulty link does to each frame (each probability drawn independently per frame).

    Attributes:
        drop: probability that a frame is lost [0-1]; default 0.
        delay: probability that a frame is held back ``delay_s`` [0-1]; default 0.
        duplicate: probability that a frame is delivered twice [0-1]; default 0.
        reorder: probability that a frame is held until the next one has passed [0-1]; default 0.
        corrupt: probability that a frame with a payload is corrupted [0-1]: one byte replaced
            by another value, or (one time in five) the payload cut short; default 0.
        delay_s: how long a delayed frame is held [s]; default 0.005 (2.5 control periods).
        reorder_max_s: a frame held for reordering goes on after this long even if no frame
            followed it [s]; default 0.01.
    """

    drop: float = 0.0
    delay: float = 0.0
    duplicate: float = 0.0
    reorder: float = 0.0
    corrupt: float = 0.0
    delay_s: float = 0.005
    reorder_max_s: float = 0.01

    def __post_init__(self) -> None:
        for name in FAULT_KINDS:
            p = getattr(self, name)
            if not (isinstance(p, (int, float)) and math.isfinite(p) and 0.0 <= p <= 1.0):
                raise ValueError(f"fault probability {name} must be in [0, 1], got {p!r}")
        for name in ("delay_s", "reorder_max_s"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and 0.0 <= v <= 10.0):
                raise ValueError(f"{name} must be in [0, 10] s, got {v!r}")

    @property
    def active(self) -> bool:
        return any(getattr(self, k) > 0.0 for k in FAULT_KINDS)

    @classmethod
    def parse(cls, text: str) -> "FaultSpec":
        """``"drop=0.05,delay=0.01,delay_s=0.004"``; an empty string is no fault."""
        known = {f.name for f in fields(cls)}
        values: dict[str, float] = {}
        for part in filter(None, (p.strip() for p in text.split(","))):
            key, sep, value = part.partition("=")
            key = key.strip()
            if not sep or key not in known:
                raise ValueError(f"fault spec {text!r}: {part!r} is not NAME=VALUE with NAME one of {sorted(known)}")
            try:
                values[key] = float(value)
            except ValueError:
                raise ValueError(f"fault spec {text!r}: {value!r} is not a number") from None
        return cls(**values)

    def describe(self) -> str:
        parts = [f"{k}={getattr(self, k):g}" for k in FAULT_KINDS if getattr(self, k) > 0.0]
        return ",".join(parts) or "none"


def _copy(msg: can.Message) -> can.Message:
    return copy.deepcopy(msg)  # a new payload (copy.copy of a can.Message shares it)


class FaultInjector:
    """Applies a :class:`FaultSpec` to frames: :meth:`push` them in, :meth:`pop_ready` them out.

    ``counts``: frames seen (``frames``) and each fault applied, by kind. Frames not faulted come
    out in the order they went in, at the same clock reading.
    """

    def __init__(self, spec: FaultSpec, rng: np.random.Generator) -> None:
        self.spec = spec
        self.rng = rng
        self.counts: Counter[str] = Counter()
        self._ready: deque[can.Message] = deque()
        self._delayed: list[tuple[float, int, can.Message]] = []
        self._order = itertools.count()
        self._held: tuple[float, can.Message] | None = None

    def push(self, msg: can.Message, now_s: float) -> None:
        spec = self.spec
        self.counts["frames"] += 1
        # One uniform draw per fault kind and frame, in a fixed order: the same seed gives the
        # same faults whatever the probabilities.
        u = self.rng.random(5)
        if u[0] < spec.drop:
            self.counts["drop"] += 1
            return
        if u[4] < spec.corrupt and msg.dlc > 0 and not msg.is_remote_frame:
            msg = self._corrupt(msg)
        copies = 2 if u[2] < spec.duplicate else 1
        if copies == 2:
            self.counts["duplicate"] += 1
        if u[1] < spec.delay:
            self.counts["delay"] += 1
            for _ in range(copies):
                heapq.heappush(self._delayed, (now_s + spec.delay_s, next(self._order), msg))
            return
        if u[3] < spec.reorder and self._held is None:
            self.counts["reorder"] += 1
            self._held = (now_s, msg)
            if copies == 2:
                self._ready.append(msg)
            return
        for _ in range(copies):
            self._ready.append(msg)
        if self._held is not None:  # the held frame goes on behind the one that overtook it
            self._ready.append(self._held[1])
            self._held = None

    def _corrupt(self, msg: can.Message) -> can.Message:
        self.counts["corrupt"] += 1
        bad = _copy(msg)
        data = bytearray(bad.data)
        if self.rng.random() < 0.2:
            n = int(self.rng.integers(0, len(data)))
            bad.data = data[:n]
            bad.dlc = n
            return bad
        i = int(self.rng.integers(len(data)))
        data[i] = (data[i] + int(self.rng.integers(1, 256))) & 0xFF
        bad.data = data
        return bad

    def pop_ready(self, now_s: float) -> list[can.Message]:
        """Frames due at ``now_s``, in delivery order."""
        delayed = self._delayed
        while delayed and delayed[0][0] <= now_s:
            self._ready.append(heapq.heappop(delayed)[2])
        if self._held is not None and now_s - self._held[0] >= self.spec.reorder_max_s:
            self._ready.append(self._held[1])
            self._held = None
        out = list(self._ready)
        self._ready.clear()
        return out

    @property
    def in_flight(self) -> int:
        return len(self._ready) + len(self._delayed) + (self._held is not None)


class FaultyBus(can.BusABC):
    """The controller's end of a bus, seen through a faulty link.

    ``to_leg`` applies to what the controller sends, ``from_leg`` to what it receives, each with
    its own generator spawned from ``seed``. ``clock()`` is the time [s] the link runs on (the
    lockstep's simulated time). :meth:`silence` makes a node's frames vanish before they reach
    the controller. ``on_send(msg)``, if given, sees every frame the controller sends, before any
    fault (to audit what the controller itself put on the bus).
    """

    def __init__(self, inner: can.BusABC, clock: Callable[[], float], *, to_leg: FaultSpec = FaultSpec(),
                 from_leg: FaultSpec = FaultSpec(), seed: int = 0,
                 on_send: Callable[[can.Message], None] | None = None) -> None:
        self.inner = inner
        self.clock = clock
        tx_rng, rx_rng = np.random.default_rng(seed).spawn(2)
        self.tx = FaultInjector(to_leg, tx_rng)
        self.rx = FaultInjector(from_leg, rx_rng)
        self.on_send = on_send
        self.silenced: set[int] = set()
        self.silenced_frames = 0
        self._rx_ready: deque[can.Message] = deque()
        super().__init__(channel=getattr(inner, "channel_info", "faulty"))

    def silence(self, node_ids: Iterable[int]) -> None:
        self.silenced.update(node_ids)

    def _flush_tx(self, now_s: float) -> None:
        for m in self.tx.pop_ready(now_s):
            self.inner.send(m)

    def send(self, msg: can.Message, timeout: float | None = None) -> None:  # noqa: ARG002
        if self.on_send is not None:
            self.on_send(msg)
        now = self.clock()
        self.tx.push(msg, now)
        self._flush_tx(now)

    def _recv_internal(self, timeout: float | None):  # noqa: ARG002 - never blocks
        if not self._rx_ready:
            now = self.clock()
            self._flush_tx(now)
            recv = self.inner.recv
            msg = recv(timeout=0.0)
            while msg is not None:
                if (msg.arbitration_id >> 5) in self.silenced and not msg.is_extended_id:
                    self.silenced_frames += 1
                else:
                    self.rx.push(msg, now)
                msg = recv(timeout=0.0)
            self._rx_ready.extend(self.rx.pop_ready(now))
        if self._rx_ready:
            return self._rx_ready.popleft(), False
        return None, False

    def counts(self) -> dict[str, dict[str, int]]:
        return {"to_leg": dict(self.tx.counts), "from_leg": dict(self.rx.counts),
                "silenced_frames": self.silenced_frames}

    def shutdown(self) -> None:
        super().shutdown()


CAN_ERR_BUSOFF = 0x40  # SocketCAN error class (linux/can/error.h): the controller went bus-off


class BusOffBus(can.BusABC):
    """The controller's end of a bus whose CAN controller goes bus-off for ``outage_s`` from
    ``start_s`` (on ``clock()``).

    The first receive in the outage returns a bus-off error frame, as SocketCAN delivers one;
    every send and receive after it raises :class:`can.CanOperationError` (the interface is down),
    and so does opening the bus again (:meth:`reopen`) until the outage is over. Frames sent to
    the controller meanwhile are lost. Pass :meth:`reopen` to the controller as its bus factory.
    """

    def __init__(self, inner: can.BusABC, clock: Callable[[], float], start_s: float, outage_s: float) -> None:
        self.inner = inner
        self.clock = clock
        self.start_s = start_s
        self.end_s = start_s + outage_s
        self.error_frame_sent = False
        self.raised = 0
        super().__init__(channel=getattr(inner, "channel_info", "bus-off"))

    def _down(self) -> bool:
        return self.start_s <= self.clock() < self.end_s

    def _fail(self, what: str):
        self.raised += 1
        raise can.CanOperationError(f"{what}: network is down (bus-off)")

    def send(self, msg: can.Message, timeout: float | None = None) -> None:  # noqa: ARG002
        if self._down():
            self._fail("send")
        self.inner.send(msg)

    def _recv_internal(self, timeout: float | None):  # noqa: ARG002 - never blocks
        if self._down():
            while self.inner.recv(timeout=0.0) is not None:
                pass  # lost while the controller is off the bus
            if not self.error_frame_sent:
                self.error_frame_sent = True
                return can.Message(arbitration_id=CAN_ERR_BUSOFF, is_error_frame=True, dlc=8,
                                   data=bytes(8), is_extended_id=False), False
            self._fail("receive")
        return self.inner.recv(timeout=0.0), False

    def reopen(self) -> "BusOffBus":
        if self._down():
            self._fail("open")
        return self

    def shutdown(self) -> None:  # the harness owns the inner bus; a reopen hands this one back
        super().shutdown()


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
