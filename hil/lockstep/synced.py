"""In-process lockstep in simulated time: the controller ticks through the sync protocol.

:class:`SyncedLockstep` has :class:`~hil.lockstep.harness.Lockstep`'s interface (``step()``,
``t_s``, ``plant``, ``loop``, ``leg``, ``config``, the fault methods), but the harness never calls
``loop.tick`` with a time of its own. Each control period:

1. the plant runs the period's physics steps (its nodes poll, update, step, publish);
2. the plant sends ``ES_Sim_Sync`` with its time ``leg.t_s`` (:meth:`PlantSyncBus.publish_sync`);
3. the controller's side waits for it through its :class:`~controller.daemon.simclock.SimClockBus`,
   ticks with the sync's ``t_s`` (every frame before the sync, none after) and sends
   ``ES_End_Of_Period`` (:func:`~controller.daemon.simclock.run_period`);
4. the plant reads the bus up to that end-of-period (:meth:`PlantSyncBus.wait_end_of_period`),
   keeping the controller's frames for its nodes' next poll, and steps on.

This is the protocol ``hil --clock sim`` runs between two processes over SocketCAN, here in one
process over python-can's ``virtual`` bus with no threads: the steps follow each other, so every
wait is satisfied at once (``grace_s`` 0). It proves the protocol gives the same run as the
in-process lockstep, frame for frame: the sync goes out after the period's last frame, so the
tick drains exactly what ``Lockstep``'s tick drains, at exactly the same time.

The sync and end-of-period frames never reach a node or the controller's ``BusIO``: the plant's
nodes read the bus through :class:`PlantSyncBus`, the controller through the ``SimClockBus``,
and injected faults (:meth:`Lockstep.inject_faults`, ``silence``, ``cut_bus``, ``bus_off``) wrap
the ``SimClockBus``, so they never touch those frames. :meth:`Lockstep.kill_controller` stops the
controller's side: the plant waits for no end-of-period, counts the period in
``PlantSyncBus.stats["alone"]`` and steps on alone (its drivers' watchdogs act on simulated time).
A third node (:meth:`Lockstep.observer`) hears the sync and end-of-period frames, as a recorder
on the vcan bus would.
"""

from __future__ import annotations

import math
import struct
import time
from collections import deque
from typing import Callable

import can

from controller.daemon.simclock import SimClockBus, run_period
from controller.stepping.premotor import Premotor
from hil.lockstep.harness import Lockstep, LockstepConfig
from protocol import BusContract
from protocol.contract import END_OF_PERIOD_ID, SIM_SYNC_ID

_F64 = struct.Struct("<d")


class PlantSyncBus(can.BusABC):
    """The plant's end of the bus in simulated time, around its real bus (the harness owns it).

    :meth:`publish_sync` sends the period's sync; :meth:`wait_end_of_period` reads the bus until
    the controller's end-of-period for that time, keeping the frames before it; :meth:`recv`
    (what the nodes' :class:`~firmware_sim.node_host.NodeHost` reads) gives those frames first,
    then the bus's, and never a sync or end-of-period frame.

    ``stats``: ``syncs`` sent, ``ends`` received for the awaited period, ``alone`` (periods the
    plant stepped on without an end-of-period), ``stale_ends`` (an end-of-period for another
    time: a late answer to an earlier sync), ``hidden`` (other sync / end-of-period frames read:
    another plant's, or malformed).
    """

    def __init__(self, inner: can.BusABC, *, contract: BusContract | None = None,
                 monotonic: Callable[[], float] = time.monotonic) -> None:
        self.inner = inner
        self.monotonic = monotonic
        contract = contract or BusContract.load()
        self._sync_codec = contract.codec("ES_Sim_Sync")
        self._eop_dlc = contract.codec("ES_End_Of_Period").dlc
        self._buffer: deque[can.Message] = deque()
        self.stats: dict[str, int] = {"syncs": 0, "ends": 0, "alone": 0, "stale_ends": 0, "hidden": 0}
        super().__init__(channel=getattr(inner, "channel_info", "plant-sync"))

    def publish_sync(self, t_s: float) -> None:
        """Send ``ES_Sim_Sync`` carrying ``t_s`` (after the period's last frame)."""
        if not math.isfinite(t_s):
            raise ValueError(f"simulated time must be finite, got {t_s!r}")
        self.inner.send(can.Message(arbitration_id=SIM_SYNC_ID, is_extended_id=True,
                                    data=self._sync_codec.pack(t_s)))
        self.stats["syncs"] += 1

    def _sim_frame(self, msg: can.Message) -> bool:
        return msg.is_extended_id and not msg.is_error_frame and msg.arbitration_id in (SIM_SYNC_ID, END_OF_PERIOD_ID)

    def wait_end_of_period(self, t_s: float, grace_s: float) -> bool:
        """Read the bus until the end-of-period answering the sync of ``t_s`` (bit for bit) has
        arrived: True. False (counted in ``alone``) when ``grace_s`` of wall time passed first:
        the controller is gone or stalled, and the plant steps on alone. Frames read meanwhile
        are kept, in order, for :meth:`recv`."""
        want = _F64.pack(t_s)
        deadline = self.monotonic() + grace_s
        while True:
            msg = self.inner.recv(timeout=max(0.0, deadline - self.monotonic()))
            if msg is None:
                self.stats["alone"] += 1
                return False
            if not self._sim_frame(msg):
                self._buffer.append(msg)
            elif (msg.arbitration_id == END_OF_PERIOD_ID and not msg.is_remote_frame
                  and len(msg.data) == self._eop_dlc):
                if bytes(msg.data) == want:
                    self.stats["ends"] += 1
                    return True
                self.stats["stale_ends"] += 1
            else:
                self.stats["hidden"] += 1

    def recv(self, timeout: float | None = None) -> can.Message | None:
        """The frames kept by :meth:`wait_end_of_period`, then the bus's; never a sync or an
        end-of-period frame (an end-of-period read here is stale: the plant went on alone)."""
        if self._buffer:
            return self._buffer.popleft()
        while True:
            msg = self.inner.recv(timeout=timeout)
            if msg is None or not self._sim_frame(msg):
                return msg
            if msg.arbitration_id == END_OF_PERIOD_ID:
                self.stats["stale_ends"] += 1
            else:
                self.stats["hidden"] += 1

    def _recv_internal(self, timeout: float | None):
        return self.recv(timeout), True

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self.inner.send(msg, timeout)

    def shutdown(self) -> None:  # the harness owns the inner bus
        super().shutdown()


class SyncedLockstep(Lockstep):
    """:class:`Lockstep` whose controller ticks through the sync protocol (see the module doc).

    ``grace_s``: how long the plant waits for the end-of-period [s of wall time]; in one process
    every answer is already on the bus when the plant looks, so 0 (the default) loses nothing.
    ``sim_clock`` is the controller's :class:`SimClockBus` (also ``controller_bus``, so the fault
    methods wrap it), ``plant_bus`` the plant's :class:`PlantSyncBus`.
    """

    def __init__(self, config: LockstepConfig = LockstepConfig(), *, premotor: Premotor | None = None,
                 gui: bool = False, grace_s: float = 0.0) -> None:
        super().__init__(config, premotor=premotor, gui=gui)
        self.grace_s = grace_s
        # Hook-free wiring: the plant's nodes and the controller read through the sync wrappers.
        self.plant_bus = PlantSyncBus(self.firmware_bus)
        self.leg.host.bus = self.plant_bus
        self.sim_clock = SimClockBus(self.controller_bus)
        self.controller_bus = self.sim_clock
        self.loop.io.bus = self.sim_clock

    def step(self) -> bool:
        """One physics step; at the end of a control period the sync, the controller's tick
        through the protocol, and the wait for its end-of-period. True if the controller ticked."""
        self.leg.step()
        self.physics_steps += 1
        if self.physics_steps % self.ticks_per_control:
            return False
        t_s = self.leg.t_s
        self.plant_bus.publish_sync(t_s)
        ticked = False
        if self.controller_alive:
            ticked = run_period(self.loop, self.sim_clock, 0.0) is not None
        self.plant_bus.wait_end_of_period(t_s, self.grace_s)
        return ticked

    def close(self) -> None:
        super().close()
        self.plant_bus.shutdown()
