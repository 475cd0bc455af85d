"""The tallest obstacle the leg can clear at all (controller.motion.reach): the rules on their own,
and the limiting pose checked in PyBullet's model of the rig (firmware_sim.plant.RigPlant)."""

from __future__ import annotations

import dataclasses
import math

import pybullet
import pytest

from controller.config import default_axes
from controller.motion.cpg import CpgConfig
from controller.motion.gait import GaitConfig
from controller.motion.kinematics import LegGeometry, forward, inverse
from controller.motion.reach import (
    LegLoads,
    check_height,
    effort_nm,
    link_extent,
    max_clearable_height_m,
    shortest_swing_s,
    static_torques_nm,
)
from firmware_sim.motor import MotorParams
from firmware_sim.plant import Obstacle, RigPlant

AXES = default_axes()  # the controller's axes: the module takes them (its package imports no bus module)

MARGIN_M = 0.005  # the blocks 5 mm below and above the limit


@pytest.fixture(scope="module")
def limit():
    return max_clearable_height_m(axes=AXES)


@pytest.fixture()
def plant():
    p = RigPlant()
    yield p
    p.close()


def test_the_default_rig_clears_well_above_the_paper_heights_with_the_leg_tucked(limit):
    axes = {a.name: a for a in default_axes()}
    assert limit.height_m == pytest.approx(0.223, abs=1e-3)
    assert limit.height_m > 0.14 + 0.07
    assert limit.knee_rad == axes["knee"].min_rad  # fully flexed
    assert limit.foot_x_m < 0.0  # tucked behind the hip
    assert "knee's -2.15 rad limit" in limit.reason
    # torque and time are not what binds
    assert abs(limit.hip_torque_nm) < 0.5 * limit.hip_effort_nm
    assert abs(limit.knee_torque_nm) < 0.5 * limit.knee_effort_nm
    assert limit.swing_needed_s < limit.swing_max_s == CpgConfig().burst_max_s
    # held, swing aside, the leg goes higher (folded back): rule 5 is what cuts it
    assert limit.held_height_m > limit.height_m + 0.02 and limit.held_x_m < -0.3


def test_shortest_swing_by_hand():
    """Rule 5's three parts, with the default swing start (-0.10 m) and landing (0.2168 m)."""
    start, land, carry, v = -0.10, 0.2168, 0.14, 0.5
    # a single x: the carriage alone carries the foot over; moving back 0.02 m first costs 0.04 s
    t, a, b = shortest_swing_s(-0.12, -0.12, start, land, carry, v)
    assert (t, a, b) == pytest.approx((0.04 + 0.28, -0.12, -0.12))
    # a wide interval around the start: the foot's own swing covers the block, no time needed
    assert shortest_swing_s(-0.3, 0.1, start, land, carry, v)[0] == pytest.approx(0.0)
    # held far ahead (the leg stretched forward): 0.28 s over, then 0.5 s back to a touchdown
    t, a, b = shortest_swing_s(0.466, 0.466, start, land, carry, v)
    assert t == pytest.approx(0.28 + (0.466 - land) / v)
    # held far behind (the leg folded back): 0.64 s just to get there behind the near edge
    assert shortest_swing_s(-0.42, -0.42, start, land, carry, v)[0] == pytest.approx(0.64 + 0.28)


def test_the_limit_follows_the_configurations(limit):
    """Defaults are read from the configurations: a taller hip adds its height; a longer longest
    burst lets the folded-back pose through; a deeper block or a slower rail lowers the limit; a
    stricter torque margin never raises it."""
    taller = max_clearable_height_m(axes=AXES, geometry=dataclasses.replace(LegGeometry(), hip_height_m=0.52))
    taller = taller.height_m
    assert taller == pytest.approx(limit.height_m + 0.05, abs=1e-9)
    longer = max_clearable_height_m(axes=AXES, cpg=dataclasses.replace(CpgConfig(), burst_max_s=1.0))
    assert longer.height_m == pytest.approx(limit.held_height_m)
    assert max_clearable_height_m(0.30, axes=AXES).height_m < limit.height_m < max_clearable_height_m(0.05, axes=AXES).height_m
    assert max_clearable_height_m(axes=AXES, dynamics_margin=0.9).height_m <= limit.height_m
    slower = max_clearable_height_m(axes=AXES, gait=dataclasses.replace(GaitConfig(), ground_speed_m_s=0.2))
    assert slower.height_m < limit.height_m  # the carriage carries the foot over too slowly
    with pytest.raises(ValueError, match="no swing"):
        max_clearable_height_m(2.0, axes=AXES)


def test_check_height_refuses_beyond_the_limit_with_the_reason(limit):
    check_height(0.14, axes=AXES)
    check_height(limit.height_m, axes=AXES)
    with pytest.raises(ValueError) as err:
        check_height(0.30, axes=AXES)
    text = str(err.value)
    assert text.startswith("0.300 m is above the leg's 0.223 m limit for a 0.1 m deep obstacle: ")
    assert "knee's -2.15 rad limit" in text and "one swing" in text


def test_the_limiting_pose_is_one_the_controller_commands(limit):
    """The controller's inverse kinematics, asked for the limiting foot position, gives the pose."""
    hip, knee = inverse(LegGeometry(), limit.foot_x_m, limit.foot_z_m)
    assert hip == pytest.approx(limit.hip_rad, abs=1e-6) and knee == pytest.approx(limit.knee_rad, abs=1e-6)


def test_no_link_is_below_the_foot_in_the_limiting_pose(limit):
    low_z, _ = link_extent(LegGeometry(), LegLoads(), limit.hip_rad, limit.knee_rad)
    assert low_z >= limit.foot_z_m - LegGeometry().foot_radius_m


# -- against the rig's model in PyBullet ------------------------------------------------------

def _leg_touches(plant: RigPlant, height_m: float, near_edge_x_m: float, depth_m: float = 0.10) -> float:
    """Place one block, run collision detection, return the leg's signed distance to it [m]
    (negative: penetrating, i.e. touched); the block is removed again."""
    plant.add_obstacle(Obstacle(near_edge_x_m=near_edge_x_m, height_m=height_m, depth_m=depth_m))
    try:
        pybullet.performCollisionDetection(physicsClientId=plant._cid)
        body = plant._obstacles[-1][0]
        points = pybullet.getClosestPoints(plant.robot, body, 0.05, physicsClientId=plant._cid)
        return min((pt[8] for pt in points), default=0.05)
    finally:
        plant.clear_obstacles()


def test_pybullet_puts_the_foot_at_the_computed_height(plant, limit):
    plant.reset(1.0, limit.hip_rad, limit.knee_rad)
    x, z = plant.foot_position()
    assert z == pytest.approx(limit.height_m, abs=1e-3)
    assert x == pytest.approx(1.0 + limit.foot_x_m, abs=1e-3)
    # the plant's joint limits (hard stops) hold the controller's commanded ones
    for axis in default_axes():
        lo, hi = plant.joint_limits_rad[axis.name]
        assert lo <= axis.min_rad and axis.max_rad <= hi


def test_a_block_5mm_lower_is_not_touched_anywhere_under_the_leg_and_5mm_taller_is(plant, limit):
    """The carriage carries the held pose over the block: the block's near edge from ahead of
    the leg's front-most link to behind the foot, never touched 5 mm lower; 5 mm taller, touched
    under the foot."""
    carriage_x_m, depth_m = 1.0, 0.10
    plant.reset(carriage_x_m, limit.hip_rad, limit.knee_rad)
    foot_x, _ = plant.foot_position()
    front_x = carriage_x_m + link_extent(LegGeometry(), LegLoads(), limit.hip_rad, limit.knee_rad)[1]
    first, last = front_x + 0.01, foot_x - depth_m - 0.03
    for i in range(41):
        near = first + i * (last - first) / 40
        gap = _leg_touches(plant, limit.height_m - MARGIN_M, near, depth_m)
        assert gap > 0.0, f"block at {near:.3f} m touched ({gap:+.4f} m)"
    under_foot = foot_x - depth_m / 2
    assert _leg_touches(plant, limit.height_m - MARGIN_M, under_foot) == pytest.approx(MARGIN_M, abs=1e-3)
    assert _leg_touches(plant, limit.height_m + MARGIN_M, under_foot) == pytest.approx(-MARGIN_M, abs=1e-3)
    plant.add_obstacle(Obstacle(near_edge_x_m=under_foot, height_m=limit.height_m + MARGIN_M, depth_m=depth_m))
    pybullet.performCollisionDetection(physicsClientId=plant._cid)
    assert plant.obstacle_contact()


def test_the_loads_match_the_rig_model_and_the_static_torques_pybullets(plant, limit):
    """LegLoads is the controller's copy of the URDF's masses and the motor's Kt: compare, then
    compare the static torques with PyBullet's inverse dynamics at rest in a few poses."""
    loads, geometry = LegLoads(), LegGeometry()
    p, robot, cid = pybullet, plant.robot, plant._cid
    assert p.getDynamicsInfo(robot, plant.thigh_link, physicsClientId=cid)[0] == pytest.approx(loads.thigh_mass_kg)
    assert p.getDynamicsInfo(robot, plant.shank_link, physicsClientId=cid)[0] == pytest.approx(loads.shank_mass_kg)
    assert p.getDynamicsInfo(robot, plant.foot_link, physicsClientId=cid)[0] == pytest.approx(loads.foot_mass_kg)
    assert loads.motor_torque_constant_nm_per_a == MotorParams().torque_constant_nm_per_a
    for axis in default_axes():
        assert effort_nm(axis, loads) == pytest.approx(plant.effort_limits_nm[axis.name])
    for hip, knee in ((limit.hip_rad, limit.knee_rad), (0.3, -1.2), (-0.5, -0.4), (1.0, -2.0)):
        plant.reset(0.0, hip, knee)
        tau = p.calculateInverseDynamics(robot, [0.0, hip, knee], [0.0] * 3, [0.0] * 3, physicsClientId=cid)
        assert static_torques_nm(geometry, loads, hip, knee) == pytest.approx(tuple(tau[1:]), abs=1e-3)
        fx, fz = forward(geometry, hip, knee)
        lowest_z = geometry.hip_height_m + fz - geometry.foot_radius_m
        assert plant.foot_position() == pytest.approx((fx, lowest_z), abs=1e-6)



def test_a_plain_swing_in_the_plant_clears_a_block_below_the_limit(plant, limit):
    """Not a proof of the limit (rule 5 moves joints instantly): a witness that a tucked swing of
    the CPG's longest burst clears 0.18 m in the plant, torques within the effort limits. A
    gravity-compensated joint PD (600 N m/rad, 12 N m s/rad) moves the leg from where stance leaves
    it to the limiting pose in 0.06 s, holds it until the foot is past the block, then lands the
    foot 0.05 m ahead of the hip by the swing's end."""
    geometry, loads, cpg, gait = LegGeometry(), LegLoads(), CpgConfig(), GaitConfig()
    ground_z = -(geometry.hip_height_m - geometry.foot_radius_m)
    start = inverse(geometry, gait.foot_ahead_m - gait.ground_speed_m_s * cpg.stance_s, ground_z - gait.stance_press_m)
    tucked, landed = (limit.hip_rad, limit.knee_rad), inverse(geometry, 0.05, ground_z + 0.005)
    near, depth_m, lift_s, dt = 0.06, 0.10, 0.06, plant.dt_s
    plant.reset(0.0, *start)
    plant.add_obstacle(Obstacle(near_edge_x_m=near, height_m=0.18, depth_m=depth_m))

    def blend(a, b, s):
        w = 0.5 * (1.0 - math.cos(math.pi * min(1.0, max(0.0, s))))
        return [x + (y - x) * w for x, y in zip(a, b)]

    passed_s = None
    for i in range(round(cpg.burst_max_s / dt)):
        t = i * dt
        foot_x, _ = plant.foot_position()
        if passed_s is None and t >= lift_s and foot_x > near + depth_m + geometry.foot_radius_m + 0.002:
            passed_s = t
        if t < lift_s:
            ref = blend(start, tucked, t / lift_s)
        elif passed_s is None:
            ref = list(tucked)
        else:
            ref = blend(tucked, landed, (t - passed_s) / (cpg.burst_max_s - passed_s))
        q = [plant.joint_state(n) for n in ("hip", "knee")]
        hold = static_torques_nm(geometry, loads, q[0][0], q[1][0])
        for j, name in enumerate(("hip", "knee")):
            plant.set_joint_torque(name, 600.0 * (ref[j] - q[j][0]) - 12.0 * q[j][1] + hold[j])
        plant.step()
        plant.contacts()
        assert not plant.obstacle_contact(), f"touched the block at {t:.3f} s"
    foot_x, foot_z = plant.foot_position()
    assert passed_s is not None and foot_x > near + depth_m and foot_z < 0.03
