"""The physics floor of a learning run: the same motion replayed into PyBullet alone, timed beside the stack.

What the stack costs is only meaningful beside what the physics it simulates costs; a different
motion (a collapsed leg with zero torque) is no floor, it costs more a step than walking does. So:

1. :func:`record` runs a learning run (:class:`hil.experiments.learn.LearningRun`: bring-up, one
   second of walking, then trials, obstacle by obstacle) through the whole stack in lockstep and
   records, per physics step, what the plant was given: the two joint torques PyBullet applied
   (the plant's held torques, already clamped, read as it steps), the scenario events between
   steps (obstacle placed or cleared, rail rewound, rail speed set, reset), the queries the stack
   made of PyBullet between steps (rail position, contacts, range ray, profile beams, foot position,
   obstacle contact where the plant could not answer it from the step's contact points: the sensor
   board at its rates and the experiment's ground truth), and the leg's
   joint states after the step. It is recorded from outside: the run's harness is a
   :class:`_RecordingLockstep`, whose leg runs on a recording subclass of the plant
   (:class:`_RecordingPlant`) that calls the plant's own methods and notes them; nothing under
   ``firmware_sim`` or ``controller`` changes, and the recording run is never timed.
2. :func:`replay` builds a fresh world with the plant's own constructor (:class:`RigPlant`, DIRECT,
   the same :class:`RigConfig`: nothing of the world differs), applies the recorded torques step by
   step with the calls :meth:`RigPlant.step` makes (``setJointMotorControlArray`` with
   ``TORQUE_CONTROL``, ``stepSimulation``, ``getJointStates``), replays the events through the
   plant's own methods at the same places, and, with ``queries``, makes the recorded queries with
   the raw PyBullet calls the plant makes for them, with the same arguments, positional where the
   plant passes them so (each kind at most once between two steps, the
   minimum the stack needs: the stack may ask the rail several times a step). :func:`exact` checks
   that the joint states are the recorded ones bit for bit.
3. :func:`measure` times the stack (the same run again, unrecorded: it is deterministic for a
   seed, and its last joint state is checked against the recording) and both replays,
   interleaved, in ``pairs`` rounds of (stack, floor, floor with queries) in one process (the two
   replays' order alternating from round to round), in **process CPU time** (``time.process_time``:
   time the process is descheduled is not counted; wall time is kept beside it in the detail) per
   physics step, and reports the medians and the median of the per-round ratios. The stack's
   time includes the experiment's own Python (ground truth, trial bookkeeping) and the one-line
   check that ends the run at ``seconds``.

Only the stepping is timed: building the stack or the world is not, and a full garbage collection
runs before each timed section (the stack's objects are freed in reference cycles by the collector:
without it, the replay that follows a stack run paid for them, 4-6 us a step here). The garbage
collector stays on while timing, for both.
"""

from __future__ import annotations

import gc
import logging
import statistics
import time
from array import array
from dataclasses import dataclass
from typing import Any, Iterable

import pybullet

from firmware_sim.plant import _UNUSED_IN_TORQUE_CONTROL, SENSOR_MAX_RANGE_M, Obstacle, RigConfig, RigPlant, touching
from hil.lockstep.harness import Lockstep, LockstepConfig

log = logging.getLogger(__name__)

DEFAULT_PAIRS = 5
"""Rounds of (stack, floor, floor with queries) by default: the medians need at least 3."""

EVENTS = frozenset({"reset", "rail_speed", "rewind", "add_obstacle", "clear_obstacles"})
"""The ops between two physics steps that change the world (the floor replays them); the others
(rail, contacts, range, profile, foot, obstacle_contact) only read it (the floor with queries)."""


@dataclass(frozen=True)
class Recording:
    """A recorded run. Attributes:
        rig: the plant's configuration (the replay builds its world from it).
        torques_nm: per physics step, the (hip, knee) joint torques PyBullet was given [N m].
        states: per physics step, the leg's joint states after it, as ``getJointStates`` returned them.
        ops: per gap, ``ops[k]`` = what happened after step ``k`` and before step ``k + 1`` (gap 0:
            before the first step), in order: events ``(name, *args)`` and queries ``(name,)``;
            a query kind is kept once per gap between two events.
        sim_s: simulated time at the end [s].
        trials: trials begun.
    """

    rig: RigConfig
    torques_nm: tuple[tuple[float, float], ...]
    states: tuple[tuple, ...]
    ops: tuple[tuple[tuple, ...], ...]
    sim_s: float
    trials: int

    @property
    def steps(self) -> int:
        return len(self.torques_nm)

    def counts(self) -> dict[str, int]:
        """How many times each event and query kind occurs in the run."""
        out: dict[str, int] = {}
        for gap in self.ops:
            for op in gap:
                out[op[0]] = out.get(op[0], 0) + 1
        return dict(sorted(out.items()))


class _Stop(Exception):
    """Raised from a trial's ``on_step`` when the run has done its physics steps."""


class _RecordingPlant(RigPlant):
    """The plant of a recording run: every method the stack uses, the plant's own, noted.

    Built by the leg of a :class:`_RecordingLockstep` (its ``plant_class``) with the plant's own
    constructor (what happens in it, a reset, is not noted: the replay's plant is built the same
    way). A Python subclass of the compiled plant (``RigPlant`` allows them): the compiled stack's calls on it reach these methods
    (mypyc gives a Python subclass's instances a table of calls through Python). Queries are noted
    when they return (a range ray reads the rail first, so the rail is noted first); events only at
    the outermost call (a rewind sets the rail speed itself)."""

    def __init__(self, config: RigConfig, *, gui: bool = False) -> None:
        self._rec_ops: list[list[tuple]] = [[]]
        self._rec_since_event: set[str] = set()
        self._rec_depth = 1  # the constructor's own reset is not an event of the run
        self._rec_torques: list[tuple[float, float]] = []
        self._rec_states: list[tuple] = []
        super().__init__(config, gui=gui)
        self._rec_depth = 0

    def _note_query(self, name: str) -> None:
        if name not in self._rec_since_event:
            self._rec_since_event.add(name)
            self._rec_ops[-1].append((name,))

    def _event(self, name: str, args: tuple, fn, *call_args):
        outer = self._rec_depth == 0
        self._rec_depth += 1
        try:
            result = fn(*call_args)
        finally:
            self._rec_depth -= 1
        if outer:
            self._rec_ops[-1].append((name, *args))
            self._rec_since_event.clear()
        return result

    # -- the hot path
    def step(self) -> None:
        self._rec_torques.append((self._torque[0], self._torque[1]))
        RigPlant.step(self)
        self._rec_states.append(self._states)
        self._rec_ops.append([])
        self._rec_since_event = set()

    # -- events
    def reset(self, carriage_x_m: float = 0.0, hip_rad: float = 0.5, knee_rad: float = -1.0) -> None:
        self._event("reset", (carriage_x_m, hip_rad, knee_rad), RigPlant.reset, self, carriage_x_m, hip_rad, knee_rad)

    def set_rail_speed(self, speed_m_s: float) -> None:
        self._event("rail_speed", (speed_m_s,), RigPlant.set_rail_speed, self, speed_m_s)

    def rewind_rail(self, distance_m: float) -> None:
        self._event("rewind", (distance_m,), RigPlant.rewind_rail, self, distance_m)

    def add_obstacle(self, obstacle: Obstacle) -> int:
        return self._event("add_obstacle", (obstacle,), RigPlant.add_obstacle, self, obstacle)

    def clear_obstacles(self) -> None:
        self._event("clear_obstacles", (), RigPlant.clear_obstacles, self)

    # -- queries
    @property
    def carriage_x_m(self) -> float:
        x = RigPlant.carriage_x_m.__get__(self)  # a property, or a compiled class's getset descriptor
        self._note_query("rail")
        return x

    def range_m(self) -> float | None:
        r = RigPlant.range_m(self)
        self._note_query("range")
        return r

    def range_profile_m(self) -> tuple[float | None, ...]:
        r = RigPlant.range_profile_m(self)
        self._note_query("profile")
        return r

    def contacts(self) -> tuple[bool, bool]:
        fresh = self._contacts_t_s != self.t_s  # else the plant answers from its cache: no query
        r = RigPlant.contacts(self)
        if fresh:
            self._note_query("contacts")
        return r

    def foot_position(self) -> tuple[float, float]:
        r = RigPlant.foot_position(self)
        self._note_query("foot")
        return r

    def obstacle_contact(self) -> bool:
        # answered from the contact points of this step when the plant has them: no query then
        cached = self._points_fresh and self._contacts_t_s == self.t_s
        r = RigPlant.obstacle_contact(self)
        if self._obstacles and not cached:
            self._note_query("obstacle_contact")
        return r


class _RecordingLockstep(Lockstep):
    """The harness of a recording run: a :class:`Lockstep` whose leg is built on a
    :class:`_RecordingPlant` (the leg's ``plant_class``), the same constructor and configuration as
    an unrecorded run's plant (the recorded states are checked against an unrecorded run's by
    :func:`measure`)."""

    def __init__(self, config: LockstepConfig, **kwargs: Any) -> None:
        super().__init__(config, plant_class=_RecordingPlant, **kwargs)


def _learning_run(seed: int, recording: bool) -> Any:
    """A learning run of seed ``seed`` (:class:`~hil.experiments.learn.LearningRun`, the default
    configuration), built, not stepped; with ``recording``, its plant records."""
    from hil.experiments.learn import LearnConfig, LearningRun

    return LearningRun(LearnConfig(seed=seed), harness=_RecordingLockstep if recording else Lockstep)


def _drive(run: Any, seconds: float) -> int:
    """Step ``run`` until at least ``seconds`` of simulated time, ended within a trial if need be
    (the bring-up and its second of walking are always done whole); returns the trials begun."""
    ls = run.ls

    def enough(_ls) -> None:
        if ls.t_s >= seconds - 1e-9:
            raise _Stop

    run.bring_up()
    trials = 0
    try:
        while ls.t_s < seconds - 1e-9:
            trials += 1
            run.trial(trials - 1, on_step=enough)
    except _Stop:
        pass
    return trials


def record(seconds: float = 10.0, seed: int = 0) -> Recording:
    """Record a learning run of at least ``seconds`` simulated (see the module's docstring)."""
    run = _learning_run(seed, recording=True)
    plant: Any = run.ls.plant
    try:
        trials = _drive(run, seconds)
        rig = run.ls.config.rig
        sim_s = run.ls.t_s
        ops = tuple(tuple(gap) for gap in plant._rec_ops)
        return Recording(rig=rig, torques_nm=tuple(plant._rec_torques), states=tuple(plant._rec_states),
                         ops=ops, sim_s=sim_s, trials=trials)
    finally:
        run.close()


def time_stack(seconds: float, seed: int = 0) -> dict[str, Any]:
    """The same learning run through the whole stack, unrecorded: process CPU and wall time of its
    stepping (``cpu_s``, ``wall_s``), ``steps``, ``sim_s`` and the leg's ``last_state``."""
    run = _learning_run(seed, recording=False)
    plant = run.ls.plant
    try:
        steps0 = run.ls.physics_steps
        gc.collect()  # what earlier runs left in reference cycles is not this run's cost
        c0, w0 = time.process_time(), time.perf_counter()
        trials = _drive(run, seconds)
        cpu, wall = time.process_time() - c0, time.perf_counter() - w0
        return {"cpu_s": cpu, "wall_s": wall, "steps": run.ls.physics_steps - steps0, "sim_s": run.ls.t_s,
                "trials": trials, "last_state": plant._states}
    finally:
        run.close()


def replay(rec: Recording, *, queries: bool = False) -> dict[str, Any]:
    """Replay ``rec`` into a fresh world; ``queries``: also the recorded queries. Returns process CPU
    and wall time of the stepping (``cpu_s``, ``wall_s``), ``steps`` and the joint ``states``."""
    plant = RigPlant(rec.rig)
    try:
        return _replay_into(plant, rec, queries)
    finally:
        plant.close()


def _replay_into(plant: RigPlant, rec: Recording, queries: bool) -> dict[str, Any]:
    """The replay loop: the plant's raw PyBullet calls on its own ids (``_cid``, ``_leg``, ``_rail``:
    read here, never changed), with no layer of Python between them but the loop's; each call
    passes its arguments as :mod:`firmware_sim.plant` does (positional, the defaults written out:
    the orders are in its docstring's source, pybullet.c's kwlists)."""
    cfg = plant.config
    cid = plant._cid
    robot = plant.robot
    leg = list(plant._leg)
    joints = list(plant._read_joints)  # what the plant reads back each step: the leg, then the rail
    foot_link, shank_link = plant.foot_link, plant.shank_link
    threshold = cfg.contact_force_n
    offset_x, z0, aim = cfg.sensor_offset_x_m, cfg.sensor_height_m, cfg.sensor_aim_m
    heights = cfg.profile_heights_m
    reach = SENSOR_MAX_RANGE_M
    keep = None if queries else EVENTS
    after: list[tuple | None] = [None] * (rec.steps + 1)
    for k, gap in enumerate(rec.ops):
        ops = tuple(op for op in gap if keep is None or op[0] in keep)
        after[k] = ops or None
    torques = rec.torques_nm
    n = rec.steps
    out: list[Any] = [None] * n
    bodies: list[int] = []
    set_motors = pybullet.setJointMotorControlArray
    step_sim = pybullet.stepSimulation
    joint_states = pybullet.getJointStates
    contact_points = pybullet.getContactPoints
    ray = pybullet.rayTest
    rays = pybullet.rayTestBatch
    link_state = pybullet.getLinkState
    torque_control = pybullet.TORQUE_CONTROL
    unused = _UNUSED_IN_TORQUE_CONTROL  # the targets and gains TORQUE_CONTROL does not use, as the plant gives them
    x = 0.0
    last: Any = plant._states
    switches = (False, False)  # what the sensor board would send: the floor does the plant's work for it

    def run_ops(ops: tuple) -> None:
        nonlocal x, switches, last
        for op in ops:
            name = op[0]
            if name == "rail":
                x = last[-1][0]  # read with the joint states, as the plant reads it
            elif name == "contacts":
                foot = shin = False
                for pt in contact_points(robot, -1, -2, -2, cid):
                    if pt[9] > threshold:
                        if pt[3] == foot_link:
                            foot = True
                        elif pt[3] == shank_link:
                            shin = True
                switches = (foot, shin)
            elif name == "range":
                x0 = x + offset_x
                ray([x0, 0.0, z0], [x0 + aim, 0.0, 0.0], -1, -1, cid)
            elif name == "profile":
                x0 = x + offset_x
                rays([[x0, 0.0, h] for h in heights], [[x0 + reach, 0.0, h] for h in heights], 1, -1, -1, -1, -1, -1.0,
                     cid)
            elif name == "foot":
                link_state(robot, foot_link, 0, 0, cid)
            elif name == "obstacle_contact":
                for body in bodies:
                    if any(touching(pt) for pt in contact_points(robot, body, -2, -2, cid)):
                        break
            elif name == "add_obstacle":
                bodies.append(plant.add_obstacle(op[1]))
            elif name == "clear_obstacles":
                plant.clear_obstacles()
                bodies.clear()
            elif name == "rewind":
                plant.rewind_rail(op[1])
                last = plant._states  # the rail read back after the move, as the plant does
            elif name == "rail_speed":
                plant.set_rail_speed(op[1])
            elif name == "reset":
                plant.reset(*op[1:])
                last = plant._states
            else:
                raise ValueError(f"unknown op {name!r} in the recording")

    gc.collect()  # the cycles a stack run leaves are freed here, not charged to the replay
    c0, w0 = time.process_time(), time.perf_counter()
    if after[0] is not None:
        run_ops(after[0])
    for k in range(n):
        set_motors(robot, leg, torque_control, unused, unused, torques[k], unused, unused, cid)
        step_sim(cid)
        out[k] = last = joint_states(robot, joints, cid)
        ops = after[k + 1]
        if ops is not None:
            run_ops(ops)
    cpu, wall = time.process_time() - c0, time.perf_counter() - w0
    return {"cpu_s": cpu, "wall_s": wall, "steps": n, "states": out}


def _bits(states: Iterable) -> bytes:
    """The joint states as the bytes of their doubles (position, velocity, reaction, torque)."""
    flat = array("d")
    for joints in states:
        for pos, vel, reaction, torque in joints:
            flat.extend((pos, vel, *reaction, torque))
    return flat.tobytes()


def first_difference(recorded: Iterable, replayed: Iterable) -> int | None:
    """The first physics step (0-based) whose joint states differ in any bit, else None (a
    shorter replay differs at its end)."""
    a, b = list(recorded), list(replayed)
    for k, (x, y) in enumerate(zip(a, b)):
        if _bits([x]) != _bits([y]):
            return k
    return None if len(a) == len(b) else min(len(a), len(b))


def exact(rec: Recording, replayed: dict[str, Any]) -> bool:
    """Whether a replay's joint states are the recorded ones, bit for bit."""
    return len(replayed["states"]) == rec.steps and _bits(rec.states) == _bits(replayed["states"])


def measure(seconds: float = 10.0, seed: int = 0, pairs: int = DEFAULT_PAIRS) -> dict[str, Any]:
    """Record, check both replays are exact, then time ``pairs`` interleaved rounds of (stack,
    floor, floor with queries) in process CPU per physics step; the figures of ``bench``."""
    if pairs < 3:
        raise ValueError(f"pairs must be at least 3 (medians of interleaved pairs), got {pairs}")
    rec = record(seconds, seed)
    rounds: list[dict[str, Any]] = []
    for i in range(pairs):
        stack = time_stack(seconds, seed)
        if stack["steps"] != rec.steps or _bits([stack["last_state"]]) != _bits([rec.states[-1]]):
            raise RuntimeError(f"the timed stack run {i} is not the recorded motion "
                               f"({stack['steps']} steps against {rec.steps} recorded)")
        if i % 2 == 0:  # alternate which replay follows the stack: neither always runs in its wake
            floor = replay(rec)
            floor_q = replay(rec, queries=True)
        else:
            floor_q = replay(rec, queries=True)
            floor = replay(rec)
        for name, r in (("floor", floor), ("floor with queries", floor_q)):
            k = first_difference(rec.states, r["states"])
            if k is not None:
                raise RuntimeError(f"the {name} replay {i} differs from the recording at physics step {k}")
        n = rec.steps
        row = {"stack_us_per_step": stack["cpu_s"] / n * 1e6,
               "floor_us_per_step": floor["cpu_s"] / n * 1e6,
               "floor_queries_us_per_step": floor_q["cpu_s"] / n * 1e6,
               "stack_wall_us_per_step": stack["wall_s"] / n * 1e6,
               "floor_wall_us_per_step": floor["wall_s"] / n * 1e6,
               "floor_queries_wall_us_per_step": floor_q["wall_s"] / n * 1e6}
        row["stack_vs_floor"] = row["stack_us_per_step"] / row["floor_us_per_step"]
        row["stack_vs_floor_queries"] = row["stack_us_per_step"] / row["floor_queries_us_per_step"]
        log.info("physics floor round %d: stack %.1f us, floor %.1f us, floor+queries %.1f us a step", i,
                 row["stack_us_per_step"], row["floor_us_per_step"], row["floor_queries_us_per_step"])
        rounds.append(row)

    def med(key: str) -> float:
        return statistics.median(r[key] for r in rounds)

    return {
        "floor_us_per_step": med("floor_us_per_step"),
        "floor_queries_us_per_step": med("floor_queries_us_per_step"),
        "stack_us_per_step": med("stack_us_per_step"),
        "stack_vs_floor": med("stack_vs_floor"),
        "stack_vs_floor_queries": med("stack_vs_floor_queries"),
        "detail": {
            "clock": "process CPU time (time.process_time) of the stepping only, per physics step; wall time beside it",
            "run": f"learning run, seed {seed}: bring-up, 1 s of walking, trials until {seconds:g} s simulated",
            "steps": rec.steps, "sim_s": rec.sim_s, "trials": rec.trials,
            "replay_exact": True,  # checked above for every replay: a difference raises
            "ops": rec.counts(),
            "pairs": rounds,
        },
    }
