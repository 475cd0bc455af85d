"""The simulated leg as hardware: the plant plus its CAN nodes, stepped one physics period at a time.

Hip and knee are ODrive axes (nodes 0 and 1 by default) behind 6:1 transmissions (the knee's
mounted reversed), the sensor board is node :data:`protocol.SENSOR_BOARD_NODE_ID`. One :meth:`SimulatedLeg.step` is one physics
period: frames waiting on the bus are handled, the drivers' loops compute torques, the physics
advances, and the cyclic frames that came due are sent.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import can
import numpy as np

from firmware_sim.motor import MotorJoint, MotorParams, Transmission
from firmware_sim.node_host import NodeHost
from firmware_sim.odrive_axis import DriverConfig, SimOdriveAxis
from firmware_sim.plant import RigConfig, RigPlant
from firmware_sim.sensor_board import SensorBoard, SensorBoardConfig
from firmware_sim.thermal import ThermalModel, ThermalParams
from protocol.compiled import interpreted


@interpreted  # a configuration: plain Python even when compiled (protocol.compiled)
@dataclass(frozen=True)
class LegHardware:
    """How the leg is built and wired.

    Attributes:
        hip_node_id, knee_node_id: CAN node ids of the two axes; defaults 0 and 1.
        gear_ratio: motor revolutions per joint revolution (both joints); default 6.0.
        hip_direction, knee_direction: sign from joint to motor angle; defaults +1 and -1.
        hip_zero_offset_rev, knee_zero_offset_rev: motor reading at joint angle 0 [rev]; 0.0.
        driver: the ODrive axis settings shared by both axes (node_id is overridden); by
            default they send their health readings (Get_Temperature, Get_Bus_Voltage_Current,
            Get_Iq) every 0.1 s, as ``[health] read_period_s`` expects.
        motor: the motor model shared by both axes.
        thermal: each axis's thermal and supply model (ambient, source voltage, ...;
            :mod:`firmware_sim.thermal`).
        sensor: the sensor board's settings.
    """

    hip_node_id: int = 0
    knee_node_id: int = 1
    gear_ratio: float = 6.0
    hip_direction: int = 1
    knee_direction: int = -1
    hip_zero_offset_rev: float = 0.0
    knee_zero_offset_rev: float = 0.0
    driver: DriverConfig = field(default_factory=lambda: DriverConfig(node_id=0, health_period_s=0.1))
    motor: MotorParams = MotorParams()
    thermal: ThermalParams = ThermalParams()
    sensor: SensorBoardConfig = SensorBoardConfig()


class SimulatedLeg:
    def __init__(self, bus: can.BusABC, *, rig: RigConfig = RigConfig(), hardware: LegHardware = LegHardware(),
                 seed: int = 0, gui: bool = False, plant_class: type[RigPlant] = RigPlant) -> None:
        """``plant_class``: the plant's class, :class:`RigPlant` or a subclass (the physics floor's
        recording plant, :mod:`hil.bench.physics_floor`); built as ``plant_class(rig, gui=gui)``."""
        self.plant = plant_class(rig, gui=gui)
        self.hardware = hardware
        self.axes: dict[str, SimOdriveAxis] = {}
        wiring = (
            ("hip", hardware.hip_node_id, hardware.hip_direction, hardware.hip_zero_offset_rev),
            ("knee", hardware.knee_node_id, hardware.knee_direction, hardware.knee_zero_offset_rev),
        )
        for name, node_id, direction, offset in wiring:
            tr = Transmission(gear_ratio=hardware.gear_ratio, direction=direction, zero_offset_rev=offset)
            lo, hi = (tr.joint_to_motor_rev(q) for q in self.plant.joint_limits_rad[name])
            driver = replace(hardware.driver, node_id=node_id, pos_min_rev=min(lo, hi), pos_max_rev=max(lo, hi))
            self.axes[name] = axis = SimOdriveAxis(driver, MotorJoint(self.plant, name, tr, hardware.motor))
            axis.thermal = ThermalModel(axis.motor, hardware.thermal)
        self.board = SensorBoard(hardware.sensor, self.plant, np.random.default_rng(seed))
        self.host = NodeHost(bus, [*self.axes.values(), self.board])
        self.dt_s = self.plant.dt_s

    @property
    def t_s(self) -> float:
        return self.plant.t_s

    def step(self) -> None:
        t = self.plant.t_s
        host = self.host
        host.poll(t)
        host.update(t, self.dt_s)
        self.plant.step()
        host.publish(self.plant.t_s)

    def close(self) -> None:
        self.plant.close()
