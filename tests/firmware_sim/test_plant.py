"""RigPlant's queries: the obstacle contact answered from the step's contact points agrees with
PyBullet's own per-obstacle query, step by step, touching and not; a point PyBullet reports
within its contact margin, apart and without force, is not a touch."""

from __future__ import annotations

import math

import pybullet
import pytest

from firmware_sim.plant import Obstacle, RigPlant


def _asked(plant: RigPlant) -> bool:
    """The obstacle contact as PyBullet answers it, one query per obstacle (the plant's fallback):
    a point touching or overlapping (distance <= 0) or pressing (force > 0)."""
    return any(pt[8] <= 0.0 or pt[9] > 0.0
               for body, _ in plant._obstacles
               for pt in pybullet.getContactPoints(bodyA=plant.robot, bodyB=body, physicsClientId=plant._cid))


@pytest.fixture
def plant():
    p = RigPlant()
    yield p
    p.close()


def test_obstacle_contact_from_the_steps_points_agrees_with_the_query(plant: RigPlant) -> None:
    # the rail carries the leg (limp: no torque) into a tall block; it touches, then is dragged along it
    plant.add_obstacle(Obstacle(plant.carriage_x_m + 0.35, 0.15, 0.10))
    answers = []
    for _ in range(1500):
        plant.step()
        plant.contacts()  # what the sensor board and the ground truth read each step
        assert plant._points_fresh
        got = plant.obstacle_contact()
        assert got == _asked(plant)
        answers.append(got)
    assert any(answers) and not all(answers)  # both answers were exercised


def test_the_leg_contact_points_name_the_link_and_the_body_and_agree_with_the_truth(plant: RigPlant) -> None:
    # the limp leg dragged into a tall block: the points say "block" exactly while the truth says touching
    plant.add_obstacle(Obstacle(plant.carriage_x_m + 0.35, 0.15, 0.10))
    seen = set()
    for _ in range(1500):
        plant.step()
        points = plant.leg_contact_points()
        assert len(points) == len(plant._contact_points)
        on_block = [p for p in points if p[1] == "block"]
        assert plant.obstacle_contact() == any(d <= 0.0 or f > 0.0 for _, _, d, f in on_block)
        seen.update((link, body) for link, body, _, _ in points)
    assert {("foot", "ground"), ("foot", "block"), ("shank", "block")} <= seen, seen


def test_obstacle_contact_after_the_obstacles_change_asks_pybullet(plant: RigPlant) -> None:
    plant.add_obstacle(Obstacle(plant.carriage_x_m + 0.35, 0.15, 0.10))
    for _ in range(1500):
        plant.step()
        plant.contacts()
        if plant.obstacle_contact():
            break
    else:
        pytest.fail("the leg never touched the obstacle: the scenario no longer tests anything")
    plant.clear_obstacles()
    assert plant.obstacle_contact() is False
    plant.add_obstacle(Obstacle(plant.carriage_x_m + 2.0, 0.10, 0.10))  # may reuse the removed body's id
    assert not plant._points_fresh
    assert plant.obstacle_contact() is _asked(plant) is False
    plant.step()
    assert plant.obstacle_contact() == _asked(plant)  # contacts() not read this step: the query answers


@pytest.mark.parametrize("distance_m, force_n, touched", [(0.0005, 0.0, False), (0.0, 0.0, True),
                                                           (-0.0002, 0.0, True), (0.0005, 0.3, True)])
def test_a_point_apart_without_force_is_not_a_touch(plant: RigPlant, distance_m: float, force_n: float,
                                                    touched: bool) -> None:
    """PyBullet keeps a contact manifold's points up to its margin apart, without force: tuning
    seed 71 failed a trial on such points (the foot passing 0.43-0.65 mm above the block's edge
    for 5 ms, no force, no switch closed). The rule: a point counts if the bodies meet
    (distance <= 0) or press (force > 0). PyBullet will not make such a point on demand (a
    manifold must form and separate in motion), so this feeds the step's point list."""
    body = plant.add_obstacle(Obstacle(plant.carriage_x_m + 2.0, 0.10, 0.10))
    plant.step()
    plant.contacts()
    assert plant._points_fresh and plant.obstacle_contact() is False
    # (flag, bodyA, bodyB, linkA, linkB, posA, posB, normalB, distance, normal force, ...)
    point = (0, plant.robot, body, plant.foot_link, -1, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 1.0),
             distance_m, force_n, 0.0, (1.0, 0.0, 0.0), 0.0, (0.0, 1.0, 0.0))
    plant._contact_points = (point,)
    assert plant.obstacle_contact() is touched


def test_the_positional_pybullet_calls_are_the_keyword_calls(plant: RigPlant) -> None:
    """The plant passes PyBullet's arguments positionally, the defaults written out (kwlist orders of
    pybullet.c): each query answers as its keyword form does, touching an obstacle and not."""
    plant.add_obstacle(Obstacle(plant.carriage_x_m + 0.35, 0.15, 0.10))
    robot, cid, body = plant.robot, plant._cid, plant._obstacles[0][0]
    frm, to = [[0.2, 0.0, h] for h in (0.05, 0.09)], [[3.2, 0.0, h] for h in (0.05, 0.09)]
    touched = False
    for k in range(1500):
        plant.step()
        if k % 50:
            continue
        points = pybullet.getContactPoints(robot, -1, -2, -2, cid)
        assert points == pybullet.getContactPoints(bodyA=robot, physicsClientId=cid)
        assert (pybullet.getContactPoints(robot, body, -2, -2, cid)
                == pybullet.getContactPoints(bodyA=robot, bodyB=body, physicsClientId=cid))
        touched = touched or any(pt[2] == body for pt in points)
        assert (pybullet.getLinkState(robot, plant.foot_link, 0, 0, cid)
                == pybullet.getLinkState(robot, plant.foot_link, physicsClientId=cid))
        x = plant.carriage_x_m
        assert (pybullet.rayTest([x, 0.0, 0.03], [x + 3.2, 0.0, 0.0], -1, -1, cid)
                == pybullet.rayTest([x, 0.0, 0.03], [x + 3.2, 0.0, 0.0], physicsClientId=cid))
        assert (pybullet.rayTestBatch(frm, to, 1, -1, -1, -1, -1, -1.0, cid)
                == pybullet.rayTestBatch(frm, to, physicsClientId=cid))
        assert (pybullet.getJointStates(robot, plant._read_joints, cid)
                == pybullet.getJointStates(robot, plant._read_joints, physicsClientId=cid))
    assert touched  # the contact queries were asked with points to return


def test_a_step_is_the_keyword_calls_step(plant: RigPlant) -> None:
    """``step`` (targets and gains given so every argument is positional) moves the world as the
    keyword calls with the forces alone do, bit for bit."""
    other = RigPlant()
    try:
        for k in range(600):
            torques = [3.0 * math.sin(0.01 * k), -2.0 * math.cos(0.013 * k)]
            plant.set_joint_torque("hip", torques[0])
            plant.set_joint_torque("knee", torques[1])
            plant.step()
            pybullet.setJointMotorControlArray(other.robot, other._leg, pybullet.TORQUE_CONTROL,
                                               forces=plant._torque, physicsClientId=other._cid)
            pybullet.stepSimulation(physicsClientId=other._cid)
            assert plant._states == tuple(pybullet.getJointStates(other.robot, other._read_joints,
                                                                  physicsClientId=other._cid))
        assert plant._states[0][0] != 0.5  # the leg moved
    finally:
        other.close()


def test_a_plant_steps_its_own_world_only(plant: RigPlant) -> None:
    """``stepSimulation(cid)``: the id given positionally is the plant's world, not another's."""
    other = RigPlant()
    try:
        before = other._states
        for _ in range(10):
            plant.step()
        assert plant.t_s > 0.0 and plant._states != before
        other._read_states()
        assert other._states == before
    finally:
        other.close()


class _NotingPlant(RigPlant):
    """A Python subclass (compiled, ``RigPlant`` allows them), as the physics floor's recording plant."""

    def __init__(self) -> None:
        self.noted: list[tuple] = []
        super().__init__()

    def reset(self, carriage_x_m: float = 0.0, hip_rad: float = 0.5, knee_rad: float = -1.0) -> None:
        self.noted.append(("reset", carriage_x_m, hip_rad, knee_rad))
        super().reset(carriage_x_m, hip_rad, knee_rad)

    def set_rail_speed(self, speed_m_s: float) -> None:
        self.noted.append(("rail_speed", speed_m_s))
        super().set_rail_speed(speed_m_s)


def test_a_python_subclass_is_built_and_called_as_the_plant_is(plant: RigPlant) -> None:
    """The plant's own calls reach a subclass's overrides, with the arguments the plant gives
    (compiled: through mypyc's table of calls through Python, which once lost reset's defaults)."""
    sub = _NotingPlant()
    try:
        assert sub.noted == [("reset", 0.0, 0.5, -1.0), ("rail_speed", 0.5)]
        assert sub._states == plant._states
        for p in (plant, sub):
            for _ in range(20):
                p.step()
        sub.noted.clear()
        sub.rewind_rail(0.001)
        plant.rewind_rail(0.001)
        assert sub.noted == [("rail_speed", 0.5)]
        assert sub._states == plant._states
    finally:
        sub.close()
