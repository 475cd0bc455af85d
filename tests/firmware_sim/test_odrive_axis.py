"""Frame-by-frame tests of the simulated ODrive axis and the motor model against the DBC layout."""

from __future__ import annotations

import math

import can
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from firmware_sim.motor import MotorJoint, MotorParams, Transmission
from firmware_sim.odrive_axis import DriverConfig, ProcedureResult, SimOdriveAxis
from protocol.contract import BusContract, arbitration_id
from protocol.odrive import AxisError, AxisState, Cmd, ControlMode, InputMode
from tests.fakes import FakeJointPlant

C = BusContract.load()
NODE = 3
DT = 0.001
KT = MotorParams().torque_constant_nm_per_a
TAU_MAX = KT * MotorParams().current_limit_a

GET_NAMES = [
    "Get_Version",
    "Heartbeat",
    "Get_Error",
    "Get_Encoder_Estimates",
    "Get_Iq",
    "Get_Temperature",
    "Get_Bus_Voltage_Current",
    "Get_Torques",
    "Get_Powers",
]


def make(plant=None, transmission=None, motor_params=None, node=NODE, **cfg):
    plant = plant if plant is not None else FakeJointPlant()
    motor = MotorJoint(plant, "knee", transmission or Transmission(), motor_params or MotorParams())
    axis = SimOdriveAxis(DriverConfig(node_id=node, **cfg), motor)
    return axis, plant, motor


def frame(name, *values, node=NODE, data=None):
    codec = C.codec(name)
    payload = codec.pack(*values) if data is None else data
    return can.Message(arbitration_id=arbitration_id(node, codec.cmd_id), data=payload, is_extended_id=False)


def rtr(name, node=NODE):
    codec = C.codec(name)
    return can.Message(
        arbitration_id=arbitration_id(node, codec.cmd_id), is_remote_frame=True, dlc=codec.dlc, is_extended_id=False
    )


def ask(axis, name, now=0.0):
    """Send an RTR and return the decoded single reply after checking its framing."""
    replies = axis.handle(rtr(name), now)
    assert len(replies) == 1
    reply = replies[0]
    codec = C.codec(name)
    assert reply.arbitration_id == arbitration_id(NODE, codec.cmd_id)
    assert reply.dlc == codec.dlc and len(reply.data) == codec.dlc
    assert not reply.is_remote_frame and not reply.is_extended_id
    return codec.decode(reply.data)


def arm(axis, now=0.0):
    axis.handle(frame("Set_Axis_State", AxisState.CLOSED_LOOP_CONTROL), now)
    assert axis.state is AxisState.CLOSED_LOOP_CONTROL


def run(axis, plant, t0, duration, every=None, action=None):
    """Step update + plant for ``duration``; call ``action(t)`` every ``every`` steps. Returns end time."""
    steps = round(duration / DT)
    t = t0
    for i in range(1, steps + 1):
        t = t0 + i * DT
        if action is not None and every and i % every == 0:
            action(t)
        axis.update(t, DT)
        plant.step(DT)
    return t


# --------------------------------------------------------------------------- motor model
def test_transmission_round_trip_with_direction_and_offset():
    tr = Transmission(gear_ratio=9.0, direction=-1, zero_offset_rev=0.25)
    assert tr.joint_to_motor_rev(0.0) == pytest.approx(0.25)
    assert tr.joint_to_motor_rev(2 * math.pi) == pytest.approx(0.25 - 9.0)
    for q in (-1.3, 0.0, 0.7, 3.0):
        assert tr.motor_rev_to_joint_rad(tr.joint_to_motor_rev(q)) == pytest.approx(q)
    assert tr.joint_vel_to_motor(2 * math.pi) == pytest.approx(-9.0)
    assert tr.motor_torque_to_joint(1.0) == pytest.approx(-9.0)


@pytest.mark.parametrize(
    "kwargs", [{"gear_ratio": 0.0}, {"gear_ratio": -2.0}, {"direction": 0}, {"direction": 2}, {"zero_offset_rev": math.nan}]
)
def test_transmission_rejects_bad_values(kwargs):
    with pytest.raises(ValueError):
        Transmission(**kwargs)


def test_motor_params_reject_bad_values():
    with pytest.raises(ValueError):
        MotorParams(current_limit_a=0.0)
    with pytest.raises(ValueError):
        MotorParams(phase_resistance_ohm=-1.0)
    assert MotorParams().max_torque_nm == pytest.approx(1.66)


def test_motor_joint_clamps_and_estimates_power():
    plant = FakeJointPlant()
    tr = Transmission(gear_ratio=6.0, direction=-1)
    motor = MotorJoint(plant, "knee", tr, MotorParams())
    plant.set_state("knee", 0.0, qd=-2 * math.pi / 6.0)  # motor turns at +1 rev/s
    assert motor.motor_state()[1] == pytest.approx(1.0)
    applied = motor.apply_motor_torque(5.0)
    assert applied == pytest.approx(TAU_MAX)
    assert plant.torque("knee") == pytest.approx(-6.0 * TAU_MAX)
    assert motor.iq_setpoint_a == pytest.approx(5.0 / KT)
    assert motor.iq_measured_a == pytest.approx(20.0)
    assert motor.torque_estimate_nm == pytest.approx(TAU_MAX)
    mech = TAU_MAX * 2 * math.pi
    assert motor.mechanical_power_w == pytest.approx(mech)
    assert motor.electrical_power_w == pytest.approx(20.0**2 * 0.04 + mech)
    assert motor.bus_current_a == pytest.approx((20.0**2 * 0.04 + mech) / 24.0)
    assert motor.apply_motor_torque(-0.5) == pytest.approx(-0.5)
    assert plant.torque("knee") == pytest.approx(3.0)
    assert motor.apply_motor_torque(math.nan) == 0.0
    assert plant.torque("knee") == 0.0


# --------------------------------------------------------------------------- config
@pytest.mark.parametrize(
    "kwargs",
    [
        {"node_id": 16},
        {"node_id": 64},
        {"node_id": -1},
        {"node_id": 1, "pos_gain": -1.0},
        {"node_id": 1, "watchdog_timeout_s": math.inf},
        {"node_id": 1, "pos_min_rev": 2.0, "pos_max_rev": 1.0},
        {"node_id": 1, "fw_version": (0, 6, 300)},
    ],
)
def test_driver_config_rejects_bad_values(kwargs):
    with pytest.raises(ValueError):
        DriverConfig(**kwargs)


# --------------------------------------------------------------------------- state machine
def test_power_on_state():
    axis, _, _ = make()
    assert axis.state is AxisState.IDLE
    assert axis.errors == AxisError.NONE
    assert axis.control_mode is ControlMode.POSITION_CONTROL
    assert axis.input_mode is InputMode.PASSTHROUGH
    hb = ask(axis, "Heartbeat")
    assert hb == {"Axis_Error": 0, "Axis_State": AxisState.IDLE, "Procedure_Result": 0, "Trajectory_Done_Flag": 1}


def test_closed_loop_entry_holds_current_position():
    plant = FakeJointPlant({"knee": 0.4})
    axis, plant, motor = make(plant=plant)
    axis.handle(frame("Set_Input_Pos", 5.0, 0.0, 0.0), 0.0)  # stale target while idle
    arm(axis)
    expected = Transmission().joint_to_motor_rev(0.4)
    assert axis.input_pos_rev == pytest.approx(expected)
    assert axis.vel_integrator_nm == 0.0
    axis.update(DT, DT)
    assert abs(plant.torque("knee")) < 1e-9  # no jump towards the stale target
    assert ask(axis, "Heartbeat")["Axis_State"] == AxisState.CLOSED_LOOP_CONTROL


def test_idle_request_leaves_closed_loop_and_zeroes_torque():
    axis, plant, _ = make()
    arm(axis)
    axis.handle(frame("Set_Input_Torque", 1.0), 0.0)
    axis.handle(frame("Set_Controller_Mode", ControlMode.TORQUE_CONTROL, InputMode.PASSTHROUGH), 0.0)
    axis.handle(frame("Set_Input_Torque", 1.0), 0.0)
    axis.update(DT, DT)
    assert plant.torque("knee") == pytest.approx(6.0)
    axis.handle(frame("Set_Axis_State", AxisState.IDLE), DT)
    assert axis.state is AxisState.IDLE
    axis.update(2 * DT, DT)
    assert plant.torque("knee") == 0.0


def test_closed_loop_refused_while_errors_active():
    axis, _, _ = make()
    axis.handle(frame("Estop"), 0.0)
    axis.handle(frame("Set_Axis_State", AxisState.CLOSED_LOOP_CONTROL), 0.01)
    assert axis.state is AxisState.IDLE
    hb = ask(axis, "Heartbeat")
    assert hb["Axis_State"] == AxisState.IDLE
    assert hb["Procedure_Result"] == ProcedureResult.DISARMED
    assert hb["Axis_Error"] & AxisError.ESTOP_REQUESTED


def test_calibration_states_complete_instantly_to_idle():
    axis, _, _ = make()
    arm(axis)
    axis.handle(frame("Set_Axis_State", AxisState.FULL_CALIBRATION_SEQUENCE), 0.0)
    assert axis.state is AxisState.IDLE
    assert axis.procedure_result == ProcedureResult.SUCCESS
    assert axis.stats["unsupported"] == 0


@pytest.mark.parametrize("state", [0, 5, 15, 99, 0xFFFFFFFF])
def test_unknown_state_numbers_ignored_and_counted(state):
    axis, _, _ = make()
    arm(axis)
    axis.handle(frame("Set_Axis_State", state), 0.0)
    assert axis.state is AxisState.CLOSED_LOOP_CONTROL
    assert axis.stats["unsupported"] == 1


def test_estop_latches_until_clear_errors():
    axis, _, _ = make()
    arm(axis)
    axis.handle(frame("Estop"), 0.01)
    assert axis.state is AxisState.IDLE
    assert axis.errors & AxisError.ESTOP_REQUESTED
    err = ask(axis, "Get_Error")
    assert err["Active_Errors"] == AxisError.ESTOP_REQUESTED
    assert err["Disarm_Reason"] == AxisError.ESTOP_REQUESTED
    for t in (0.02, 0.03):
        axis.handle(frame("Set_Axis_State", AxisState.CLOSED_LOOP_CONTROL), t)
        assert axis.state is AxisState.IDLE
    axis.handle(frame("Clear_Errors", data=b""), 0.04)  # DLC 0 accepted
    assert axis.errors == AxisError.NONE
    hb = ask(axis, "Heartbeat")
    assert hb["Axis_Error"] == 0 and hb["Procedure_Result"] == ProcedureResult.SUCCESS
    axis.handle(frame("Set_Axis_State", AxisState.CLOSED_LOOP_CONTROL), 0.05)
    assert axis.state is AxisState.CLOSED_LOOP_CONTROL
    assert axis.stats["malformed"] == 0


def test_clear_errors_with_identify_byte():
    axis, _, _ = make()
    axis.handle(frame("Estop", data=b"\x00\x01"), 0.0)  # Estop accepts any length
    assert axis.errors & AxisError.ESTOP_REQUESTED
    axis.handle(frame("Clear_Errors", 1), 0.0)
    assert axis.errors == AxisError.NONE


def test_controller_mode_voltage_is_ignored():
    axis, _, _ = make()
    axis.handle(frame("Set_Controller_Mode", ControlMode.VOLTAGE_CONTROL, InputMode.PASSTHROUGH), 0.0)
    assert axis.control_mode is ControlMode.POSITION_CONTROL
    axis.handle(frame("Set_Controller_Mode", ControlMode.VELOCITY_CONTROL, 42), 0.0)
    assert axis.control_mode is ControlMode.POSITION_CONTROL
    assert axis.stats["unsupported"] == 2
    axis.handle(frame("Set_Controller_Mode", ControlMode.VELOCITY_CONTROL, InputMode.POS_FILTER), 0.0)
    assert axis.control_mode is ControlMode.VELOCITY_CONTROL
    assert axis.input_mode is InputMode.POS_FILTER


def test_reboot_restores_power_on_state_and_saved_configuration():
    axis, _, _ = make()
    arm(axis)
    axis.handle(frame("Set_Pos_Gain", 50.0), 0.0)
    axis.handle(frame("Estop"), 0.0)
    axis.handle(frame("Reboot", 0), 0.0)
    assert axis.state is AxisState.IDLE and axis.errors == AxisError.NONE
    assert axis.pos_gain == pytest.approx(30.0)
    axis.handle(frame("Set_Pos_Gain", 50.0), 0.0)
    axis.handle(frame("Reboot", 1), 0.0)  # save configuration, then reboot
    assert axis.pos_gain == pytest.approx(50.0)
    axis.handle(frame("Reboot", data=b""), 0.0)  # DLC 0: plain reboot
    assert axis.pos_gain == pytest.approx(50.0)
    axis.handle(frame("Reboot", 2), 0.0)  # erase configuration
    assert axis.pos_gain == pytest.approx(30.0)
    axis.handle(frame("Reboot", 3), 0.0)  # DFU: not simulated
    assert axis.stats["unsupported"] == 1


def test_gain_and_limit_commands_update_the_controller():
    axis, _, _ = make()
    axis.handle(frame("Set_Pos_Gain", 12.5), 0.0)
    axis.handle(frame("Set_Vel_Gains", 0.1, 0.2), 0.0)
    axis.handle(frame("Set_Limits", 7.5, 4.0), 0.0)
    assert (axis.pos_gain, axis.vel_gain, axis.vel_integrator_gain) == pytest.approx((12.5, 0.1, 0.2))
    assert (axis.vel_limit_rev_s, axis.current_limit_a) == pytest.approx((7.5, 4.0))
    assert axis.torque_limit_nm == pytest.approx(KT * 4.0)
    axis.handle(frame("Set_Limits", -1.0, 4.0), 0.0)
    axis.handle(frame("Set_Vel_Gains", math.nan, 0.2), 0.0)
    assert axis.vel_limit_rev_s == pytest.approx(7.5) and axis.vel_gain == pytest.approx(0.1)
    assert axis.stats["malformed"] == 2


def test_set_absolute_position_offsets_the_estimate():
    plant = FakeJointPlant({"knee": 0.3})
    axis, _, _ = make(plant=plant)
    axis.handle(frame("Set_Absolute_Position", 10.0), 0.0)
    assert ask(axis, "Get_Encoder_Estimates")["Pos_Estimate"] == pytest.approx(10.0, abs=1e-5)
    plant.set_state("knee", 0.3 + 2 * math.pi / 6.0)  # one more motor turn
    assert ask(axis, "Get_Encoder_Estimates")["Pos_Estimate"] == pytest.approx(11.0, abs=1e-5)


# --------------------------------------------------------------------------- RTR replies
@pytest.mark.parametrize("name", GET_NAMES)
def test_every_get_answers_an_rtr_with_its_id_and_dlc(name):
    axis, _, _ = make()
    ask(axis, name)  # framing asserted inside
    assert axis.stats["tx"][name] == 1
    assert axis.stats["rx"][name] == 1


def test_get_request_as_empty_data_frame_is_answered():
    axis, _, _ = make()
    replies = axis.handle(frame("Get_Encoder_Estimates", data=b""), 0.0)
    assert len(replies) == 1 and replies[0].dlc == 8


def test_get_reply_values():
    plant = FakeJointPlant({"knee": 0.5})
    plant.set_state("knee", 0.5, qd=1.5)
    tr = Transmission(gear_ratio=6.0, direction=-1, zero_offset_rev=0.2)
    axis, plant, motor = make(plant=plant, transmission=tr, hw_version=(3, 6, 56), fw_version=(0, 6, 10))
    assert ask(axis, "Get_Version") == {
        "Protocol_Version": 2,
        "Hw_Version_Major": 3,
        "Hw_Version_Minor": 6,
        "Hw_Version_Variant": 56,
        "Fw_Version_Major": 0,
        "Fw_Version_Minor": 6,
        "Fw_Version_Revision": 10,
        "Fw_Version_Unreleased": 0,
    }
    enc = ask(axis, "Get_Encoder_Estimates")
    assert enc["Pos_Estimate"] == pytest.approx(tr.joint_to_motor_rev(0.5), rel=1e-6)
    assert enc["Vel_Estimate"] == pytest.approx(tr.joint_vel_to_motor(1.5), rel=1e-6)
    # Torque mode, 0.5 Nm: Iq, torques, powers and bus current follow.
    arm(axis)
    axis.handle(frame("Set_Controller_Mode", ControlMode.TORQUE_CONTROL, InputMode.PASSTHROUGH), 0.0)
    axis.handle(frame("Set_Input_Torque", 0.5), 0.0)
    axis.update(DT, DT)
    iq = ask(axis, "Get_Iq")
    assert iq["Iq_Setpoint"] == pytest.approx(0.5 / KT, rel=1e-6)
    assert iq["Iq_Measured"] == pytest.approx(0.5 / KT, rel=1e-6)
    tq = ask(axis, "Get_Torques")
    assert tq["Torque_Target"] == pytest.approx(0.5) and tq["Torque_Estimate"] == pytest.approx(0.5)
    vel = tr.joint_vel_to_motor(1.5)
    pw = ask(axis, "Get_Powers")
    assert pw["Mechanical_Power"] == pytest.approx(0.5 * vel * 2 * math.pi, rel=1e-5)
    assert pw["Electrical_Power"] == pytest.approx((0.5 / KT) ** 2 * 0.04 + 0.5 * vel * 2 * math.pi, rel=1e-5)
    bus = ask(axis, "Get_Bus_Voltage_Current")
    assert bus["Bus_Voltage"] == pytest.approx(24.0 - 0.2 * bus["Bus_Current"], rel=1e-6)  # sags under load
    assert bus["Bus_Current"] == pytest.approx(pw["Electrical_Power"] / 24.0, rel=1e-5)
    temps = ask(axis, "Get_Temperature")
    # the thermal model (firmware_sim.thermal) after one 1 ms step: still at the 25 C ambient
    assert temps["FET_Temperature"] == pytest.approx(25.0, abs=0.01)
    assert temps["Motor_Temperature"] == pytest.approx(25.0, abs=0.01)
    err = ask(axis, "Get_Error")
    assert err == {"Active_Errors": 0, "Disarm_Reason": 0}


def test_rtr_for_a_command_is_malformed():
    axis, _, _ = make()
    replies = axis.handle(rtr("Set_Axis_State"), 0.0)
    assert replies == []
    assert axis.state is AxisState.IDLE
    assert axis.stats["malformed"] == 1


# --------------------------------------------------------------------------- cyclic frames
def _count_cyclic(axis, duration, t0=0.0, accumulate=False):
    counts = {"Heartbeat": 0, "Get_Encoder_Estimates": 0}
    times = {"Heartbeat": [], "Get_Encoder_Estimates": []}
    t = t0
    for i in range(round(duration / DT)):
        t = t + DT if accumulate and i else t0 + i * DT
        for msg in axis.due(t):
            route = C.route(msg.arbitration_id)
            assert route.node_id == NODE
            counts[route.codec.name] += 1
            times[route.codec.name].append(t)
    return counts, times


def test_cyclic_rates_over_one_second():
    axis, _, _ = make()
    counts, times = _count_cyclic(axis, 1.0)
    assert 9 <= counts["Heartbeat"] <= 11
    assert 499 <= counts["Get_Encoder_Estimates"] <= 501
    gaps = [b - a for a, b in zip(times["Get_Encoder_Estimates"], times["Get_Encoder_Estimates"][1:])]
    assert max(gaps) == pytest.approx(0.002, abs=1e-6) and min(gaps) == pytest.approx(0.002, abs=1e-6)


def test_cyclic_schedule_does_not_drift_with_accumulated_time():
    axis, _, _ = make()
    counts, _ = _count_cyclic(axis, 10.0, accumulate=True)
    assert 99 <= counts["Heartbeat"] <= 101
    assert 4999 <= counts["Get_Encoder_Estimates"] <= 5001


def test_cyclic_schedule_resyncs_after_a_long_pause():
    axis, _, _ = make()
    assert len(axis.due(0.0)) == 2
    assert len(axis.due(5.0)) == 2  # one of each, not a burst of catch-up frames
    assert axis.due(5.001) == []
    assert [C.route(m.arbitration_id).codec.name for m in axis.due(5.002)] == ["Get_Encoder_Estimates"]


def test_zero_period_disables_cyclic_frames():
    axis, _, _ = make(heartbeat_period_s=0.0, encoder_period_s=0.0)
    counts, _ = _count_cyclic(axis, 0.5)
    assert counts == {"Heartbeat": 0, "Get_Encoder_Estimates": 0}


def test_cyclic_encoder_frame_reports_the_plant():
    plant = FakeJointPlant({"knee": -0.2})
    axis, _, _ = make(plant=plant)
    enc = [m for m in axis.due(0.0) if m.arbitration_id == arbitration_id(NODE, Cmd.GET_ENCODER_ESTIMATES)]
    pos, vel = C.codec("Get_Encoder_Estimates").unpack(enc[0].data)
    assert pos == pytest.approx(Transmission().joint_to_motor_rev(-0.2), rel=1e-6)
    assert vel == 0.0


# --------------------------------------------------------------------------- watchdog
def test_watchdog_expires_without_commands():
    axis, plant, _ = make(watchdog_timeout_s=0.1)
    arm(axis, 0.0)
    run(axis, plant, 0.0, 0.1)
    assert axis.state is AxisState.CLOSED_LOOP_CONTROL  # exactly at the timeout: not yet
    run(axis, plant, 0.1, 0.005)
    assert axis.state is AxisState.IDLE
    assert axis.errors & AxisError.WATCHDOG_TIMER_EXPIRED
    hb = [m for m in axis.due(0.2) if m.arbitration_id == arbitration_id(NODE, Cmd.HEARTBEAT)][0]
    decoded = C.codec("Heartbeat").decode(hb.data)
    assert decoded["Axis_Error"] & AxisError.WATCHDOG_TIMER_EXPIRED
    assert decoded["Axis_State"] == AxisState.IDLE
    assert decoded["Procedure_Result"] == ProcedureResult.DISARMED
    axis.handle(frame("Set_Axis_State", AxisState.CLOSED_LOOP_CONTROL), 0.3)
    assert axis.state is AxisState.IDLE  # latched until Clear_Errors


def test_watchdog_fed_regularly_stays_closed_loop():
    axis, plant, _ = make(watchdog_timeout_s=0.1)
    arm(axis, 0.0)
    run(axis, plant, 0.0, 1.0, every=50, action=lambda t: axis.handle(frame("Set_Input_Pos", 0.0, 0.0, 0.0), t))
    assert axis.state is AxisState.CLOSED_LOOP_CONTROL
    assert axis.errors == AxisError.NONE


def test_rtr_requests_do_not_feed_the_watchdog():
    axis, plant, _ = make(watchdog_timeout_s=0.1)
    arm(axis, 0.0)
    run(axis, plant, 0.0, 0.3, every=10, action=lambda t: axis.handle(rtr("Get_Encoder_Estimates"), t))
    assert axis.state is AxisState.IDLE
    assert axis.errors & AxisError.WATCHDOG_TIMER_EXPIRED


def test_watchdog_checked_before_a_late_frame_is_processed():
    axis, _, _ = make(watchdog_timeout_s=0.1)
    arm(axis, 0.0)
    axis.handle(frame("Set_Input_Pos", 0.0, 0.0, 0.0), 0.5)  # no update() ran in between
    assert axis.state is AxisState.IDLE
    assert axis.errors & AxisError.WATCHDOG_TIMER_EXPIRED


def test_watchdog_disabled_with_zero_timeout():
    axis, plant, _ = make(watchdog_timeout_s=0.0)
    arm(axis, 0.0)
    run(axis, plant, 0.0, 0.5)
    assert axis.state is AxisState.CLOSED_LOOP_CONTROL


# --------------------------------------------------------------------------- malformed / unknown
def test_short_and_nan_frames_are_counted_and_ignored():
    axis, _, _ = make()
    arm(axis)
    before = axis.input_pos_rev
    good = C.codec("Set_Input_Pos").pack(1.0, 0.0, 0.0)
    assert axis.handle(frame("Set_Input_Pos", data=good[:4]), 0.0) == []
    assert axis.handle(frame("Set_Input_Pos", math.nan, 0.0, 0.0), 0.0) == []
    assert axis.handle(frame("Set_Input_Pos", math.inf, 0.0, 0.0), 0.0) == []
    assert axis.handle(frame("Set_Input_Vel", 1.0, math.nan), 0.0) == []
    assert axis.handle(frame("Set_Input_Torque", -math.inf), 0.0) == []
    assert axis.handle(frame("Set_Axis_State", data=b"\x08"), 0.0) == []
    assert axis.input_pos_rev == before
    assert axis.input_vel_rev_s == 0.0 and axis.input_torque_nm == 0.0
    assert axis.stats["malformed"] == 6
    axis.update(DT, DT)
    assert math.isfinite(axis.torque_setpoint_nm)


def test_malformed_frames_do_not_feed_the_watchdog():
    axis, plant, _ = make(watchdog_timeout_s=0.1)
    arm(axis, 0.0)
    run(axis, plant, 0.0, 0.3, every=10, action=lambda t: axis.handle(frame("Set_Input_Pos", math.nan, 0, 0), t))
    assert axis.state is AxisState.IDLE


def test_unknown_ids_extended_and_foreign_frames_are_counted():
    axis, _, _ = make()
    for cmd in (0x08, 0x10, 0x1E):  # ids ODrive 0.6.10's DBC leaves unused
        assert axis.handle(can.Message(arbitration_id=NODE << 5 | cmd, data=b"\0" * 8, is_extended_id=False), 0.0) == []
    assert axis.stats["unknown"] == 3
    # TxSdo is what the driver sends: received, it is malformed (no handler), not unknown
    assert axis.handle(can.Message(arbitration_id=NODE << 5 | 0x05, data=b"\0" * 8, is_extended_id=False), 0.0) == []
    assert axis.stats["unknown"] == 3 and axis.stats["malformed"] == 1
    ext = can.Message(arbitration_id=NODE << 5 | Cmd.SET_AXIS_STATE, data=b"\x08\0\0\0", is_extended_id=True)
    assert axis.handle(ext, 0.0) == []
    assert axis.stats["unknown"] == 4
    assert axis.handle(frame("Set_Axis_State", AxisState.CLOSED_LOOP_CONTROL, node=NODE + 1), 0.0) == []
    assert axis.stats["foreign"] == 1
    assert axis.state is AxisState.IDLE


def test_data_frame_with_payload_on_a_get_id_is_malformed():
    axis, _, _ = make()
    assert axis.handle(frame("Heartbeat", 0, 1, 0, 1), 0.0) == []
    assert axis.stats["malformed"] == 1


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    frames=st.lists(
        st.tuples(
            st.one_of(st.integers(0, 31).map(lambda c: NODE << 5 | c), st.integers(0, 0x7FF), st.integers(0, 0x1FFFFFFF)),
            st.binary(max_size=8),
            st.booleans(),
            st.booleans(),
        ),
        max_size=25,
    )
)
def test_fuzzed_frames_never_raise(frames):
    axis, plant, _ = make(pos_min_rev=-2.0, pos_max_rev=2.0)
    t = 0.0
    for arb_id, data, remote, extended in frames:
        extended = extended or arb_id > 0x7FF
        msg = can.Message(
            arbitration_id=arb_id,
            data=None if remote else data,
            dlc=len(data),
            is_remote_frame=remote,
            is_extended_id=extended,
        )
        replies = axis.handle(msg, t)
        for reply in replies:
            assert reply.arbitration_id >> 5 == NODE and not reply.is_remote_frame
        t += DT
        axis.update(t, DT)
        plant.step(DT)
        axis.due(t)
    assert axis.stats["internal_errors"] == 0
    assert axis.state in (AxisState.IDLE, AxisState.CLOSED_LOOP_CONTROL)
    assert math.isfinite(axis.torque_setpoint_nm)
    assert abs(axis.torque_setpoint_nm) <= TAU_MAX + 1e-9
    assert all(math.isfinite(v) for v in plant.joint_state("knee"))


# --------------------------------------------------------------------------- control loop
def _feed_target(axis, target):
    return lambda t: axis.handle(frame("Set_Input_Pos", target, 0.0, 0.0), t)


@pytest.mark.parametrize("direction", [1, -1])
def test_position_loop_drives_the_joint_to_the_target(direction):
    tr = Transmission(gear_ratio=6.0, direction=direction, zero_offset_rev=0.3)
    axis, plant, motor = make(plant=FakeJointPlant({"knee": 0.1}), transmission=tr)
    arm(axis)
    target = axis.input_pos_rev + 1.0
    run(axis, plant, 0.0, 3.0, every=20, action=_feed_target(axis, target))
    pos, vel = motor.motor_state()
    assert pos == pytest.approx(target, abs=2e-3)
    assert abs(vel) < 0.05
    assert plant.joint_state("knee")[0] == pytest.approx(tr.motor_rev_to_joint_rad(target), abs=1e-3)


def test_integrator_removes_steady_state_error_under_load():
    plant = FakeJointPlant(load_torque_nm=-3.0)
    axis, plant, motor = make(plant=plant)
    arm(axis)
    run(axis, plant, 0.0, 0.3, every=20, action=_feed_target(axis, 0.5))
    early_error = abs(motor.motor_state()[0] - 0.5)
    run(axis, plant, 0.3, 5.0, every=20, action=_feed_target(axis, 0.5))
    late_error = abs(motor.motor_state()[0] - 0.5)
    assert early_error > 0.01  # the load pulls the joint off target at first
    assert late_error < 1e-3
    assert axis.vel_integrator_nm == pytest.approx(3.0 / 6.0, rel=0.02)


def test_velocity_mode_tracks_input_velocity():
    axis, plant, motor = make()
    arm(axis)
    axis.handle(frame("Set_Controller_Mode", ControlMode.VELOCITY_CONTROL, InputMode.PASSTHROUGH), 0.0)
    feed = lambda t: axis.handle(frame("Set_Input_Vel", 3.0, 0.0), t)  # noqa: E731
    feed(0.0)
    run(axis, plant, 0.0, 1.0, every=20, action=feed)
    assert motor.motor_state()[1] == pytest.approx(3.0, abs=0.02)


def test_velocity_setpoint_clamped_to_velocity_limit():
    axis, plant, motor = make()
    arm(axis)
    axis.handle(frame("Set_Limits", 2.0, 20.0), 0.0)
    axis.handle(frame("Set_Controller_Mode", ControlMode.VELOCITY_CONTROL, InputMode.PASSTHROUGH), 0.0)
    feed = lambda t: axis.handle(frame("Set_Input_Vel", 10.0, 0.0), t)  # noqa: E731
    feed(0.0)
    run(axis, plant, 0.0, 1.0, every=20, action=feed)
    assert motor.motor_state()[1] == pytest.approx(2.0, abs=0.05)


def test_torque_mode_applies_input_torque_through_the_transmission():
    tr = Transmission(gear_ratio=6.0, direction=-1)
    axis, plant, motor = make(transmission=tr)
    arm(axis)
    axis.handle(frame("Set_Controller_Mode", ControlMode.TORQUE_CONTROL, InputMode.PASSTHROUGH), 0.0)
    axis.handle(frame("Set_Input_Torque", 0.4), 0.0)
    axis.update(DT, DT)
    assert plant.torque("knee") == pytest.approx(-0.4 * 6.0, rel=1e-6)
    assert motor.iq_measured_a == pytest.approx(0.4 / KT, rel=1e-6)


def test_torque_clamp_respected_in_every_mode():
    axis, plant, motor = make(watchdog_timeout_s=0.0)
    arm(axis)
    peak = 0.0

    def track(t):
        nonlocal peak
        peak = max(peak, abs(plant.torque("knee")))

    axis.handle(frame("Set_Input_Pos", 50.0, 0.0, 0.0), 0.0)  # far target: saturates
    run(axis, plant, 0.0, 0.2, every=1, action=track)
    assert peak == pytest.approx(TAU_MAX * 6.0, rel=1e-9)  # reached and not exceeded
    axis.handle(frame("Set_Limits", 20.0, 5.0), 0.2)
    axis.handle(frame("Set_Controller_Mode", ControlMode.TORQUE_CONTROL, InputMode.PASSTHROUGH), 0.2)
    axis.handle(frame("Set_Input_Torque", -100.0), 0.2)
    plant.set_state("knee", 0.0, 0.0)
    axis.update(0.201, DT)
    assert plant.torque("knee") == pytest.approx(-KT * 5.0 * 6.0, rel=1e-6)
    assert axis.torque_setpoint_nm == pytest.approx(-KT * 5.0, rel=1e-6)
    axis.handle(frame("Set_Limits", 20.0, 500.0), 0.2)  # above the hardware limit
    axis.update(0.202, DT)
    assert abs(plant.torque("knee")) <= TAU_MAX * 6.0 + 1e-9


def test_torque_mode_backs_off_at_the_velocity_limit():
    axis, plant, motor = make()
    arm(axis)
    axis.handle(frame("Set_Controller_Mode", ControlMode.TORQUE_CONTROL, InputMode.PASSTHROUGH), 0.0)
    axis.handle(frame("Set_Limits", 5.0, 20.0), 0.0)
    feed = lambda t: axis.handle(frame("Set_Input_Torque", 1.0), t)  # noqa: E731
    run(axis, plant, 0.0, 2.0, every=20, action=feed)
    assert motor.motor_state()[1] <= 5.0 + 0.05
    assert motor.motor_state()[1] > 4.5


def test_targets_outside_limits_are_counted_but_accepted():
    axis, _, _ = make(pos_min_rev=-1.0, pos_max_rev=2.0)
    for target in (-1.5, 0.0, 2.0, 2.5, -1.0):
        axis.handle(frame("Set_Input_Pos", target, 0.0, 0.0), 0.0)
    assert axis.targets_outside_limits == 2
    assert axis.stats["targets_outside_limits"] == 2
    assert axis.input_pos_rev == pytest.approx(-1.0)
    axis2, _, _ = make(pos_max_rev=0.5)  # one-sided limit
    axis2.handle(frame("Set_Input_Pos", -100.0, 0.0, 0.0), 0.0)
    axis2.handle(frame("Set_Input_Pos", 0.6, 0.0, 0.0), 0.0)
    assert axis2.targets_outside_limits == 1


def test_idle_applies_zero_torque_every_step():
    axis, plant, _ = make()
    plant.set_joint_torque("knee", 3.0)
    calls = plant.torque_calls
    axis.update(DT, DT)
    assert plant.torque("knee") == 0.0
    assert plant.torque_calls == calls + 1


def test_integrator_does_not_wind_up_while_torque_saturates():
    plant = FakeJointPlant(load_torque_nm=-30.0)  # stronger than the motor: stalls against it
    axis, plant, _ = make(plant=plant, watchdog_timeout_s=0.0)
    arm(axis)
    axis.handle(frame("Set_Input_Pos", 5.0, 0.0, 0.0), 0.0)
    run(axis, plant, 0.0, 1.0)
    assert axis.torque_setpoint_nm == pytest.approx(TAU_MAX)
    assert abs(axis.vel_integrator_nm) < 0.05


# --------------------------------------------------------------------------- safety latches
def test_estop_stays_latched_through_idle_calibration_and_time_until_clear_errors():
    axis, plant, _ = make(watchdog_timeout_s=0.0)
    arm(axis)
    axis.handle(frame("Estop"), 0.0)
    assert axis.state is AxisState.IDLE and axis.stats["estops"] == 1
    t = 0.0
    for request in (AxisState.IDLE, AxisState.FULL_CALIBRATION_SEQUENCE, AxisState.CLOSED_LOOP_CONTROL):
        axis.handle(frame("Set_Axis_State", request), t)
        t = run(axis, plant, t, 0.5)  # time passing clears nothing
        axis.handle(frame("Set_Axis_State", AxisState.CLOSED_LOOP_CONTROL), t)
        assert axis.state is AxisState.IDLE
        assert axis.errors & AxisError.ESTOP_REQUESTED
        assert ask(axis, "Heartbeat", t)["Procedure_Result"] == ProcedureResult.DISARMED
    assert plant.torque("knee") == 0.0
    axis.handle(frame("Estop"), t)  # a second Estop while latched: counted, still latched
    assert axis.stats["estops"] == 2
    axis.handle(frame("Clear_Errors", 0), t)
    axis.handle(frame("Set_Axis_State", AxisState.CLOSED_LOOP_CONTROL), t)
    assert axis.state is AxisState.CLOSED_LOOP_CONTROL and axis.errors == AxisError.NONE


def test_estop_while_idle_latches_and_reboot_clears_it():
    axis, _, _ = make()
    axis.handle(frame("Estop"), 0.0)
    assert axis.state is AxisState.IDLE and axis.errors & AxisError.ESTOP_REQUESTED
    axis.handle(frame("Reboot", 0), 0.0)  # power-on state: no error
    assert axis.errors == AxisError.NONE
    arm(axis)


def test_watchdog_trip_is_latched_until_clear_errors_then_rearms():
    axis, plant, _ = make(watchdog_timeout_s=0.1)
    arm(axis, 0.0)
    t = run(axis, plant, 0.0, 0.2)
    assert axis.state is AxisState.IDLE and axis.stats["watchdog_trips"] == 1
    t = run(axis, plant, t, 0.5)  # stays tripped, counted once
    assert axis.stats["watchdog_trips"] == 1
    assert ask(axis, "Get_Error") == {"Active_Errors": AxisError.WATCHDOG_TIMER_EXPIRED,
                                      "Disarm_Reason": AxisError.WATCHDOG_TIMER_EXPIRED}
    axis.handle(frame("Set_Input_Pos", 0.0, 0.0, 0.0), t)  # a command feeds, but does not re-arm
    assert axis.state is AxisState.IDLE
    axis.handle(frame("Clear_Errors", 0), t)
    assert ask(axis, "Heartbeat", t)["Axis_Error"] == 0
    axis.handle(frame("Set_Axis_State", AxisState.CLOSED_LOOP_CONTROL), t)
    assert axis.state is AxisState.CLOSED_LOOP_CONTROL


def test_watchdog_idle_axis_accumulates_no_error_and_arming_feeds_it():
    axis, plant, _ = make(watchdog_timeout_s=0.1)
    t = run(axis, plant, 0.0, 2.0)  # idle for 2 s without a single frame
    assert axis.errors == AxisError.NONE
    arm(axis, t)
    t = run(axis, plant, t, 0.09)
    assert axis.state is AxisState.CLOSED_LOOP_CONTROL  # entry fed the watchdog


def test_other_nodes_frames_do_not_feed_the_watchdog():
    axis, plant, _ = make(watchdog_timeout_s=0.1)
    arm(axis, 0.0)
    other = lambda t: axis.handle(frame("Set_Input_Pos", 0.0, 0.0, 0.0, node=NODE + 1), t)  # noqa: E731
    run(axis, plant, 0.0, 0.3, every=10, action=other)
    assert axis.state is AxisState.IDLE and axis.errors & AxisError.WATCHDOG_TIMER_EXPIRED


# --------------------------------------------------------------------------- position limits
LIMITS = dict(pos_min_rev=-1.0, pos_max_rev=2.0, watchdog_timeout_s=0.0)


def _put_motor_at(plant, tr, pos_rev):
    plant.set_state("knee", tr.motor_rev_to_joint_rad(pos_rev))


@pytest.mark.parametrize("direction", [1, -1])
@pytest.mark.parametrize("side", ["min", "max"])
def test_joint_pushed_past_its_limit_disarms_with_position_limit_violation(direction, side):
    tr = Transmission(gear_ratio=6.0, direction=direction, zero_offset_rev=0.1)
    axis, plant, _ = make(transmission=tr, **LIMITS)
    margin = axis.config.pos_limit_margin_rev
    edge, sign = (-1.0, -1.0) if side == "min" else (2.0, 1.0)
    _put_motor_at(plant, tr, edge + sign * 0.9 * margin)  # past the limit, within the margin
    arm(axis)
    axis.update(DT, DT)
    assert axis.state is AxisState.CLOSED_LOOP_CONTROL and axis.stats["position_limit_trips"] == 0
    _put_motor_at(plant, tr, edge + sign * 1.5 * margin)  # pushed past the margin
    plant.set_joint_torque("knee", 1.0)
    axis.update(2 * DT, DT)
    assert axis.state is AxisState.IDLE
    assert axis.errors == AxisError.POSITION_LIMIT_VIOLATION
    assert axis.disarm_reason == AxisError.POSITION_LIMIT_VIOLATION
    assert axis.procedure_result == ProcedureResult.DISARMED
    assert plant.torque("knee") == 0.0 and axis.torque_setpoint_nm == 0.0
    assert axis.stats["position_limit_trips"] == 1
    hb = ask(axis, "Heartbeat")
    assert hb["Axis_Error"] & AxisError.POSITION_LIMIT_VIOLATION and hb["Axis_State"] == AxisState.IDLE
    # Latched: refused until Clear_Errors, and tripped again at once while still out there.
    axis.handle(frame("Set_Axis_State", AxisState.CLOSED_LOOP_CONTROL), 0.01)
    assert axis.state is AxisState.IDLE
    axis.handle(frame("Clear_Errors", 0), 0.01)
    arm(axis, 0.01)
    axis.update(0.011, DT)
    assert axis.state is AxisState.IDLE and axis.stats["position_limit_trips"] == 2
    _put_motor_at(plant, tr, 0.5)  # back inside: arms and stays armed
    axis.handle(frame("Clear_Errors", 0), 0.02)
    arm(axis, 0.02)
    axis.update(0.021, DT)
    assert axis.state is AxisState.CLOSED_LOOP_CONTROL and axis.errors == AxisError.NONE


def test_position_limit_checked_only_in_closed_loop_and_only_with_limits():
    tr = Transmission()
    axis, plant, _ = make(transmission=tr, **LIMITS)
    _put_motor_at(plant, tr, 5.0)
    axis.update(DT, DT)  # idle: nothing to trip
    assert axis.errors == AxisError.NONE
    free, free_plant, _ = make(watchdog_timeout_s=0.0)  # no limits configured
    _put_motor_at(free_plant, tr, 1e6)
    arm(free)
    free.update(DT, DT)
    assert free.state is AxisState.CLOSED_LOOP_CONTROL


def test_position_limit_margin_is_configurable_and_validated():
    tr = Transmission()
    axis, plant, _ = make(transmission=tr, pos_limit_margin_rev=0.5, **LIMITS)
    _put_motor_at(plant, tr, 2.4)
    arm(axis)
    axis.update(DT, DT)
    assert axis.state is AxisState.CLOSED_LOOP_CONTROL
    _put_motor_at(plant, tr, 2.6)
    axis.update(2 * DT, DT)
    assert axis.errors == AxisError.POSITION_LIMIT_VIOLATION
    for bad in (-0.01, math.nan, math.inf):
        with pytest.raises(ValueError):
            DriverConfig(node_id=1, pos_limit_margin_rev=bad)


def test_set_absolute_position_that_moves_the_estimate_past_a_limit_trips():
    axis, plant, _ = make(**LIMITS)
    arm(axis)
    axis.update(DT, DT)
    axis.handle(frame("Set_Absolute_Position", 3.0), DT)  # the estimate jumps past pos_max_rev
    axis.update(2 * DT, DT)
    assert axis.errors == AxisError.POSITION_LIMIT_VIOLATION and axis.state is AxisState.IDLE


@pytest.mark.parametrize("limits", [LIMITS, dict(watchdog_timeout_s=0.0)])
def test_nan_position_estimate_disarms_with_missing_estimate(limits):
    axis, plant, _ = make(**limits)
    arm(axis)
    plant.set_state("knee", math.nan)
    axis.update(DT, DT)
    assert axis.state is AxisState.IDLE and axis.errors == AxisError.MISSING_ESTIMATE
    assert axis.stats["missing_estimate_trips"] == 1 and axis.stats["position_limit_trips"] == 0


# --------------------------------------------------------------------------- torque / current limits
@settings(max_examples=200, deadline=None, derandomize=True)
@given(
    current_limit_a=st.one_of(st.just(0.0), st.floats(0.0, 100.0), st.just(1e9)),
    mode=st.sampled_from([ControlMode.TORQUE_CONTROL, ControlMode.VELOCITY_CONTROL, ControlMode.POSITION_CONTROL]),
    inputs=st.lists(
        st.tuples(st.floats(-1e4, 1e4), st.floats(-50.0, 50.0), st.floats(-100.0, 100.0)), min_size=1, max_size=20
    ),
    q0=st.floats(-3.0, 3.0),
    qd0=st.floats(-20.0, 20.0),
)
def test_applied_torque_never_exceeds_kt_times_the_lower_current_limit(current_limit_a, mode, inputs, q0, qd0):
    axis, plant, motor = make(watchdog_timeout_s=0.0)
    plant.set_state("knee", q0, qd0)
    arm(axis)
    axis.handle(frame("Set_Limits", 20.0, current_limit_a), 0.0)
    axis.handle(frame("Set_Controller_Mode", mode, InputMode.PASSTHROUGH), 0.0)
    # Set_Limits' float32 current limit, as the axis decoded it
    limit_nm = KT * min(axis.current_limit_a, MotorParams().current_limit_a)
    assert axis.torque_limit_nm == pytest.approx(limit_nm)
    t = 0.0
    for pos, vel, torque in inputs:
        axis.handle(frame("Set_Input_Pos", pos, max(-32.0, min(32.0, vel)), max(-32.0, min(32.0, torque))), t)
        axis.handle(frame("Set_Input_Vel", vel, torque), t)
        axis.handle(frame("Set_Input_Torque", torque), t)
        t += DT
        axis.update(t, DT)
        assert abs(axis.torque_setpoint_nm) <= limit_nm * (1 + 1e-12)
        assert abs(motor.torque_estimate_nm) <= limit_nm * (1 + 1e-12)
        assert abs(plant.torque("knee")) <= 6.0 * limit_nm * (1 + 1e-12)
        plant.step(DT)


# --------------------------------------------------------------------------- ODrive 0.6.10's SDO, Address, DFU
from protocol.contract import sdo_bits_value, sdo_value_bits  # noqa: E402
from protocol.endpoints import BY_PATH, PLACEHOLDER, WATCHDOG_TIMEOUT  # noqa: E402


def sdo(axis, opcode, path_or_id, raw=0, now=0.0):
    endpoint_id = BY_PATH[path_or_id].id if isinstance(path_or_id, str) else path_or_id
    return axis.handle(frame("RxSdo", opcode, endpoint_id, 0, raw), now)


def sdo_read(axis, path, now=0.0):
    (reply,) = sdo(axis, 0, path, now=now)
    codec = C.codec("TxSdo")
    assert reply.arbitration_id == arbitration_id(NODE, codec.cmd_id) and len(reply.data) == codec.dlc
    values = codec.decode(reply.data)
    assert values["Endpoint_ID"] == BY_PATH[path].id and values["Reserved0"] == 0
    return values["Value"]


def test_watchdog_timeout_written_through_rxsdo_reads_back_and_is_enforced():
    axis, plant, _ = make(watchdog_timeout_s=0.1)
    assert sdo_bits_value(sdo_read(axis, "axis0.config.watchdog_timeout")) == pytest.approx(0.1)
    assert sdo_read(axis, "axis0.config.enable_watchdog") == 1
    assert sdo(axis, 1, "axis0.config.watchdog_timeout", sdo_value_bits(0.3)) == []  # a write: no answer
    assert sdo_bits_value(sdo_read(axis, "axis0.config.watchdog_timeout")) == pytest.approx(0.3)
    assert axis.stats["sdo_writes"] == 1 and axis.stats["sdo_reads"] == 3
    arm(axis, 0.0)
    run(axis, plant, 0.0, 0.25)  # beyond the old 0.1 s, within the new 0.3 s
    assert axis.state is AxisState.CLOSED_LOOP_CONTROL
    run(axis, plant, 0.25, 0.1)
    assert axis.state is AxisState.IDLE and axis.errors & AxisError.WATCHDOG_TIMER_EXPIRED
    assert axis.stats["watchdog_trips"] == 1


def test_watchdog_disabled_and_reenabled_through_sdo():
    axis, plant, _ = make(watchdog_timeout_s=0.1)
    sdo(axis, 1, "axis0.config.enable_watchdog", 0)
    arm(axis, 0.0)
    run(axis, plant, 0.0, 0.5)
    assert axis.state is AxisState.CLOSED_LOOP_CONTROL
    sdo(axis, 1, "axis0.config.enable_watchdog", 1, now=0.5)
    run(axis, plant, 0.5, 0.2)
    assert axis.stats["watchdog_trips"] == 1


def test_sdo_gains_and_input_mode_read_and_write():
    axis, _, _ = make()
    sdo(axis, 1, "axis0.controller.config.pos_gain", sdo_value_bits(12.5))
    sdo(axis, 1, "axis0.controller.config.vel_gain", sdo_value_bits(0.5))
    sdo(axis, 1, "axis0.controller.config.vel_integrator_gain", sdo_value_bits(0.75))
    sdo(axis, 1, "axis0.controller.config.input_mode", int(InputMode.TRAP_TRAJ))
    assert (axis.pos_gain, axis.vel_gain, axis.vel_integrator_gain) == (12.5, 0.5, 0.75)
    assert axis.input_mode is InputMode.TRAP_TRAJ
    assert sdo_bits_value(sdo_read(axis, "axis0.controller.config.pos_gain")) == 12.5
    assert sdo_read(axis, "axis0.controller.config.input_mode") == InputMode.TRAP_TRAJ
    assert all(e.placeholder and not e.verified for e in PLACEHOLDER)
    assert not WATCHDOG_TIMEOUT.verified and WATCHDOG_TIMEOUT.id == 200


def test_sdo_bad_values_are_malformed_and_change_nothing():
    axis, _, _ = make(watchdog_timeout_s=0.1)
    sdo(axis, 1, "axis0.config.watchdog_timeout", sdo_value_bits(-1.0))
    sdo(axis, 1, "axis0.config.watchdog_timeout", sdo_value_bits(math.nan))
    sdo(axis, 1, "axis0.config.enable_watchdog", 2)
    sdo(axis, 1, "axis0.controller.config.input_mode", 42)
    sdo(axis, 7, "axis0.config.watchdog_timeout", 0)  # neither read nor write
    assert axis.stats["malformed"] == 5 and axis.stats["sdo_writes"] == 0
    assert axis.watchdog_timeout_s == 0.1 and axis.enable_watchdog and axis.input_mode is InputMode.PASSTHROUGH


def test_sdo_unknown_endpoint_is_answered_with_nothing_and_counted():
    axis, _, _ = make()
    assert sdo(axis, 0, 0x1234) == []
    assert sdo(axis, 1, 0x1234, 5) == []
    assert sdo(axis, 0, "config.dc_bus_undervoltage_trip_level") == []  # in the table, not simulated
    assert axis.stats["sdo_unknown_endpoint"] == 3 and axis.stats["malformed"] == 0


def test_sdo_read_only_endpoints_and_requested_state():
    axis, _, motor = make()
    assert sdo_read(axis, "axis0.config.can.node_id") == NODE
    assert sdo_read(axis, "axis0.current_state") == AxisState.IDLE
    assert sdo_bits_value(sdo_read(axis, "axis0.pos_estimate")) == pytest.approx(motor.motor_state()[0], abs=1e-6)
    sdo(axis, 1, "axis0.config.can.node_id", 9)
    assert axis.stats["unsupported"] == 1 and axis.node_id == NODE
    sdo(axis, 1, "axis0.requested_state", int(AxisState.CLOSED_LOOP_CONTROL))
    assert axis.state is AxisState.CLOSED_LOOP_CONTROL
    assert sdo_read(axis, "axis0.current_state") == AxisState.CLOSED_LOOP_CONTROL


def test_sdo_read_in_4_bytes_as_odrives_example_sends_it():
    axis, _, _ = make(watchdog_timeout_s=0.1)
    codec = C.codec("RxSdo")
    msg = can.Message(arbitration_id=arbitration_id(NODE, codec.cmd_id), is_extended_id=False,
                      data=bytes([0]) + WATCHDOG_TIMEOUT.id.to_bytes(2, "little") + b"\0")
    (reply,) = axis.handle(msg, 0.0)
    assert sdo_bits_value(C.codec("TxSdo").decode(reply.data)["Value"]) == pytest.approx(0.1)


def test_sdo_watchdog_setting_survives_a_reboot_only_when_saved():
    axis, _, _ = make(watchdog_timeout_s=0.1)
    sdo(axis, 1, "axis0.config.watchdog_timeout", sdo_value_bits(0.25))
    axis.handle(frame("Reboot", 0), 0.0)
    assert axis.watchdog_timeout_s == 0.1
    sdo(axis, 1, "axis0.config.watchdog_timeout", sdo_value_bits(0.25))
    axis.handle(frame("Reboot", 1), 0.0)  # save configuration, then reboot
    assert axis.watchdog_timeout_s == pytest.approx(0.25)


def test_enter_dfu_mode_is_refused_and_counted():
    axis, _, _ = make()
    arm(axis)
    assert axis.handle(frame("Enter_DFU_Mode"), 0.01) == []
    assert axis.stats["dfu_refused"] == 1 and axis.stats["malformed"] == 0
    assert axis.state is AxisState.CLOSED_LOOP_CONTROL and not axis.errors


def test_address_is_answered_with_node_id_and_a_stable_serial_number():
    axis, _, _ = make()
    values = ask(axis, "Address")
    assert values["Node_ID"] == NODE
    serial = values["Serial_Number"]
    assert 0 < serial < 1 << 48
    assert ask(make()[0], "Address")["Serial_Number"] == serial  # the same board, the same number
    other = make(node=NODE + 1)[0].handle(rtr("Address", node=NODE + 1), 0.0)[0]
    assert C.codec("Address").decode(other.data)["Serial_Number"] != serial
    assert ask(make(serial_number=0x123456789ABC)[0], "Address")["Serial_Number"] == 0x123456789ABC
    with pytest.raises(ValueError):
        DriverConfig(node_id=1, serial_number=1 << 48)


def test_version_is_an_odrive_pro_v4_4_58_with_firmware_0_6_10():
    values = ask(make()[0], "Get_Version")
    hw = (values["Hw_Version_Major"], values["Hw_Version_Minor"], values["Hw_Version_Variant"])
    fw = (values["Fw_Version_Major"], values["Fw_Version_Minor"], values["Fw_Version_Revision"])
    assert hw == (4, 4, 58) and fw == (0, 6, 10)


@pytest.mark.parametrize("length", [4, 8])
def test_set_axis_state_in_4_or_8_bytes(length):
    axis, _, _ = make()
    msg = can.Message(arbitration_id=arbitration_id(NODE, Cmd.SET_AXIS_STATE), is_extended_id=False,
                      data=int(AxisState.CLOSED_LOOP_CONTROL).to_bytes(length, "little"))
    axis.handle(msg, 0.0)
    assert axis.state is AxisState.CLOSED_LOOP_CONTROL and axis.stats["malformed"] == 0
    short = can.Message(arbitration_id=arbitration_id(NODE, Cmd.SET_AXIS_STATE), is_extended_id=False, data=b"\1\0\0")
    axis.handle(short, 0.0)
    assert axis.stats["malformed"] == 1 and axis.state is AxisState.CLOSED_LOOP_CONTROL
