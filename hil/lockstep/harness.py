"""In-process lockstep: the simulated leg and the controller on one python-can ``virtual`` bus.

Physics runs at ``rig.physics_hz`` (1 kHz); the controller ticks every
``physics_hz / rate_hz`` physics steps (every 2 at 500 Hz) with the simulated time as its clock.
Frames cross the virtual bus exactly as they would a real one; nothing else passes between the
two sides. Both sides drain the bus completely at their turn, so a run is deterministic for a
seed.

Faults (:mod:`hil.faults.model`): :meth:`Lockstep.inject_faults` puts a faulty link (seeded, on the
simulated clock) between the controller and the bus, :meth:`Lockstep.silence` makes nodes'
frames vanish on it, :meth:`Lockstep.cut_bus` pulls the controller's cable, and
:meth:`Lockstep.kill_controller` stops the controller dead (``kill -9``: no more ticks, no
goodbye frames) while the leg runs on.

Compiled (:mod:`protocol.compiled`): :class:`LegHarness` and :class:`Lockstep` are native classes
that allow Python subclasses (``SimTimePlant``, ``SyncedLockstep``, the physics floor's recording
harness); :class:`LockstepConfig` stays a Python class, as every configuration.
"""

from __future__ import annotations

import itertools
import uuid
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import can

from controller.config import ControllerConfig
from controller.loop import ControlLoop
from controller.stepping.premotor import Premotor
from firmware_sim.leg import LegHardware, SimulatedLeg
from firmware_sim.plant import RigConfig, RigPlant
from hil.faults.model import BusOffBus, CutBus, FaultSpec, FaultyBus
from hil.lockstep.localbus import BUSES
from protocol.compiled import interpreted, mypyc_attr

_channel_counter = itertools.count()


@interpreted  # a configuration: plain Python even when compiled (protocol.compiled)
@dataclass(frozen=True)
class LockstepConfig:
    """A lockstep session.

    Attributes:
        seed: seeds the sensor board's noise and dropouts; the same seed gives the same run.
        rig: the plant (physics rate, rail speed, sensor mounting).
        hardware: the leg's nodes and wiring.
        controller: the controller's configuration (its rate must divide the physics rate).
        auto_arm: the controller arms by itself once every node is heard (its ``auto_arm`` is
            set to this), as every experiment needs; default True. False leaves arming to
            ``loop.request_arm``.
    """

    seed: int = 0
    rig: RigConfig = RigConfig()
    hardware: LegHardware = field(default_factory=LegHardware)
    controller: ControllerConfig = field(default_factory=ControllerConfig)
    auto_arm: bool = True

    def __post_init__(self) -> None:
        if self.controller.auto_arm != self.auto_arm:
            object.__setattr__(self, "controller", replace(self.controller, auto_arm=self.auto_arm))
        ratio = self.rig.physics_hz / self.controller.rate_hz
        if abs(ratio - round(ratio)) > 1e-9 or round(ratio) < 1:
            raise ValueError(
                f"controller rate {self.controller.rate_hz} Hz must divide the physics rate {self.rig.physics_hz} Hz"
            )


@mypyc_attr(allow_interpreted_subclasses=True)  # SimTimePlant (hil.lockstep.synced)
class LegHarness:
    """What every harness around a simulated leg shares: ``leg``, its ``plant`` and clock
    ``t_s``, and closing as a context manager (``close`` is the harness's own)."""

    leg: SimulatedLeg

    @property
    def plant(self) -> RigPlant:
        return self.leg.plant

    @property
    def t_s(self) -> float:
        return self.leg.t_s

    def close(self) -> None:
        raise NotImplementedError

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()


@mypyc_attr(allow_interpreted_subclasses=True)  # SyncedLockstep, the physics floor's recording run
class Lockstep(LegHarness):
    """``bus``: the in-process bus, a name of :data:`hil.lockstep.localbus.BUSES` (default
    ``"local"``, python-can's ``BusABC`` without copies, locks or clock reads; ``"virtual"`` is
    python-can's own; both give the same run). ``plant_class``: the leg's plant class (default
    :class:`RigPlant`; the physics floor records through a subclass)."""

    def __init__(self, config: LockstepConfig = LockstepConfig(), *, premotor: Premotor | None = None,
                 gui: bool = False, bus: str = "local", plant_class: type[RigPlant] = RigPlant) -> None:
        self.config = config
        channel = f"lockstep-{uuid.uuid4().hex}-{next(_channel_counter)}"
        self.channel = channel
        self._make_bus: Callable[[str], can.BusABC] = BUSES[bus]
        self.firmware_bus: can.BusABC = self._make_bus(channel)
        self.controller_bus: can.BusABC = self._make_bus(channel)  # SyncedLockstep puts its own
        self.leg = SimulatedLeg(self.firmware_bus, rig=config.rig, hardware=config.hardware, seed=config.seed, gui=gui,
                                plant_class=plant_class)
        self.loop = ControlLoop(config.controller, self.controller_bus, premotor=premotor)
        self.ticks_per_control = int(round(config.rig.physics_hz / config.controller.rate_hz))
        self.physics_steps = 0
        self._cut: CutBus | None = None
        self.faulty: FaultyBus | None = None
        self.controller_alive = True

    def step(self) -> bool:
        """One physics step, and a controller tick when one is due. True if the controller ticked."""
        self.leg.step()
        self.physics_steps += 1
        if self.physics_steps % self.ticks_per_control == 0 and self.controller_alive:
            self.loop.tick(self.leg.t_s)
            return True
        return False

    def cut_bus(self, cut: bool = True) -> None:
        """Pull (``cut=True``) or plug back the controller's cable."""
        if not cut:
            self.loop.io.bus = self.controller_bus
            return
        if self._cut is None:
            self._cut = CutBus(self.controller_bus)
        self.loop.io.bus = self._cut

    def observer(self) -> can.BusABC:
        """A third node on the bus that hears every frame (read it often: its queue has no bound)."""
        return self._make_bus(self.channel)

    def inject_faults(self, to_leg: FaultSpec = FaultSpec(), from_leg: FaultSpec = FaultSpec(), *, seed: int = 0,
                      on_send=None) -> FaultyBus:
        """Put a faulty link between the controller and the bus from now on (see :class:`FaultyBus`)."""
        if self.faulty is None:
            self.faulty = FaultyBus(self.controller_bus, lambda: self.leg.t_s, to_leg=to_leg, from_leg=from_leg,
                                    seed=seed, on_send=on_send)
            self.loop.io.bus = self.faulty
        return self.faulty

    def silence(self, node_ids) -> None:
        """From now on, every frame these nodes send is lost before it reaches the controller."""
        self.inject_faults().silence(node_ids)

    def bus_off(self, outage_s: float) -> BusOffBus:
        """From now on, the controller's bus is off for ``outage_s``; the controller reopens it
        with its backoff (its ``reopen`` factory fails until the outage is over)."""
        inner = self.loop.io.bus
        off = BusOffBus(inner, lambda: self.leg.t_s, self.leg.t_s, outage_s)
        self.loop.io.bus = off
        self.loop.io.reopen = off.reopen
        return off

    def kill_controller(self) -> None:
        """``kill -9``: the controller stops at once; the leg and its drivers run on."""
        self.controller_alive = False

    def axes_idle(self) -> bool:
        """Ground truth: every simulated axis is in IDLE (no torque)."""
        from protocol import AxisState

        return all(a.state is AxisState.IDLE for a in self.leg.axes.values())

    def close(self) -> None:
        self.leg.close()
        if self.faulty is not None:
            self.faulty.shutdown()
        if self._cut is not None:
            self._cut.shutdown()
        self.controller_bus.shutdown()
        self.firmware_bus.shutdown()
