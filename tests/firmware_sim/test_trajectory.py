"""The trapezoidal planner (ODrive's TRAP_TRAJ) alone, and driven through the simulated driver's
Set_Traj_* frames and Set_Input_Pos, with the heartbeat's Trajectory_Done_Flag."""

from __future__ import annotations

import math

import can
import pytest

from firmware_sim.motor import MotorJoint, MotorParams, Transmission
from firmware_sim.odrive_axis import DriverConfig, SimOdriveAxis
from firmware_sim.trajectory import TrapezoidalTrajectory
from protocol.contract import BusContract, arbitration_id
from protocol.odrive import AxisState, ControlMode, InputMode
from tests.fakes import FakeJointPlant

C = BusContract.load()
NODE = 2
DT = 0.001


def frame(name, *values):
    codec = C.codec(name)
    return can.Message(arbitration_id=arbitration_id(NODE, codec.cmd_id), data=codec.pack(*values),
                       is_extended_id=False)


def done_flag(axis):
    codec = C.codec("Heartbeat")
    (reply,) = axis.handle(can.Message(arbitration_id=arbitration_id(NODE, codec.cmd_id), is_remote_frame=True,
                                       dlc=codec.dlc, is_extended_id=False), 0.0)
    return codec.decode(reply.data)["Trajectory_Done_Flag"]


# --------------------------------------------------------------------------- the planner
def test_long_move_accelerates_cruises_and_decelerates():
    t = TrapezoidalTrajectory(10.0, 0.0, 0.0, 2.0, 0.5, 1.0)
    assert (t.t_accel_s, t.t_decel_s) == pytest.approx((4.0, 2.0))
    assert t.t_cruise_s == pytest.approx((10.0 - 4.0 - 2.0) / 2.0)
    assert t.cruise_vel == pytest.approx(2.0)
    assert t.eval(1.0) == pytest.approx((0.25, 0.5, 0.5))  # accelerating
    assert t.eval(5.0)[1:] == pytest.approx((2.0, 0.0))  # cruising
    assert t.eval(t.t_total_s - 1.0) == pytest.approx((10.0 - 0.5, 1.0, -1.0))  # decelerating
    assert t.eval(t.t_total_s) == (10.0, 0.0, 0.0) and t.done(t.t_total_s)
    assert t.eval(-1.0) == (0.0, 0.0, 0.0)


def test_short_move_is_a_triangle_below_the_velocity_limit():
    t = TrapezoidalTrajectory(-1.0, 0.0, 0.0, 2.0, 0.5, 0.5)
    assert t.t_cruise_s == 0.0
    assert t.cruise_vel == pytest.approx(-math.sqrt(0.5))
    assert t.eval(t.t_accel_s)[0] == pytest.approx(-0.5)


def test_profile_is_continuous_and_within_its_limits():
    for xf, xi, vi in ((3.0, 0.5, 0.0), (-2.0, 1.0, 0.8), (1.0, 0.0, 3.0), (0.2, 0.0, -1.0)):
        t = TrapezoidalTrajectory(xf, xi, vi, 1.5, 2.0, 3.0)
        prev = t.eval(0.0)
        assert prev[0] == pytest.approx(xi) and prev[1] == pytest.approx(vi)
        steps = int(t.t_total_s / 1e-3) + 2
        for i in range(1, steps):
            y = t.eval(i * 1e-3)
            assert abs(y[0] - prev[0]) < max(abs(vi), 1.5) * 1e-3 + 1e-6
            if abs(vi) <= 1.5:
                assert abs(y[1]) <= 1.5 + 1e-9
            prev = y
        assert t.eval(t.t_total_s) == (xf, 0.0, 0.0)


@pytest.mark.parametrize("bad", [{"vel_limit": 0.0}, {"accel_limit": -1.0}, {"decel_limit": math.nan},
                                 {"xf": math.inf}])
def test_planner_rejects_bad_values(bad):
    args = {"xf": 1.0, "xi": 0.0, "vi": 0.0, "vel_limit": 1.0, "accel_limit": 1.0, "decel_limit": 1.0} | bad
    with pytest.raises(ValueError):
        TrapezoidalTrajectory(**args)


# --------------------------------------------------------------------------- through the driver
def _driver():
    plant = FakeJointPlant({"knee": 0.0})
    motor = MotorJoint(plant, "knee", Transmission(gear_ratio=6.0), MotorParams())
    axis = SimOdriveAxis(DriverConfig(node_id=NODE, watchdog_timeout_s=0.0), motor)
    return axis, plant, motor


def test_trapezoidal_move_through_set_traj_reaches_its_target_with_the_done_flag():
    axis, plant, motor = _driver()
    assert done_flag(axis) == 1
    vel_limit, accel, decel = 1.5, 4.0, 6.0
    for f in (frame("Set_Traj_Vel_Limit", vel_limit), frame("Set_Traj_Accel_Limits", accel, decel),
              frame("Set_Traj_Inertia", 0.01),
              frame("Set_Controller_Mode", ControlMode.POSITION_CONTROL, InputMode.TRAP_TRAJ),
              frame("Set_Axis_State", AxisState.CLOSED_LOOP_CONTROL)):
        assert axis.handle(f, 0.0) == []
    assert axis.stats["malformed"] == 0
    assert (axis.traj_vel_limit, axis.traj_accel_limit, axis.traj_decel_limit) == (vel_limit, accel, decel)
    assert axis.traj_inertia == pytest.approx(0.01)
    assert axis.state is AxisState.CLOSED_LOOP_CONTROL and axis.input_mode is InputMode.TRAP_TRAJ
    start = motor.motor_state()[0]
    target = start + 3.0
    axis.handle(frame("Set_Input_Pos", target, 0.0, 0.0), 0.0)
    planned = axis._traj
    assert planned is not None and planned.t_cruise_s > 0.0  # a real trapezoid: it cruises
    expected_s = planned.t_total_s  # 3/1.5 + 1.5/8 + 1.5/12 = 2.3125 s
    assert expected_s == pytest.approx(3.0 / vel_limit + vel_limit / (2 * accel) + vel_limit / (2 * decel))
    flags, peak, t = [], 0.0, 0.0
    for i in range(1, int(4.0 / DT) + 1):
        t = i * DT
        axis.update(t, DT)
        plant.step(DT)
        peak = max(peak, abs(motor.motor_state()[1]))
        if i % 50 == 0:
            flags.append((t, done_flag(axis)))
    moving = [f for s, f in flags if s < expected_s - 0.01]
    after = [f for s, f in flags if s > expected_s + 0.01]
    assert moving and set(moving) == {0}
    assert after and set(after) == {1}
    pos, vel = motor.motor_state()
    assert pos == pytest.approx(target, abs=2e-3) and abs(vel) < 0.05
    assert peak <= vel_limit * 1.05  # the shaft follows the profile: its peak velocity within the limit
    assert peak >= vel_limit * 0.9  # and it did cruise near it
    assert axis.input_pos_rev == target


def test_a_new_target_during_a_move_replans_from_where_the_move_is():
    axis, plant, motor = _driver()
    for f in (frame("Set_Controller_Mode", ControlMode.POSITION_CONTROL, InputMode.TRAP_TRAJ),
              frame("Set_Axis_State", AxisState.CLOSED_LOOP_CONTROL)):
        axis.handle(f, 0.0)
    axis.handle(frame("Set_Input_Pos", 5.0, 0.0, 0.0), 0.0)
    for i in range(1, 1001):
        axis.update(i * DT, DT)
        plant.step(DT)
    moving = axis._traj.eval(1.0)
    axis.handle(frame("Set_Input_Pos", -1.0, 0.0, 0.0), 1.0)
    replanned = axis._traj
    assert (replanned.xi, replanned.vi) == pytest.approx(moving[:2])
    assert replanned.xf == -1.0 and done_flag(axis) == 0


def test_idle_or_another_input_mode_ends_the_move_and_sets_the_done_flag():
    axis, _, _ = _driver()
    axis.handle(frame("Set_Controller_Mode", ControlMode.POSITION_CONTROL, InputMode.TRAP_TRAJ), 0.0)
    axis.handle(frame("Set_Axis_State", AxisState.CLOSED_LOOP_CONTROL), 0.0)
    axis.handle(frame("Set_Input_Pos", 2.0, 0.0, 0.0), 0.0)
    assert done_flag(axis) == 0
    axis.handle(frame("Set_Axis_State", AxisState.IDLE), 0.1)
    assert done_flag(axis) == 1
    axis.handle(frame("Set_Axis_State", AxisState.CLOSED_LOOP_CONTROL), 0.2)
    axis.handle(frame("Set_Input_Pos", 2.0, 0.0, 0.0), 0.2)
    assert done_flag(axis) == 0
    axis.handle(frame("Set_Controller_Mode", ControlMode.POSITION_CONTROL, InputMode.PASSTHROUGH), 0.3)
    assert done_flag(axis) == 1


def test_passthrough_and_idle_targets_plan_nothing():
    axis, _, _ = _driver()
    axis.handle(frame("Set_Axis_State", AxisState.CLOSED_LOOP_CONTROL), 0.0)
    axis.handle(frame("Set_Input_Pos", 2.0, 0.0, 0.0), 0.0)  # PASSTHROUGH
    assert axis._traj is None and done_flag(axis) == 1
    axis.handle(frame("Set_Axis_State", AxisState.IDLE), 0.0)
    axis.handle(frame("Set_Controller_Mode", ControlMode.POSITION_CONTROL, InputMode.TRAP_TRAJ), 0.0)
    axis.handle(frame("Set_Input_Pos", 2.0, 0.0, 0.0), 0.0)  # IDLE: stored, no move
    assert axis._traj is None and done_flag(axis) == 1


@pytest.mark.parametrize("f", [lambda: frame("Set_Traj_Vel_Limit", 0.0), lambda: frame("Set_Traj_Vel_Limit", math.nan),
                               lambda: frame("Set_Traj_Accel_Limits", 1.0, -1.0),
                               lambda: frame("Set_Traj_Inertia", -0.1)])
def test_bad_trajectory_limits_are_malformed_and_change_nothing(f):
    axis, _, _ = _driver()
    before = (axis.traj_vel_limit, axis.traj_accel_limit, axis.traj_decel_limit, axis.traj_inertia)
    axis.handle(f(), 0.0)
    assert axis.stats["malformed"] == 1
    assert (axis.traj_vel_limit, axis.traj_accel_limit, axis.traj_decel_limit, axis.traj_inertia) == before
