"""The drivers' thermal and supply model (firmware_sim.thermal) and its hook in the simulated ODrive."""

from __future__ import annotations

import math

import pytest

from firmware_sim.motor import MotorJoint, MotorParams
from firmware_sim.odrive_axis import DriverConfig, SimOdriveAxis
from firmware_sim.thermal import ThermalModel, ThermalParams
from protocol import AxisState, BusContract, data_frame
from protocol.odrive import ControlMode, InputMode
from tests.fakes import FakeJointPlant

C = BusContract.load()
KT = MotorParams().torque_constant_nm_per_a


class Stalled:
    """A motor held against a stop: the plant never moves, whatever the torque."""

    def joint_state(self, name):
        return 0.0, 0.0

    def set_joint_torque(self, name, tau_nm):
        pass


def held(amps: float, params: ThermalParams = ThermalParams()) -> ThermalModel:
    motor = MotorJoint(Stalled(), "knee")
    motor.apply_motor_torque(amps * KT, 0.0)
    return ThermalModel(motor, params)


def test_everything_starts_at_ambient_and_the_bus_at_the_source_voltage():
    m = held(0.0, ThermalParams(ambient_c=31.0))
    assert m.temperature_values() == (31.0, 31.0)
    assert m.bus_values() == (24.0, 0.0)
    assert held(0.0, ThermalParams(source_voltage_v=48.0)).bus_values()[0] == 48.0


def test_the_motor_winding_is_first_order_in_the_copper_loss():
    p = ThermalParams()
    m = held(20.0, p)  # the hardware limit against a stop: 20^2 * 0.04 = 16 W
    rise = 16.0 * p.motor_thermal_resistance_k_per_w
    dt = 0.001
    for _ in range(int(round(p.motor_time_constant_s / dt))):
        m.step(dt)
    assert m.motor_c == pytest.approx(25.0 + rise * (1 - math.exp(-1)), rel=1e-6)  # 63 % after one tau
    for _ in range(20):
        m.step(p.motor_time_constant_s)  # exact for any step: a long one is stable
    assert m.motor_c == pytest.approx(25.0 + rise, rel=1e-9)  # 57 C: never 90 C at 25 C ambient
    fet_rise = (400.0 * p.fet_resistance_ohm + p.fet_idle_loss_w) * p.fet_thermal_resistance_k_per_w
    assert m.fet_c == pytest.approx(25.0 + fet_rise, rel=1e-9)


def test_a_hot_ambient_or_a_winding_fault_drives_the_motor_out_of_bounds():
    m = held(20.0, ThermalParams(ambient_c=70.0))
    for _ in range(10):
        m.step(60.0)
    assert m.temperature_values()[1] > 90.0
    m = held(0.0)
    m.extra_motor_loss_w = 100.0  # a fault: heat without current
    m.step(30.0)
    assert m.motor_c > 90.0 and m.fet_c < 30.0


def test_the_bus_sags_under_load_and_rises_while_regenerating():
    p = ThermalParams(source_resistance_ohm=0.5)
    motor = MotorJoint(Stalled(), "knee")
    m = ThermalModel(motor, p)
    motor.apply_motor_torque(10.0 * KT, 50.0)  # 10 A at 50 rev/s: drawing power
    v, i = m.bus_values()
    assert i > 0 and v == pytest.approx(24.0 - 0.5 * i)
    motor.apply_motor_torque(-10.0 * KT, 50.0)  # braking: power back into the bus
    v, i = m.bus_values()
    assert i < 0 and v > 24.0
    m.source_voltage_v = 15.0  # the supply sags (a battery running down)
    assert m.bus_values()[0] == pytest.approx(15.0 - 0.5 * i)
    motor.apply_motor_torque(10.0 * KT, 50.0)
    assert m.bus_values()[0] < 15.0 and m.min_bus_voltage_v < 15.0


def test_parameters_are_checked():
    with pytest.raises(ValueError, match="motor_time_constant_s"):
        ThermalParams(motor_time_constant_s=0.0)
    with pytest.raises(ValueError, match="source_resistance_ohm"):
        ThermalParams(source_resistance_ohm=-1.0)
    with pytest.raises(ValueError, match="ambient_c"):
        ThermalParams(ambient_c=math.nan)


def test_the_simulated_odrive_reports_the_model_and_sends_it_cyclically():
    plant = FakeJointPlant({"knee": 0.0}, load_torque_nm=0.0)
    axis = SimOdriveAxis(DriverConfig(node_id=3, health_period_s=0.1, watchdog_timeout_s=0.0),
                         MotorJoint(plant, "knee"), C)
    names = [C.route(m.arbitration_id).codec.name for m in axis.due(0.0)]
    assert names == ["Heartbeat", "Get_Encoder_Estimates", "Get_Temperature", "Get_Bus_Voltage_Current", "Get_Iq"]
    assert [C.route(m.arbitration_id).codec.name for m in axis.due(0.05)] == ["Get_Encoder_Estimates"]
    assert "Get_Temperature" in [C.route(m.arbitration_id).codec.name for m in axis.due(0.1)]
    axis.thermal.ambient_c = 95.0
    axis.handle(data_frame(C.odrive_id(3, "Set_Controller_Mode"),
                           C.codec("Set_Controller_Mode").pack(int(ControlMode.TORQUE_CONTROL),
                                                               int(InputMode.PASSTHROUGH))), 0.1)
    axis.handle(data_frame(C.odrive_id(3, "Set_Axis_State"),
                           C.codec("Set_Axis_State").pack(int(AxisState.CLOSED_LOOP_CONTROL))), 0.1)
    for k in range(2000):
        axis.update(0.1 + k * 0.1, 0.1)
        plant.step(0.1)
    frames = {C.route(m.arbitration_id).codec.name: m for m in axis.due(201.0)}
    fet, motor = C.codec("Get_Temperature").unpack(frames["Get_Temperature"].data)
    assert motor > 90.0 and fet > 90.0  # 200 s at 95 C ambient, tau 60 s and 20 s
    assert DriverConfig(node_id=3).health_period_s == 0.0  # ODrive's default: not sent


def test_new_params_apply_from_the_next_step():
    hot = ThermalParams(motor_thermal_resistance_k_per_w=5.0, fet_resistance_ohm=0.05, fet_idle_loss_w=2.0,
                        fet_thermal_resistance_k_per_w=6.0, motor_time_constant_s=10.0, fet_time_constant_s=5.0)
    changed, fresh, default = held(10.0), held(10.0, hot), held(10.0)
    changed.step(0.01)
    changed.params = hot
    changed.motor_c = changed.fet_c = 25.0
    for _ in range(50):
        for model in (changed, fresh, default):
            model.step(0.01)
    assert changed.params is hot
    assert (changed.motor_c, changed.fet_c) == (fresh.motor_c, fresh.fet_c)
    assert fresh.fet_c > default.fet_c + 1.0 and fresh.motor_c > default.motor_c + 0.5  # (hot heats more)
