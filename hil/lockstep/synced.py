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

import logging
import math
import struct
import time
from collections import deque
from typing import Callable

import can

from controller.daemon.simclock import SimClockBus, run_period
from controller.stepping.premotor import Premotor
from hil.lockstep.harness import LegHarness, Lockstep, LockstepConfig
from controller.supervisor import Phase
from protocol import BusContract
from protocol.contract import CONTROLLER_STATE_ID, END_OF_PERIOD_ID, PHASE_CODES, SIM_SYNC_ID, SIM_TIME_IDS

_F64 = struct.Struct("<d")
log = logging.getLogger(__name__)

GRACE_S = 10.0
"""How long the plant waits for the controller's end-of-period before it declares the controller
gone and steps on alone [s of wall time], across processes (:class:`SimTimePlant`). A loaded
2-core host stalls a process for well under a second; a stall shorter than this only slows the
run, it never changes it."""


class PlantSyncBus(can.BusABC):
    """The plant's end of the bus in simulated time, around its real bus (the harness owns it).

    :meth:`publish_sync` sends the period's sync; :meth:`wait_end_of_period` reads the bus until
    the controller's end-of-period for that time, keeping the frames before it; :meth:`recv`
    (what the nodes' :class:`~firmware_sim.node_host.NodeHost` reads) gives those frames first,
    then the bus's, and never a sync or end-of-period frame.

    ``stats``: ``syncs`` sent, ``ends`` received for the awaited period, ``alone`` (periods the
    plant stepped on without an end-of-period), ``stale_ends`` (an end-of-period for another
    time: a late answer to an earlier sync), ``states`` (``ES_Controller_State`` frames read),
    ``hidden`` (other simulated-time frames read: another plant's, or malformed), ``silenced``
    (frames of :attr:`silenced_node` never sent).

    ``controller_phase``: the controller's phase as its last ``ES_Controller_State`` said
    (a :class:`~controller.supervisor.Phase` value; None before the first). ``silenced_node``:
    a node id whose frames :meth:`send` drops from now on (its transmitter died; it still hears
    the bus), or None: a fault injected on the plant's side, on simulated time.
    """

    def __init__(self, inner: can.BusABC, *, contract: BusContract | None = None,
                 monotonic: Callable[[], float] = time.monotonic) -> None:
        self.inner = inner
        self.monotonic = monotonic
        contract = contract or BusContract.load()
        self._sync_codec = contract.codec("ES_Sim_Sync")
        self._eop_dlc = contract.codec("ES_End_Of_Period").dlc
        self._state_codec = contract.codec("ES_Controller_State")
        self._buffer: deque[can.Message] = deque()
        self.controller_phase: str | None = None
        self.silenced_node: int | None = None
        self.stats: dict[str, int] = {"syncs": 0, "ends": 0, "alone": 0, "stale_ends": 0, "states": 0, "hidden": 0,
                                      "silenced": 0}
        super().__init__(channel=getattr(inner, "channel_info", "plant-sync"))

    def publish_sync(self, t_s: float) -> None:
        """Send ``ES_Sim_Sync`` carrying ``t_s`` (after the period's last frame)."""
        if not math.isfinite(t_s):
            raise ValueError(f"simulated time must be finite, got {t_s!r}")
        self.inner.send(can.Message(arbitration_id=SIM_SYNC_ID, is_extended_id=True,
                                    data=self._sync_codec.pack(t_s)))
        self.stats["syncs"] += 1

    def _sim_frame(self, msg: can.Message) -> bool:
        return msg.is_extended_id and not msg.is_error_frame and msg.arbitration_id in SIM_TIME_IDS

    def _state(self, msg: can.Message) -> bool:
        """Take an ``ES_Controller_State`` frame (True), or say it is not one (False)."""
        if msg.arbitration_id != CONTROLLER_STATE_ID or msg.is_remote_frame or len(msg.data) != self._state_codec.dlc:
            return False
        (code,) = self._state_codec.unpack(msg.data)
        if not 0 <= code < len(PHASE_CODES):
            return False
        self.controller_phase = PHASE_CODES[int(code)]
        self.stats["states"] += 1
        return True

    def open_time(self, t_s: float, *, resend_s: float = 0.1, timeout_s: float = 120.0,
                  alive: Callable[[], bool] = lambda: True) -> bool:
        """Open simulated time: send the sync of ``t_s`` (0.0, before the first physics step)
        every ``resend_s`` [s of wall time] until its end-of-period arrives (True): the controller
        may start after the plant, and a sync sent before its socket existed is lost. False when
        ``timeout_s`` passed or ``alive()`` said no first."""
        deadline = self.monotonic() + timeout_s
        while self.monotonic() < deadline and alive():
            self.publish_sync(t_s)
            if self.wait_end_of_period(t_s, resend_s, count_alone=False):
                return True
        return False

    def wait_end_of_period(self, t_s: float, grace_s: float, *, count_alone: bool = True) -> bool:
        """Read the bus until the end-of-period answering the sync of ``t_s`` (bit for bit) has
        arrived: True. False (counted in ``alone``) when ``grace_s`` of wall time passed first:
        the controller is gone or stalled, and the plant steps on alone. Frames read meanwhile
        are kept, in order, for :meth:`recv`; a controller state read meanwhile is taken."""
        want = _F64.pack(t_s)
        deadline = self.monotonic() + grace_s
        while True:
            msg = self.inner.recv(timeout=max(0.0, deadline - self.monotonic()))
            if msg is None:
                if count_alone:
                    self.stats["alone"] += 1
                return False
            if not self._sim_frame(msg):
                self._buffer.append(msg)
            elif self._state(msg):
                pass
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
            elif not self._state(msg):
                self.stats["hidden"] += 1

    def _recv_internal(self, timeout: float | None):
        return self.recv(timeout), True

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        silenced = self.silenced_node
        if silenced is not None and not msg.is_extended_id and msg.arbitration_id >> 5 == silenced:
            self.stats["silenced"] += 1
            return
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


class RemoteLoop:
    """What the plant's side knows of a controller in another process: its phase, as its
    ``ES_Controller_State`` frames say (read by the :class:`PlantSyncBus`). It stands in for
    :class:`~controller.loop.ControlLoop` where an experiment (:class:`hil.experiments.learn.
    LearningRun`) asks ``loop.phase`` and ``loop.supervisor.fault_cause``; the controller's own
    records (steps, reflexes, weights) are in its records file, read after the run. ``stats``
    lists stay empty."""

    def __init__(self, bus: PlantSyncBus) -> None:
        from types import SimpleNamespace

        self._bus = bus
        self.stats = SimpleNamespace(steps=[], reflexes=[], ticks=0)
        self.supervisor = SimpleNamespace(fault_cause="the controller reported FAULT (its records say why)")
        self.premotor = None
        self.cpg = SimpleNamespace(burst_s=math.nan)

    @property
    def phase(self) -> Phase:
        code = self._bus.controller_phase
        return Phase.WAIT_NODES if code is None else Phase(code)


class SimTimePlant(LegHarness):
    """The plant's half of :class:`SyncedLockstep`, with the controller in another process on
    ``bus`` (SocketCAN: ``hil --clock sim``). The interface an experiment uses of
    :class:`~hil.lockstep.harness.Lockstep`: ``config``, ``leg``, ``plant``, ``t_s``, ``step()``,
    ``loop`` (a :class:`RemoteLoop`), ``close()``.

    At construction the plant opens simulated time (:meth:`PlantSyncBus.open_time`: the sync of
    0.0, repeated until answered, for at most ``open_timeout_s``; ``RuntimeError`` otherwise)
    before its first physics step, so the controller hears every frame the leg ever sends, as in
    the in-process lockstep. Each control period then ends with the sync and the wait for its
    end-of-period, at most ``grace_s`` of wall time: after that the controller is declared gone
    (logged once; ``gone`` True) and the plant steps on alone, its drivers' watchdogs acting on
    simulated time; while gone it waits at most one period of wall time for each answer (so the
    leg runs at about real time, and a controller that comes back is heard again).

    ``grace_s`` (default :data:`GRACE_S`): long enough that no stall of a loaded host reaches it
    (a stall of the controller only delays the plant: the run stays the same); short enough that
    a dead controller is noticed. ``bus`` belongs to the caller.
    """

    def __init__(self, config: LockstepConfig, premotor: Premotor | None = None, gui: bool = False, *,
                 bus: can.BusABC, grace_s: float | None = None, open_timeout_s: float = 120.0,
                 alive: Callable[[], bool] = lambda: True) -> None:
        from firmware_sim.leg import SimulatedLeg

        del premotor  # the controller in the other process has its own
        self.config = config
        self.grace_s = GRACE_S if grace_s is None else grace_s
        self.plant_bus = PlantSyncBus(bus)
        self.leg = SimulatedLeg(self.plant_bus, rig=config.rig, hardware=config.hardware, seed=config.seed, gui=gui)
        self.loop = RemoteLoop(self.plant_bus)
        self.ticks_per_control = int(round(config.rig.physics_hz / config.controller.rate_hz))
        self.period_s = 1.0 / config.controller.rate_hz
        self.physics_steps = 0
        self.gone = False
        self.wall_waits_s = 0.0
        if not self.plant_bus.open_time(self.leg.t_s, timeout_s=open_timeout_s, alive=alive):
            self.leg.close()
            raise RuntimeError(f"no controller answered the opening sync within {open_timeout_s:g} s")

    def silence(self, node_id: int) -> None:
        """From now on the node's frames are never sent (its transmitter died; it still hears the
        controller): a fault on simulated time, on the plant's side of the bus."""
        self.plant_bus.silenced_node = node_id

    def step(self) -> bool:
        """One physics step; at the end of a control period the sync and the wait for its
        end-of-period. True if the controller answered."""
        self.leg.step()
        self.physics_steps += 1
        if self.physics_steps % self.ticks_per_control:
            return False
        t_s = self.leg.t_s
        bus = self.plant_bus
        bus.publish_sync(t_s)
        t0 = bus.monotonic()
        answered = bus.wait_end_of_period(t_s, self.period_s if self.gone else self.grace_s)
        self.wall_waits_s += bus.monotonic() - t0
        if answered:
            self.loop.stats.ticks += 1
            if self.gone:
                log.warning("the controller answered again at t=%.3f s", t_s)
                self.gone = False
        elif not self.gone:
            log.warning("no end-of-period within %.1f s at t=%.3f s: the controller is gone; the plant steps on alone",
                        self.grace_s, t_s)
            self.gone = True
        return answered

    def close(self) -> None:
        self.leg.close()
        self.plant_bus.shutdown()
