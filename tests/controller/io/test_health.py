"""Runtime health (issue 14): the drivers' readings, their bounds, and the safe stop beyond them;
and a heartbeat that reports an error, acted on in the tick it arrives."""

from __future__ import annotations

import dataclasses
import math

import pytest

from controller.config import ControllerConfig, default_axes
from controller.io.axis import AxisLink
from controller.io.health import HealthConfig, health_fault
from controller.io.sensors import SensorLink
from controller.settings.file import SECTIONS, config_from_dict
from controller.supervisor import Phase, Supervisor
from protocol import SENSOR_BOARD_NODE_ID, AxisError, AxisState, BusContract, data_frame
from tests.controller.test_loop import Leg, arm_and_run

C = BusContract.load()
TEMP, IQ, BUS = C.codec("Get_Temperature"), C.codec("Get_Iq"), C.codec("Get_Bus_Voltage_Current")


def temperature(node: int, fet_c: float, motor_c: float):
    return data_frame(C.odrive_id(node, "Get_Temperature"), TEMP.pack(fet_c, motor_c))


def bus_voltage(node: int, volts: float, amps: float = 0.5):
    return data_frame(C.odrive_id(node, "Get_Bus_Voltage_Current"), BUS.pack(volts, amps))


def iq(node: int, amps: float):
    return data_frame(C.odrive_id(node, "Get_Iq"), IQ.pack(amps, amps))


def hip() -> AxisLink:
    return AxisLink(default_axes()[0], C)


# -- the configuration -------------------------------------------------------------------------
def test_health_config_defaults_bounds_and_section():
    h = HealthConfig()
    assert (h.min_bus_voltage_v, h.max_bus_voltage_v, h.max_fet_temp_c, h.max_motor_temp_c, h.max_current_a,
            h.read_period_s) == (18.0, 56.0, 100.0, 90.0, 30.0, 0.1)
    assert ControllerConfig().health == h
    assert h.max_current_a > max(a.current_limit_a for a in default_axes())  # only a failed limit trips it
    with pytest.raises(ValueError, match="health.max_motor_temp_c"):
        HealthConfig(max_motor_temp_c=500.0)
    with pytest.raises(ValueError, match="min_bus_voltage_v"):
        HealthConfig(min_bus_voltage_v=50.0, max_bus_voltage_v=40.0)
    assert {s.key for s in SECTIONS["health"]} == {f.name for f in dataclasses.fields(HealthConfig)}


def test_the_health_section_reads_from_toml_tables():
    cfg = config_from_dict({"bus": {"interface": "virtual", "channel": "x"},
                            "health": {"max_motor_temp_c": 80.0, "min_bus_voltage_v": 40.0}})
    assert cfg.controller.health.max_motor_temp_c == 80.0 and cfg.controller.health.min_bus_voltage_v == 40.0


# -- the readings ----------------------------------------------------------------------------
def test_readings_are_kept_and_implausible_frames_refused():
    a = hip()
    assert a.fet_temp_c is None and a.motor_temp_c is None and a.iq_a is None and a.bus_voltage_v is None
    assert a.on_temperature((41.5, 60.25), 1.0) and (a.fet_temp_c, a.motor_temp_c, a.temperature_t_s) == (41.5, 60.25, 1.0)
    assert a.on_temperature((40.0, math.nan), 1.1) and a.motor_temp_c is None  # no motor thermistor
    assert not a.on_temperature((400.0, 30.0), 1.2) and a.fet_temp_c == 40.0  # nothing applied
    assert not a.on_temperature((30.0, math.inf), 1.2) and a.temperature_t_s == 1.1
    assert a.on_iq((5.0, -4.5), 2.0) and a.iq_a == -4.5
    assert not a.on_iq((5.0, math.nan), 2.1) and a.iq_a == -4.5


@pytest.mark.parametrize("reading, cause", [
    (dict(motor_temp_c=92.34), "hip motor temperature 92.3 C above 90 C"),
    (dict(fet_temp_c=101.0), "hip FET temperature 101.0 C above 100 C"),
    (dict(bus_voltage_v=16.04), "hip bus voltage 16.0 V below 18 V"),
    (dict(bus_voltage_v=57.5), "hip bus voltage 57.5 V above 56 V"),
    (dict(iq_a=-31.0), "hip motor current 31.0 A above 30 A"),
])
def test_a_reading_beyond_its_bound_names_axis_reading_and_bound(reading, cause):
    a = hip()
    assert health_fault(HealthConfig(), a) is None  # nothing read: nothing to say
    for key, value in reading.items():
        setattr(a, key, value)
    assert health_fault(HealthConfig(), a) == cause


def test_readings_within_bounds_are_healthy():
    a = hip()
    a.bus_voltage_v, a.fet_temp_c, a.motor_temp_c, a.iq_a = 24.0, 99.9, 90.0, 20.0
    assert health_fault(HealthConfig(), a) is None


# -- the supervisor ----------------------------------------------------------------------------
def _supervisor() -> Supervisor:
    axes = [AxisLink(cfg, C) for cfg in default_axes()]
    return Supervisor(axes, SensorLink(SENSOR_BOARD_NODE_ID), 0.35, 1.0, 1.0, health=HealthConfig())


def _hear(sup: Supervisor, t: float, state: AxisState) -> None:
    for a in sup.axes:
        assert a.on_heartbeat((0, int(state), 0, 1), t) and a.on_encoder((0.0, 0.0), t)
    assert sup.sensors.on_heartbeat((0, 1, 1, 0.0), t)


@pytest.mark.parametrize("phase", [Phase.ARMING, Phase.RAMP, Phase.WALK])
def test_beyond_a_bound_in_any_active_phase_is_a_latched_fault(phase):
    sup = _supervisor()
    _hear(sup, 0.0, AxisState.CLOSED_LOOP_CONTROL if phase is not Phase.ARMING else AxisState.IDLE)
    sup.enter(phase, 0.0)
    knee = sup.axes[1]
    assert knee.on_temperature((45.0, 90.5), 0.01)
    sup.update(0.01)
    assert sup.phase is Phase.FAULT and sup.fault_cause == "knee motor temperature 90.5 C above 90 C"
    assert knee.on_temperature((45.0, 30.0), 0.02)  # cooled down: still latched
    _hear(sup, 0.02, AxisState.IDLE)
    sup.update(0.02)
    assert sup.phase is Phase.FAULT


def test_outside_the_active_phases_a_bound_is_not_a_fault_and_silence_of_readings_is_none():
    sup = _supervisor()
    _hear(sup, 0.0, AxisState.IDLE)
    sup.update(0.0)
    assert sup.phase is Phase.INACTIVE
    assert sup.axes[0].on_bus_voltage((10.0, 0.0), 0.0)
    sup.update(0.01)
    assert sup.phase is Phase.INACTIVE  # idle axes: nothing to stop (arming would fault at once)
    sup.axes[0].bus_voltage_v = None
    _hear(sup, 0.1, AxisState.CLOSED_LOOP_CONTROL)
    sup.enter(Phase.WALK, 0.1)
    for k in range(1, 50):  # readings never came (or stopped): silence is the silence timeout's
        _hear(sup, 0.1 + 0.02 * k, AxisState.CLOSED_LOOP_CONTROL)
        sup.update(0.1 + 0.02 * k)
    assert sup.phase is Phase.WALK


# -- through the bus, the loop walking ------------------------------------------------------------
def _walking() -> Leg:
    leg = Leg()
    arm_and_run(leg, 800)
    assert leg.loop.phase is Phase.WALK
    return leg


def test_a_heartbeat_with_an_error_while_walking_is_a_fault_in_that_tick_naming_the_error():
    leg = _walking()
    leg.errors[1] = int(AxisError.MOTOR_OVER_TEMP)
    leg.tick()  # the heartbeat still says CLOSED_LOOP_CONTROL, with the error
    sup = leg.loop.supervisor
    assert leg.loop.phase is Phase.FAULT and leg.loop.io.dropped["invalid"] == 0
    name = AxisError(leg.errors[1]).name
    assert sup.fault_cause.startswith(f"axis knee reported {name} (") and "in closed loop" in sup.fault_cause
    assert sup.fault_t_s == pytest.approx(leg.t - leg.loop.config.period_s)  # the tick that drained it
    idle = C.codec("Set_Axis_State")
    last = [m for m in leg.bus.sent if m.arbitration_id == C.odrive_id(1, "Set_Axis_State")][-1]
    assert idle.unpack(last.data)[0] == AxisState.IDLE  # the safe stop, in that same tick


@pytest.mark.parametrize("frame, cause", [
    (temperature(0, 50.0, 92.3), "hip motor temperature 92.3 C above 90 C"),
    (bus_voltage(1, 15.0), "knee bus voltage 15.0 V below 18 V"),
    (iq(0, 35.0), "hip motor current 35.0 A above 30 A"),
])
def test_a_health_frame_beyond_a_bound_while_walking_stops_the_leg_in_that_tick(frame, cause):
    leg = _walking()
    leg.bus.push(temperature(0, 40.0, 40.0), bus_voltage(0, 24.0), iq(0, 3.0))  # healthy readings
    leg.tick()
    assert leg.loop.phase is Phase.WALK
    pos_before = sum(1 for m in leg.bus.sent if m.arbitration_id == C.odrive_id(0, "Set_Input_Pos"))
    leg.bus.push(frame)
    leg.tick()
    assert leg.loop.phase is Phase.FAULT and leg.loop.supervisor.fault_cause == cause
    leg.tick(5)
    assert sum(1 for m in leg.bus.sent if m.arbitration_id == C.odrive_id(0, "Set_Input_Pos")) == pos_before
