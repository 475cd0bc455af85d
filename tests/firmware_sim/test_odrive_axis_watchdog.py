"""The simulated driver's watchdog and state machine, to the letter: errors accumulate until
Clear_Errors, every count counts each event, the torque target is zero the moment the axis is
IDLE, a disabled watchdog never trips, and a command's time reaches its handler. Found by mutation
testing (docs/mutation.md); the broader behaviour is in test_odrive_axis.py."""

from __future__ import annotations

import can

from firmware_sim.odrive_axis import ProcedureResult
from protocol.odrive import AxisError, AxisState, InputMode
from tests.firmware_sim.test_odrive_axis import NODE, arm, ask, frame, make, rtr, run, sdo


def test_a_latched_error_holds_the_axis_idle_until_clear_errors():
    axis, _, _ = make()
    axis.latch_error(AxisError.ESTOP_REQUESTED)
    assert axis.state is AxisState.IDLE and axis.errors == AxisError.ESTOP_REQUESTED
    assert axis.disarm_reason == AxisError.ESTOP_REQUESTED
    axis.handle(frame("Set_Axis_State", AxisState.CLOSED_LOOP_CONTROL), 0.0)
    assert axis.state is AxisState.IDLE
    assert ask(axis, "Heartbeat")["Procedure_Result"] == ProcedureResult.DISARMED  # refused, and says so
    axis.handle(frame("Set_Axis_State", AxisState.MOTOR_CALIBRATION), 0.05)  # a procedure: refused too
    assert axis.state is AxisState.IDLE
    assert ask(axis, "Heartbeat")["Procedure_Result"] == ProcedureResult.DISARMED
    axis.handle(frame("Clear_Errors", 0), 0.1)
    assert axis.errors == AxisError.NONE and axis.disarm_reason == AxisError.NONE
    axis.handle(frame("Set_Axis_State", AxisState.MOTOR_CALIBRATION), 0.15)
    assert ask(axis, "Heartbeat")["Procedure_Result"] == ProcedureResult.SUCCESS
    arm(axis, 0.2)


def test_errors_accumulate_in_errors_and_disarm_reason():
    axis, plant, _ = make(watchdog_timeout_s=0.1)
    arm(axis, 0.0)
    run(axis, plant, 0.0, 0.2)  # the watchdog trips
    axis.handle(frame("Estop", data=b""), 0.25)
    both = AxisError.WATCHDOG_TIMER_EXPIRED | AxisError.ESTOP_REQUESTED
    assert axis.errors == both and axis.disarm_reason == both
    assert ask(axis, "Get_Error", 0.3) == {"Active_Errors": int(both), "Disarm_Reason": int(both)}


def test_every_trip_and_every_odd_frame_is_counted():
    axis, plant, _ = make(watchdog_timeout_s=0.1)
    for k in range(3):
        t0 = k * 1.0
        axis.handle(frame("Clear_Errors", 0), t0)
        arm(axis, t0)
        run(axis, plant, t0, 0.2)
    assert axis.stats["watchdog_trips"] == 3
    for _ in range(2):
        axis.handle(frame("Heartbeat", 0, 1, 0, 0, node=NODE + 1), 5.0)  # another node's
        axis.handle(rtr("Set_Input_Pos"), 5.0)  # a command as a remote frame
        axis.handle(frame("Get_Encoder_Estimates", 0.0, 0.0), 5.0)  # a getter with data
        axis.handle(frame("Set_Axis_State", 99), 5.0)  # no such state
    assert axis.stats["foreign"] == 2 and axis.stats["malformed"] == 4 and axis.stats["unsupported"] == 2
    assert axis.stats["rx"]["Set_Input_Pos"] == 2 and axis.stats["rx"]["Set_Axis_State"] == 3 + 2


def test_the_torque_target_is_zero_as_soon_as_the_axis_is_idle():
    for request in (AxisState.IDLE, AxisState.MOTOR_CALIBRATION):
        axis, plant, _ = make()
        arm(axis, 0.0)
        axis.handle(frame("Set_Input_Pos", 2.0, 0.0, 0.0), 0.001)
        run(axis, plant, 0.001, 0.01)
        assert axis.torque_setpoint_nm != 0.0  # pulling towards the target
        axis.handle(frame("Set_Axis_State", request), 0.02)
        assert ask(axis, "Get_Torques", 0.02)["Torque_Target"] == 0.0  # before any control step
        assert axis.state is AxisState.IDLE


def test_a_watchdog_disabled_through_sdo_never_trips():
    axis, plant, _ = make(watchdog_timeout_s=0.1)
    sdo(axis, 1, "axis0.config.enable_watchdog", 0)
    arm(axis, 0.0)
    run(axis, plant, 0.0, 3.0)
    assert axis.state is AxisState.CLOSED_LOOP_CONTROL and axis.stats["watchdog_trips"] == 0


def test_a_command_s_time_reaches_its_handler():
    axis, plant, _ = make()
    axis.handle(frame("Set_Controller_Mode", 3, int(InputMode.TRAP_TRAJ)), 0.0)
    arm(axis, 0.0)
    run(axis, plant, 0.0, 0.01)
    axis.handle(frame("Set_Input_Pos", 0.5, 0.0, 0.0), 0.01)  # a trapezoidal move from now
    assert axis.stats["internal_errors"] == 0 and not axis.trajectory_done
    run(axis, plant, 0.01, 0.005)
    assert axis.stats["internal_errors"] == 0 and axis.torque_setpoint_nm != 0.0


def test_an_extended_or_error_frame_is_unknown():
    axis, _, _ = make()
    ext = frame("Set_Axis_State", AxisState.CLOSED_LOOP_CONTROL)
    ext.is_extended_id = True
    err = can.Message(arbitration_id=ext.arbitration_id, is_error_frame=True, dlc=8, data=b"\0" * 8)
    assert axis.handle(ext, 0.0) == [] and axis.handle(err, 0.0) == []
    assert axis.stats["unknown"] == 2 and axis.state is AxisState.IDLE
