"""RigPlant's queries: the obstacle contact answered from the step's contact points agrees with
PyBullet's own per-obstacle query, step by step, touching and not."""

from __future__ import annotations

import pybullet
import pytest

from firmware_sim.plant import Obstacle, RigPlant


def _asked(plant: RigPlant) -> bool:
    """The obstacle contact as PyBullet answers it, one query per obstacle (the plant's fallback)."""
    return any(pybullet.getContactPoints(bodyA=plant.robot, bodyB=body, physicsClientId=plant._cid)
               for body, _ in plant._obstacles)


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
