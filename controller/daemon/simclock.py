"""The controller's side of simulated time (``hil --clock sim``): tick once per sync frame.

In simulated time the plant owns the clock. After each control period's physics steps it sends
``ES_Sim_Sync`` (29-bit id :data:`~protocol.contract.SIM_SYNC_ID`) carrying its time ``t_s`` as a
float64; the controller ticks once with exactly that ``t_s`` as its clock and then sends
``ES_End_Of_Period`` (:data:`~protocol.contract.END_OF_PERIOD_ID`) echoing it; the plant steps on
when that frame has arrived. :class:`SimClockBus` is the controller's bus in this mode, wrapped
around the real one and handed to :class:`~controller.io.bus.BusIO` in its place.

**The rule.** :meth:`SimClockBus.recv` hands the controller every frame up to and *not
including* the next sync frame, then returns None, whatever its ``timeout``, until that sync has
been claimed by :meth:`SimClockBus.wait_sync` and answered by :meth:`SimClockBus.end_period`.
Sync and end-of-period frames are never handed to the controller's ``BusIO``.

**The reason.** ``BusIO.drain`` reads until ``recv`` returns None. On a wall clock that is "until
the queue is empty now", which depends on how fast each process ran. Here it is "until the
period boundary the plant marked": the plant sends the sync after the last frame of the period,
so the frames a tick sees are exactly those the plant sent in that period, and the tick's clock is
exactly the plant's time, whatever the host's load. The same seed then gives the same run as the
in-process lockstep (:class:`hil.lockstep.harness.Lockstep`), frame for frame. Frames read while
waiting for a sync are buffered, in order, for the tick that follows it. Faults injected between
the controller and the bus (:class:`hil.faults.model.FaultyBus`) wrap this bus, so they never
see, lose or delay a sync or end-of-period frame.

A period: ``sync = clock.wait_sync(timeout_s)``; ``loop.tick(sync.t_s)``;
``clock.end_period(sync, phase)`` (:func:`run_period` does the three).

**Opening.** Simulated time opens with a sync at ``t_s = 0.0``, which the plant sends before its
first physics step and repeats until it is answered (the controller may start after the plant):
the controller answers it and does **not** tick (no time has passed; the in-process lockstep's
first tick is at the end of the first period). :func:`is_opening` says which sync that is.

**Stale syncs.** A sync whose time is not later than the last one claimed (a repeat of the opening
sync, a plant that re-sent a sync it had given up on) is dropped, never ticked on, and counted in
``stale_syncs``: a tick is never repeated for a time already lived.

**The controller's phase.** :meth:`SimClockBus.end_period` with ``phase`` sends
``ES_Controller_State`` (:data:`~protocol.contract.CONTROLLER_STATE_ID`, the phase's code in
:data:`~protocol.contract.PHASE_CODES`) just before the end-of-period, in the first period and
whenever the phase changed: the experiment stepping the plant learns at the same simulated instant
as the in-process lockstep that the leg walks, or stopped safely.

Counters (``stats``): ``syncs`` claimed, ``ends`` sent, ``states`` sent, ``stale_syncs``,
``foreign_end_of_period`` (another controller's, hidden), ``malformed_sync`` (a sync with the
wrong length, a remote frame, or a time that is not finite: dropped, never ticked on).
"""

from __future__ import annotations

import logging
import math
import time
from collections import deque
from typing import Callable, NamedTuple

import can

from protocol import BusContract
from protocol.contract import CONTROLLER_STATE_ID, END_OF_PERIOD_ID, PHASE_CODES, SIM_SYNC_ID

log = logging.getLogger(__name__)


class SimSync(NamedTuple):
    """One sync frame, claimed: ``period`` counts the syncs this clock claimed before it (0 for
    the first), ``t_s`` is the plant's simulated time [s], bit for bit."""

    period: int
    t_s: float


class SimClockBus(can.BusABC):
    """The controller's bus in simulated time (see the module doc for the rule and the reason).

    ``inner``: the real bus (SocketCAN, or python-can ``virtual`` in one process); this bus owns
    it (:meth:`shutdown` shuts it down). ``monotonic``: the wall clock that bounds
    :meth:`wait_sync`'s wait (only there; the controller's clock is the sync's ``t_s``).
    """

    def __init__(self, inner: can.BusABC, *, contract: BusContract | None = None,
                 monotonic: Callable[[], float] = time.monotonic) -> None:
        self.inner = inner
        self.monotonic = monotonic
        contract = contract or BusContract.load()
        self._sync_codec = contract.codec("ES_Sim_Sync")
        self._eop_codec = contract.codec("ES_End_Of_Period")
        self._state_codec = contract.codec("ES_Controller_State")
        self._last_claimed: float = -math.inf  # the time of the last sync claimed
        self._phase_sent: str | None = None
        self._buffer: deque[can.Message] = deque()  # frames before the pending sync
        self._pending: float | None = None  # a sync read from the bus, not yet claimed
        self._current: SimSync | None = None  # claimed by wait_sync, not yet ended
        self._periods = 0
        self.stats: dict[str, int] = {"syncs": 0, "ends": 0, "states": 0, "stale_syncs": 0,
                                      "foreign_end_of_period": 0, "malformed_sync": 0}
        super().__init__(channel=getattr(inner, "channel_info", "simclock"))

    @property
    def current(self) -> SimSync | None:
        """The sync being answered (claimed and not yet ended), or None."""
        return self._current

    # ------------------------------------------------------------------ reading the bus
    def _read(self, timeout: float | None) -> can.Message | None:
        """One frame from the inner bus that is not ours to hide: a sync is kept as pending
        (and None returned), an end-of-period or a malformed sync is counted and skipped."""
        deadline = None if timeout is None else self.monotonic() + timeout
        while True:
            left = None if deadline is None else max(0.0, deadline - self.monotonic())
            msg = self.inner.recv(timeout=left)
            if msg is None:
                return None
            if msg.is_extended_id and not msg.is_error_frame:
                arb = msg.arbitration_id
                if arb == SIM_SYNC_ID:
                    t_s = self._sync_time(msg)
                    if t_s is None:
                        continue
                    if t_s <= self._last_claimed or (self._pending is not None and t_s <= self._pending):
                        self.stats["stale_syncs"] += 1  # a time already lived (or already pending)
                        continue
                    self._pending = t_s
                    return None
                if arb == END_OF_PERIOD_ID or arb == CONTROLLER_STATE_ID:
                    self.stats["foreign_end_of_period"] += 1
                    continue
            return msg

    def _sync_time(self, msg: can.Message) -> float | None:
        codec = self._sync_codec
        if msg.is_remote_frame or msg.dlc != codec.dlc or len(msg.data) != codec.dlc:
            self.stats["malformed_sync"] += 1
            return None
        (t_s,) = codec.unpack(msg.data)
        if not math.isfinite(t_s):
            self.stats["malformed_sync"] += 1
            return None
        return t_s

    def recv(self, timeout: float | None = None) -> can.Message | None:
        """The next frame before the next sync; None at the sync (at once, whatever ``timeout``),
        or when nothing arrived within ``timeout``."""
        if self._buffer:
            return self._buffer.popleft()
        if self._pending is not None or self._current is not None:
            return None  # the period ends here: what follows belongs to the next sync's tick
        return self._read(timeout)

    def _recv_internal(self, timeout: float | None):  # BusABC's hook; recv above does the work
        return self.recv(timeout), True

    def wait_sync(self, timeout_s: float | None) -> SimSync | None:
        """Block until the next sync frame has arrived (at most ``timeout_s`` of wall time; None:
        forever) and claim it; frames before it are kept for the tick. None on a timeout.

        Raises ``RuntimeError`` while a claimed sync has not been answered (:meth:`end_period`)."""
        if self._current is not None:
            raise RuntimeError(f"period {self._current.period} (t={self._current.t_s!r} s) not ended: "
                               "call end_period before waiting for the next sync")
        if self._pending is None:
            deadline = None if timeout_s is None else self.monotonic() + timeout_s
            while self._pending is None:
                left = None if deadline is None else max(0.0, deadline - self.monotonic())
                msg = self._read(left)
                if msg is not None:
                    self._buffer.append(msg)
                elif self._pending is None:
                    return None  # timed out
        sync = SimSync(self._periods, self._pending)
        self._last_claimed = self._pending
        self._pending = None
        self._current = sync
        self._periods += 1
        self.stats["syncs"] += 1
        return sync

    def end_period(self, sync: SimSync, phase: str | None = None) -> None:
        """Send the end-of-period frame for ``sync`` (the claimed one), preceded by
        ``ES_Controller_State`` when ``phase`` (a :class:`~controller.supervisor.Phase` value) is
        given and differs from the last one sent; the next frames belong to the next sync. A send
        error (``can.CanError``) is raised to the caller, with the period still ended: the plant
        steps on after its grace either way."""
        if sync != self._current:
            raise ValueError(f"end_period for {sync!r}, but the sync being answered is {self._current!r}")
        self._current = None
        self.stats["ends"] += 1
        if phase is not None and phase != self._phase_sent:
            self._phase_sent = phase
            self.stats["states"] += 1
            self.inner.send(can.Message(arbitration_id=CONTROLLER_STATE_ID, is_extended_id=True,
                                        data=self._state_codec.pack(PHASE_CODES.index(phase))))
        self.inner.send(can.Message(arbitration_id=END_OF_PERIOD_ID, is_extended_id=True,
                                    data=self._eop_codec.pack(sync.t_s)))

    # ------------------------------------------------------------------ the rest of a bus
    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        """The controller's frames go to the bus unchanged."""
        self.inner.send(msg, timeout)

    def shutdown(self) -> None:
        if self._is_shutdown:
            return
        super().shutdown()
        self.inner.shutdown()


def is_opening(sync: SimSync) -> bool:
    """The sync that opens simulated time (``t_s`` 0.0): answered, never ticked on."""
    return sync.t_s <= 0.0


def run_period(loop, clock: SimClockBus, timeout_s: float | None) -> SimSync | None:
    """One controller period in simulated time: wait for the sync, tick ``loop`` (a
    :class:`~controller.loop.ControlLoop` whose bus is ``clock``, or wraps it) with its time
    (not for the opening sync), end the period with the loop's phase. None (and no tick) if no
    sync came within ``timeout_s``."""
    sync = clock.wait_sync(timeout_s)
    if sync is None:
        return None
    try:
        if not is_opening(sync):
            loop.tick(sync.t_s)
    finally:
        clock.end_period(sync, loop.phase.value)
    return sync
