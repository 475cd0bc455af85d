"""The PyBullet plant: the gait rig on its rail, the ground and the obstacles.

This is the physics only. Motor drivers (``odrive_axis``) reach the joints through
:meth:`RigPlant.joint_state` and :meth:`RigPlant.set_joint_torque`; the sensor board through
:meth:`RigPlant.range_m`, :meth:`RigPlant.range_profile_m` and :meth:`RigPlant.contacts`. Scenario control (rail speed, obstacle
placement, resets) is a side channel of the simulation, never on the bus.

Frames: x forward along the rail, z up; the ground's top face is z = 0.

Compiled (:mod:`protocol.compiled`): :class:`RigPlant` is a native class that allows Python
subclasses (the physics floor's recording plant, :mod:`hil.bench.physics_floor`); its
configurations stay Python classes.

The per-step PyBullet calls pass every argument positionally, the defaults written out: PyBullet
parses its arguments with ``PyArg_ParseTupleAndKeywords``, which turns each C keyword name it
looks for into a Python string on every call. The orders and defaults are each function's
``kwlist`` in ``examples/pybullet/pybullet.c`` of bullet3 3.2.7 (the installed pybullet), written
beside each call.
"""

from __future__ import annotations

import contextlib
import math
import os
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Final

import pybullet
from pybullet_utils import bullet_client

import urdf
from protocol.compiled import interpreted, mypyc_attr

LEG_JOINTS = ("hip", "knee")
PROFILE_MAX_BEAMS = 3  # beam slots in the sensor board's SB_Profile frame
SENSOR_MAX_RANGE_M = 3.0  # the range sensor's and the profile beams' reach
_SLOT: Final = {name: i for i, name in enumerate(LEG_JOINTS)}
_UNUSED_IN_TORQUE_CONTROL: Final = (0.0,) * len(LEG_JOINTS)
"""``setJointMotorControlArray``'s targetPositions, targetVelocities, positionGains and
velocityGains in TORQUE_CONTROL, given so the forces and the client id can be positional:
pybullet.c reads them (one number a joint) and sends only the forces (its ``CONTROL_MODE_TORQUE``
case)."""


def touching(point: tuple) -> bool:
    """Whether a PyBullet contact point is a touch: its bodies meet (contact distance, field 8, at
    most 0) or press (normal force, field 9, above 0). PyBullet also keeps points up to its contact
    margin apart with no force (:meth:`RigPlant.obstacle_contact`): near misses."""
    return point[8] <= 0.0 or point[9] > 0.0


@interpreted  # a configuration: plain Python even when compiled (protocol.compiled)
@dataclass(frozen=True)
class RigConfig:
    """Physical set-up of the rig.

    Attributes:
        physics_hz: physics steps per simulated second [Hz]; default 1000.
        rail_speed_m_s: carriage speed along the rail [m/s]; default 0.5.
        sensor_offset_x_m: range sensor origin ahead of the hip axis [m]; default 0.20 (the boom).
        sensor_height_m: range sensor origin above the ground [m]; default 0.03 (any obstacle taller
            than 3 cm is seen at every distance).
        sensor_aim_m: horizontal distance at which the sensor's ray meets flat ground [m];
            default 3.2 (just beyond the sensor's 3 m range, so flat ground reads "no target").
        profile_heights_m: heights above the ground of the sensor's horizontal profile beams [m],
            strictly increasing, at most 3 (SB_Profile's beam slots); default (0.05, 0.09, 0.13).
            Each beam starts at the range sensor's origin (x) and looks straight ahead.
        gravity_m_s2: gravity [m/s^2]; default 9.81.
        solver_iterations: PyBullet constraint solver iterations; default 20 (enough for one foot contact).
        contact_force_n: normal force above which a switch reads closed [N]; default 0.5.
    """

    physics_hz: float = 1000.0
    rail_speed_m_s: float = 0.5
    sensor_offset_x_m: float = 0.20
    sensor_height_m: float = 0.03
    sensor_aim_m: float = 3.2
    profile_heights_m: tuple[float, ...] = (0.05, 0.09, 0.13)
    gravity_m_s2: float = 9.81
    solver_iterations: int = 20
    contact_force_n: float = 0.5

    def __post_init__(self) -> None:
        if not 100.0 <= self.physics_hz <= 20000.0:
            raise ValueError(f"physics_hz must be in [100, 20000] Hz, got {self.physics_hz}")
        if not 0.0 <= self.rail_speed_m_s <= 3.0:
            raise ValueError(f"rail_speed_m_s must be in [0, 3] m/s, got {self.rail_speed_m_s}")
        heights = tuple(self.profile_heights_m)
        if len(heights) > PROFILE_MAX_BEAMS:
            raise ValueError(f"profile_heights_m: at most {PROFILE_MAX_BEAMS} beams, got {len(heights)}")
        if not all(isinstance(h, (int, float)) and math.isfinite(h) and 0.0 < h <= 0.5 for h in heights):
            raise ValueError(f"profile_heights_m must be in (0, 0.5] m, got {heights!r}")
        if any(b <= a for a, b in zip(heights, heights[1:])):
            raise ValueError(f"profile_heights_m must be strictly increasing, got {heights!r}")


@interpreted  # a configuration: plain Python even when compiled (protocol.compiled)
@dataclass(frozen=True)
class Obstacle:
    """A rectangular block across the rail.

    Attributes:
        near_edge_x_m: world x of its near (leg-side) face [m].
        height_m: height [m]; default 0.10.
        depth_m: extent along the rail [m]; default 0.10.
    """

    near_edge_x_m: float
    height_m: float = 0.10
    depth_m: float = 0.10


@contextlib.contextmanager
def _c_stdout_to_stderr():
    """PyBullet's C code prints a banner on stdout when it connects; keep stdout for our JSON."""
    sys.stdout.flush()
    saved = os.dup(1)
    try:
        os.dup2(2, 1)
        yield
    finally:
        os.dup2(saved, 1)
        os.close(saved)


@mypyc_attr(allow_interpreted_subclasses=True)  # the physics floor's recording plant
class RigPlant:
    """The rig in a PyBullet world (DIRECT by default, GUI for a person watching)."""

    def __init__(self, config: RigConfig = RigConfig(), *, gui: bool = False) -> None:
        self.config = config
        self.dt_s = 1.0 / config.physics_hz
        with _c_stdout_to_stderr():
            self._p = bullet_client.BulletClient(connection_mode=pybullet.GUI if gui else pybullet.DIRECT)
        self._cid = self._p._client
        p = self._p
        p.setPhysicsEngineParameter(fixedTimeStep=self.dt_s, numSolverIterations=config.solver_iterations)
        p.setGravity(0, 0, -config.gravity_m_s2)
        self.ground = p.loadURDF(str(urdf.GROUND), useFixedBase=True)
        self.robot = p.loadURDF(str(urdf.GAIT_RIG), useFixedBase=True)
        names = {p.getJointInfo(self.robot, j)[1].decode(): j for j in range(p.getNumJoints(self.robot))}
        self._rail = names["rail"]
        self._joint_index = {name: names[name] for name in LEG_JOINTS}
        self._leg = [self._joint_index[n] for n in LEG_JOINTS]
        self._read_joints = [*self._leg, self._rail]  # what each step reads back: the leg, then the rail
        self.foot_link = names["ankle"]
        self.shank_link = self._joint_index["knee"]
        self.thigh_link = self._joint_index["hip"]
        self.joint_limits_rad = {
            n: (p.getJointInfo(self.robot, j)[8], p.getJointInfo(self.robot, j)[9]) for n, j in self._joint_index.items()
        }
        self.effort_limits_nm: dict[str, float] = {
            n: p.getJointInfo(self.robot, j)[10] for n, j in self._joint_index.items()
        }
        # Joints are torque-driven: switch off PyBullet's default velocity motors.
        p.setJointMotorControlArray(self.robot, self._leg, pybullet.VELOCITY_CONTROL, forces=[0.0, 0.0])
        self._torque = [0.0, 0.0]
        self._states: tuple = ()
        self._obstacles: list[tuple[int, Obstacle]] = []
        self._urdf_dir = tempfile.TemporaryDirectory(prefix="es-obstacles-")
        self.t_s = 0.0
        self.rail_speed_m_s = config.rail_speed_m_s
        # reset's defaults written out: compiled, a call that reaches a Python subclass's override
        # (the recording plant) passes omitted float arguments as 0.0 (mypyc 2.4's glue ignores them)
        self.reset(0.0, 0.5, -1.0)

    # -- scenario side channel -------------------------------------------------------------
    def reset(self, carriage_x_m: float = 0.0, hip_rad: float = 0.5, knee_rad: float = -1.0) -> None:
        """Put the carriage at ``carriage_x_m`` moving at the rail speed, the leg at rest."""
        p = self._p
        p.resetJointState(self.robot, self._rail, carriage_x_m, self.rail_speed_m_s)
        p.resetJointState(self.robot, self._joint_index["hip"], hip_rad, 0.0)
        p.resetJointState(self.robot, self._joint_index["knee"], knee_rad, 0.0)
        self.set_rail_speed(self.rail_speed_m_s)
        self._torque = [0.0, 0.0]
        self._contacts_t_s = -1.0
        self._contacts = (False, False)
        self._contact_points: tuple = ()
        self._points_fresh = False
        self._read_states()

    def set_rail_speed(self, speed_m_s: float) -> None:
        self.rail_speed_m_s = speed_m_s
        self._p.setJointMotorControl2(
            self.robot, self._rail, pybullet.VELOCITY_CONTROL, targetVelocity=speed_m_s, force=2000.0
        )

    GROUND_END_X_M: Final = 399.0

    def rewind_rail(self, distance_m: float) -> None:
        """Move the carriage (and the leg with it) back along the rail, keeping every joint's
        state: the treadmill rig's way of running forever on finite ground. Call it only while
        the foot is in the air and no obstacle is placed."""
        if self._obstacles:
            raise RuntimeError("rewind the rail only with no obstacle placed")
        p = self._p
        x, v = p.getJointState(self.robot, self._rail)[:2]
        p.resetJointState(self.robot, self._rail, x - distance_m, v)
        self.set_rail_speed(self.rail_speed_m_s)
        self._read_states()
        self._contacts_t_s = -1.0

    def add_obstacle(self, obstacle: Obstacle) -> int:
        path = Path(self._urdf_dir.name) / f"obstacle_{obstacle.height_m:.4f}_{obstacle.depth_m:.4f}.urdf"
        if not path.exists():
            path.write_text(urdf.obstacle_urdf(obstacle.height_m, obstacle.depth_m))
        body = self._p.loadURDF(str(path), basePosition=[obstacle.near_edge_x_m, 0.0, 0.0], useFixedBase=True)
        self._obstacles.append((body, obstacle))
        self._points_fresh = False  # a body id may be reused: the cached points no longer name the obstacles
        return body

    def clear_obstacles(self) -> None:
        for body, _ in self._obstacles:
            self._p.removeBody(body)
        self._obstacles.clear()
        self._points_fresh = False

    @property
    def obstacles(self) -> list[Obstacle]:
        return [o for _, o in self._obstacles]

    # -- motor driver side -----------------------------------------------------------------
    def joint_state(self, name: str) -> tuple[float, float]:
        """(angle [rad], velocity [rad/s]) of a leg joint, as of the last physics step."""
        state = self._states[_SLOT[name]]
        return state[0], state[1]

    def set_joint_torque(self, name: str, torque_nm: float) -> None:
        """Torque applied at the next step [N m], clamped to the joint's effort limit."""
        limit = self.effort_limits_nm[name]
        self._torque[_SLOT[name]] = limit if torque_nm > limit else (-limit if torque_nm < -limit else torque_nm)

    def step(self) -> None:
        """Apply the held torques and advance one physics step (the hot path: raw pybullet calls)."""
        cid = self._cid
        unused = _UNUSED_IN_TORQUE_CONTROL
        # kwlist: bodyUniqueId, jointIndices, controlMode, targetPositions, targetVelocities, forces,
        # positionGains, velocityGains, physicsClientId
        pybullet.setJointMotorControlArray(self.robot, self._leg, pybullet.TORQUE_CONTROL, unused, unused,
                                           self._torque, unused, unused, cid)
        pybullet.stepSimulation(cid)  # kwlist: physicsClientId
        self.t_s += self.dt_s
        self._read_states()

    def _read_states(self) -> None:
        # the leg's joints and the rail in one call: the rail's state is the last one
        # kwlist: bodyUniqueId, jointIndices, physicsClientId
        self._states = tuple(pybullet.getJointStates(self.robot, self._read_joints, self._cid))

    # -- sensor board side -----------------------------------------------------------------
    @property
    def carriage_x_m(self) -> float:
        """The carriage's position on the rail [m], as read after the last step (or reset, or
        rewind): nothing moves it between steps."""
        return self._states[-1][0]

    def range_m(self) -> float | None:
        """True distance along the range sensor's ray to the first hit within 3 m, else None."""
        c = self.config
        x0 = self.carriage_x_m + c.sensor_offset_x_m
        z0 = c.sensor_height_m
        length = math.hypot(c.sensor_aim_m, z0)
        # kwlist: rayFromPosition, rayToPosition, collisionFilterMask=-1, reportHitNumber=-1, physicsClientId
        hit = pybullet.rayTest([x0, 0.0, z0], [x0 + c.sensor_aim_m, 0.0, 0.0], -1, -1, self._cid)[0]
        if hit[0] < 0 or hit[0] == self.robot:
            return None
        distance = hit[2] * length
        return distance if distance <= SENSOR_MAX_RANGE_M else None

    def range_profile_m(self) -> tuple[float | None, ...]:
        """True distance along each horizontal profile beam (lowest first) to the first hit within
        3 m, else None; one entry per ``RigConfig.profile_heights_m``. A beam whose first hit is
        the rig itself (the leg in front of the boom) returns None, like :meth:`range_m`."""
        heights = self.config.profile_heights_m
        if not heights:
            return ()
        x0 = self.carriage_x_m + self.config.sensor_offset_x_m
        reach = SENSOR_MAX_RANGE_M
        # kwlist: rayFromPositions, rayToPositions, numThreads=1, parentObjectUniqueId=-1, parentLinkIndex=-1,
        # reportHitNumber=-1, collisionFilterMask=-1, fractionEpsilon=-1.0, physicsClientId
        hits = pybullet.rayTestBatch([[x0, 0.0, h] for h in heights], [[x0 + reach, 0.0, h] for h in heights],
                                     1, -1, -1, -1, -1, -1.0, self._cid)
        return tuple(None if hit[0] < 0 or hit[0] == self.robot else hit[2] * reach for hit in hits)

    def contacts(self) -> tuple[bool, bool]:
        """(foot switch, shin switch): each closed while its link presses on anything.

        Read once per physics step and cached: the sensor board and the experiment's ground
        truth may both ask within one step.
        """
        if self._contacts_t_s == self.t_s:
            return self._contacts
        foot = shin = False
        threshold = self.config.contact_force_n
        # kwlist: bodyA, bodyB=-1, linkIndexA=-2, linkIndexB=-2, physicsClientId
        points = pybullet.getContactPoints(self.robot, -1, -2, -2, self._cid)
        for pt in points:
            if pt[9] > threshold:
                if pt[3] == self.foot_link:
                    foot = True
                elif pt[3] == self.shank_link:
                    shin = True
        self._contacts = (foot, shin)
        self._contacts_t_s = self.t_s
        self._contact_points = points
        self._points_fresh = True
        return self._contacts

    # -- ground truth for experiments (never on the bus) ------------------------------------
    def foot_position(self) -> tuple[float, float]:
        """World (x, z) of the foot sphere's lowest point [m]."""
        # kwlist: bodyUniqueId, linkIndex, computeLinkVelocity=0, computeForwardKinematics=0, physicsClientId
        pos = pybullet.getLinkState(self.robot, self.foot_link, 0, 0, self._cid)[0]
        return pos[0], pos[2] - 0.02

    def obstacle_contact(self) -> bool:
        """True while any leg link touches any obstacle: a contact point whose bodies touch or
        overlap (contact distance at most 0) or press (normal force above 0).

        PyBullet also reports points up to its contact margin apart, with no force: a foot
        passing 0.4-0.7 mm above a block's edge is such a point (tuning seed 71). That is a near
        miss, not a touch: no switch could close on it, and a trial is not failed by it.

        Answered from the leg's contact points that :meth:`contacts` read this step, when it did
        and no obstacle came or went since (PyBullet's ``getContactPoints(bodyA=leg, bodyB=b)`` is
        that same list filtered on ``b``: one query fewer per step); else asked per obstacle."""
        obstacles = self._obstacles
        if not obstacles:
            return False
        if self._points_fresh and self._contacts_t_s == self.t_s:
            bodies = [body for body, _ in obstacles]
            for pt in self._contact_points:
                if pt[2] in bodies and touching(pt):
                    return True
            return False
        for body, _ in obstacles:
            # kwlist: see contacts
            for pt in pybullet.getContactPoints(self.robot, body, -2, -2, self._cid):
                if touching(pt):
                    return True
        return False

    def leg_contact_points(self) -> list[tuple[str, str, float, float]]:
        """The leg's contact points of this step, for diagnosis (issue 18's contacts no reflex
        heard): (link, body, distance [m], normal force [N]); link ``foot``, ``shank`` or
        ``link<index>``, body ``block``, ``ground`` or ``body<id>``. The points :meth:`contacts`
        read this step (read now if it has not)."""
        self.contacts()
        links = {self.foot_link: "foot", self.shank_link: "shank"}
        bodies = {body: "block" for body, _ in self._obstacles}
        bodies[self.ground] = "ground"
        return [(links.get(pt[3], f"link{pt[3]}"), bodies.get(pt[2], f"body{pt[2]}"), float(pt[8]), float(pt[9]))
                for pt in self._contact_points]

    def render_rgb(self, width: int = 480, height: int = 320, target_x_m: float | None = None):
        """An RGB image (height x width x 3 uint8 list) from a side camera, DIRECT mode included."""
        x = self.carriage_x_m if target_x_m is None else target_x_m
        view = self._p.computeViewMatrix([x, -1.6, 0.35], [x, 0.0, 0.25], [0, 0, 1])
        proj = self._p.computeProjectionMatrixFOV(40.0, width / height, 0.05, 10.0)
        _, _, rgb, _, _ = self._p.getCameraImage(width, height, view, proj, renderer=pybullet.ER_TINY_RENDERER)
        return rgb

    def close(self) -> None:
        try:
            self._p.disconnect()
        except pybullet.error:
            pass
        self._urdf_dir.cleanup()
