"""The learning experiment: trial after trial, the leg approaches an obstacle and steps over it.

The leg walks continuously through the whole stack in lockstep. A trial places a rectangular
obstacle at a random distance ahead (a side channel of the simulation: the controller learns of
it only through the range sensor), walks until the hip is well past it, and removes it; the next
trial's obstacle comes into view at once. Success is ground truth from the plant: no contact
between any leg link and the obstacle. What the controller felt (its reflexes), decided (its
gated burst changes) and learned (its weights) is read from the controller's own records.

A run into a folder survives being stopped (:func:`learn_into`, docs/runs.md): every finished
trial is appended to ``trials.jsonl`` at once, the same command again resumes an unfinished run by
re-running its kept trials deterministically (each checked against its record) and going on, a
finished run is not run again, and a folder of another configuration is refused unless
``overwrite``. PyBullet's in-memory save and restore is bit-exact for this plant over a trial
boundary (tests/hil/experiments/test_learn_resume.py), but a checkpoint would also have to hold
the drivers, the controller, the bus and every random generator: the re-run is what resumes.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import shutil
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable

import numpy as np

from controller.atomic import fsync_dir, write_json_atomic
from controller.config import ControllerConfig
from controller.errors import InputError, stamp
from controller.stepping.context import ContextPremotor
from controller.stepping.learner import AdaptivePremotor
from controller.supervisor import Phase
from controller.stepping.weights import WeightsError, read_weights, save_weights
from firmware_sim.leg import LegHardware
from firmware_sim.plant import Obstacle, RigConfig
from hil.analysis.metrics import (METRICS_FILE, METRICS_FORMAT, footfall_std_by_step, last_window, mistakes_101_150,
                                  read_metrics, window_success)
from hil.experiments.conditions import Conditions, check_leg_limit
from hil.experiments.journal import (LOCK_FILE, TRIALS_FILE, FolderLock, Journal, JournalWriter, prepare_folder,
                                     read_journal)
from hil.lockstep.groundtruth import FootfallTracker
from hil.experiments.methods import CONTROLLER_METHOD, get as get_method
from hil.lockstep.harness import Lockstep, LockstepConfig

log = logging.getLogger(__name__)


FIGURE_TRACES = (0, -1)
"""The trials ``learn`` traces for its figures (Fig. 2: the first and the last); ``hil`` traces the same."""


@dataclass(frozen=True)
class LearnConfig:
    """A learning run.

    Attributes:
        trials: number of approaches; default 150.
        seed: seeds the start distances and the sensor noise; default 0.
        obstacle_height_m: obstacle height [m]; default 0.08.
        obstacle_heights_m: if given, each trial's obstacle height is drawn uniformly from these
            [m] (mixed heights, for the context learner); default () = always obstacle_height_m.
        obstacle_depth_m: obstacle extent along the rail [m]; default 0.10.
        range_noise_m: range sensor noise, one standard deviation [m]; default 0.02.
        range_dropout_prob: probability that a range sample is a dropout; default 0.05.
        rail_speed_m_s: the plant's rail (carriage) speed [m/s]; default 0.5.
        believed_rail_speed_m_s: the rail speed the controller is told [m/s]: it sets
            ``controller.gait.ground_speed_m_s`` (which a caller's controller configuration thus
            cannot set apart from it); None (default): the plant's, stored as that number.
        start_min_m, start_max_m: the obstacle's near edge ahead of the hip when a trial begins
            [m]; uniform, default 2.2-2.9 (two strides of spread, inside the sensor's 3 m).
        past_obstacle_m: a trial ends when the hip is this far past the far edge [m]; 0.45.
        learning: False freezes the weights at zero (the no-adaptation baseline); default True.
        method: which premotor drives the burst length: a name of the method registry
            (:data:`hil.experiments.methods.METHODS`); default "paper" (the Elegant Stepping model,
            the controller's own: :data:`~hil.experiments.methods.CONTROLLER_METHOD`; the
            ``learn`` command's default is ``improved``). A method that does not learn
            (``none``) sets ``learning`` False.
        trace_trials: 0-based indices of trials whose foot path and burst length are recorded
            at ``trace_rate_hz`` into the trial's ``trace`` (Fig. 2, burst against time);
            negative indices count from the end; default none.
        trace_rate_hz: sample rate of a trace [Hz]; default 100.
        controller: the controller's configuration (its ``auto_arm`` is set: a run arms by itself).
            Its range filter's assumed noise (``range_filter.noise_m``) is its own setting, not
            ``range_noise_m``: a sensor noisier than the filter assumes can be tried.

    The experimental conditions among these fields (heights, depth, noise, dropout, start range,
    rail speeds) are declared, with their units and ranges, and checked once, in
    :class:`hil.experiments.conditions.Conditions`; the run keeps them in its header (this
    configuration, in ``trials.jsonl``'s first line and ``metrics.json``), the per-trial draws
    (height, start distance) in each trial's record: why, in that module's docstring.
    """

    trials: int = 150
    seed: int = 0
    obstacle_height_m: float = 0.08
    obstacle_heights_m: tuple[float, ...] = ()
    obstacle_depth_m: float = 0.10
    range_noise_m: float = 0.02
    range_dropout_prob: float = 0.05
    rail_speed_m_s: float = 0.5
    believed_rail_speed_m_s: float | None = None
    start_min_m: float = 2.2
    start_max_m: float = 2.9
    past_obstacle_m: float = 0.45
    learning: bool = True
    method: str = CONTROLLER_METHOD
    trace_trials: tuple[int, ...] = ()
    trace_rate_hz: float = 100.0
    controller: ControllerConfig = field(default_factory=ControllerConfig)

    def __post_init__(self) -> None:
        if not self.controller.auto_arm:  # the lockstep arms by itself (LockstepConfig.auto_arm): say so
            object.__setattr__(self, "controller", replace(self.controller, auto_arm=True))
        if not get_method(self.method).learns:  # a registry name (else ValueError); ``none`` never learns
            object.__setattr__(self, "learning", False)
        if not 1 <= self.trials <= 100000:
            raise ValueError(f"trials must be in [1, 100000], got {self.trials}")
        object.__setattr__(self, "obstacle_heights_m", tuple(self.obstacle_heights_m))
        if self.believed_rail_speed_m_s is None:  # told the truth: stored as the number it is
            object.__setattr__(self, "believed_rail_speed_m_s", self.rail_speed_m_s)
        if self.controller.gait.ground_speed_m_s != self.believed_rail_speed_m_s:  # what the controller is told
            gait = replace(self.controller.gait, ground_speed_m_s=self.believed_rail_speed_m_s)
            object.__setattr__(self, "controller", replace(self.controller, gait=gait))
        Conditions.of_learn(self)  # the conditions' declared ranges (ValueError naming the condition)
        check_leg_limit(self.obstacle_heights_m or (self.obstacle_height_m,), self.obstacle_depth_m,
                        self.controller, "obstacle height")  # and within what the leg can clear at all
        if not 1.0 <= self.trace_rate_hz <= 1000.0:
            raise ValueError(f"trace_rate_hz must be in [1, 1000] Hz, got {self.trace_rate_hz}")

    def lockstep(self) -> LockstepConfig:
        """The plant's and the controller's configuration: the sensor's true noise and dropout and
        the plant's rail speed; the controller's is ``controller`` (told ``believed_rail_speed_m_s``
        by ``__post_init__``; its filter's assumed noise stays its own ``range_filter.noise_m``)."""
        hw = LegHardware()
        sensor = replace(hw.sensor, range_noise_m=self.range_noise_m, range_dropout_prob=self.range_dropout_prob)
        ctl = self.controller
        if not self.learning:
            ctl = replace(ctl, learner=replace(ctl.learner, learning=False))
        return LockstepConfig(seed=self.seed, rig=replace(RigConfig(), rail_speed_m_s=self.rail_speed_m_s),
                              hardware=replace(hw, sensor=sensor), controller=ctl)


STALL_S = 5.0
"""A trial whose carriage is this late [s] at the trial's end stalled (see :meth:`LearningRun.trial`)."""


class LearningRun:
    """One learning run: build with a config, call :meth:`run`, read ``trials`` and the weights."""

    def __init__(self, config: LearnConfig, premotor=None, harness: type[Lockstep] = Lockstep) -> None:
        """``harness``: the lockstep class that joins plant and controller (default :class:`Lockstep`;
        :class:`hil.lockstep.synced.SyncedLockstep` runs the same through the simulated-time protocol)."""
        self.config = config
        self._near_m: float | None = None  # the current obstacle's near edge (ground truth)
        self._height_m = 0.0  # and its height (ground truth)
        if premotor is None:  # None from the registry too: the controller's own premotor
            premotor = get_method(config.method).build(config.controller, config.learning, config.seed,
                                                      self._true_distance_m, self._true_height_m)
        self.ls = harness(config.lockstep(), premotor=premotor)
        self.rng = np.random.default_rng(config.seed)
        self.tracker = FootfallTracker(self.ls.plant, clearance=False)  # no clearance in a trial's record
        self.trials: list[dict[str, Any]] = []
        self.last_times: dict[str, float] = {}
        """The simulated times [s] of the last trial: its start (``t0_s``), the first footfall beyond
        the obstacle's near edge (``crossing_s``) and its end (``end_s``), by which a controller's
        records are matched to it (``hil --clock sim``)."""

    @property
    def near_edge_m(self) -> float | None:
        """The current trial's obstacle near edge [m, world x] (ground truth); None between trials."""
        return self._near_m

    def _true_height_m(self) -> float | None:
        return self._height_m if self._near_m is not None else None

    def _true_distance_m(self) -> float | None:
        if self._near_m is None:
            return None
        return self._near_m - self.ls.plant.foot_position()[0]

    @property
    def premotor(self):
        return self.ls.loop.premotor

    def bring_up(self, timeout_s: float = 10.0) -> None:
        ls = self.ls
        while ls.loop.phase is not Phase.WALK:
            if ls.t_s > timeout_s or ls.loop.phase is Phase.FAULT:
                raise RuntimeError(f"the leg did not come up: {ls.loop.supervisor.fault_cause or ls.loop.phase}")
            ls.step()
        for _ in range(1000):  # one second of walking before the first obstacle
            ls.step()
            self.tracker.update()

    REWIND_AFTER_M = 150.0

    def _rewind_if_far(self) -> None:
        """Past REWIND_AFTER_M, wait for the foot to be in the air and move the rig back."""
        plant = self.ls.plant
        if plant.carriage_x_m < self.REWIND_AFTER_M:
            return
        self._wait_foot_in_air()
        plant.rewind_rail(self.REWIND_AFTER_M)

    def _foot_in_air(self) -> bool:
        """The foot off the ground: no foot contact and at least 2 cm up."""
        plant = self.ls.plant
        return not plant.contacts()[0] and plant.foot_position()[1] >= 0.02

    def _wait_foot_in_air(self) -> None:
        """Step the lockstep (tracking footfalls) until :meth:`_foot_in_air`."""
        while not self._foot_in_air():
            self.ls.step()
            self.tracker.update()

    def traced(self, index: int) -> bool:
        n = self.config.trials
        return any(index == (k if k >= 0 else n + k) for k in self.config.trace_trials)

    def _place_obstacle(self, x0: float) -> tuple[float, float, float]:
        """Place the trial's obstacle (the hip at ``x0``); its near edge [m, world x], height and
        depth [m]: a start distance drawn from ``rng``, then a height if several (the course,
        :mod:`hil.experiments.course`, places its layout's instead)."""
        c = self.config
        near = x0 + float(self.rng.uniform(c.start_min_m, c.start_max_m))
        height = c.obstacle_height_m
        if c.obstacle_heights_m:
            height = float(c.obstacle_heights_m[int(self.rng.integers(len(c.obstacle_heights_m)))])
        self.ls.plant.add_obstacle(Obstacle(near, height, c.obstacle_depth_m))
        return near, height, c.obstacle_depth_m

    def _remove_obstacle(self) -> None:
        """Take the trial's obstacle away at its end (the course keeps those still ahead)."""
        self.ls.plant.clear_obstacles()

    def trial(self, index: int, on_step: Callable[[Lockstep], None] | None = None) -> dict[str, Any]:
        """Run trial ``index``; ``on_step(lockstep)``, if given, is called after every physics step
        (the animation grabs its frames there)."""
        c, ls = self.config, self.ls
        plant, loop = ls.plant, ls.loop
        self._rewind_if_far()
        x0 = plant.carriage_x_m
        near, height, depth = self._place_obstacle(x0)
        far = near + depth
        self._near_m = near
        self._height_m = height
        t0 = ls.t_s
        n_steps0, n_reflex0, n_td0 = len(loop.stats.steps), len(loop.stats.reflexes), len(self.tracker.footfalls_x_m)
        touching = False
        contacts: list[list[float]] = []  # [start, end] of each episode of contact [s], from t0
        trace: dict[str, list[float]] | None = None
        if self.traced(index):
            trace = {"t_s": [], "foot_x_m": [], "foot_z_m": [], "burst_s": [], "contact": []}
        every = max(1, int(round(ls.config.rig.physics_hz / c.trace_rate_hz))) if trace else 0
        n = 0
        # hot path (once a physics step): bound methods and the two bounds hoisted out of the loop
        step, track, end_m, watch_m = ls.step, self.tracker.update, far + c.past_obstacle_m, near - 1.0
        # the carriage reaches the end in (end_m - x0) / speed; one caught on the block (a foot
        # wedged on a tall one) never does: the trial ends as a stalled mistake STALL_S later
        deadline_s = t0 + (end_m - x0) / plant.rail_speed_m_s + STALL_S
        stalled = False
        while plant.carriage_x_m < end_m:
            if ls.t_s > deadline_s:
                stalled = True
                break
            step()
            track()
            if plant.carriage_x_m > watch_m:
                now_touching = plant.obstacle_contact()
                if now_touching:
                    if not touching:
                        contacts.append([ls.t_s - t0, ls.t_s - t0])
                    else:
                        contacts[-1][1] = ls.t_s - t0
                touching = now_touching
            if trace is not None and n % every == 0:
                fx, fz = plant.foot_position()
                trace["t_s"].append(ls.t_s - t0)
                trace["foot_x_m"].append(fx - near)
                trace["foot_z_m"].append(fz)
                trace["burst_s"].append(loop.cpg.burst_s)
                trace["contact"].append(bool(contacts))
            n += 1
            if on_step is not None:
                on_step(ls)
            if loop.phase is Phase.FAULT:
                raise RuntimeError(f"safe stop during trial {index}: {loop.supervisor.fault_cause}")
        self._remove_obstacle()
        self._near_m = None
        touchdowns = list(zip(self.tracker.touchdown_t_s[n_td0:], self.tracker.footfalls_x_m[n_td0:]))
        before = [(t, x) for t, x in touchdowns if x < near]
        crossing_t = next((t for t, x in touchdowns if x >= near), ls.t_s)
        self.last_times = {"t0_s": t0, "crossing_s": crossing_t, "end_s": ls.t_s}
        steps = loop.stats.steps[n_steps0:]
        # the decisions before the crossing: every gate whose swing began before the foot landed
        # beyond the near edge (the last of them is the crossing swing's own gate)
        decided = [s for s in steps if s.swing_start_s < crossing_t]
        reflexes = loop.stats.reflexes[n_reflex0:]
        return {
            "index": index,
            "success": not contacts and not stalled,
            "start_distance_m": near - x0,
            "obstacle_height_m": height,
            "reflexes": [
                {"kind": r.kind, "t_s": r.t_s - t0, "cause": r.cause, "swing": r.swing, "phase": r.phase}
                for r in reflexes
            ],
            "contacts": contacts,
            "stalled": stalled,
            "contact_misses": contact_misses(contacts, [r.t_s - t0 for r in reflexes],
                                             c.controller.reflexes.refractory_s),
            "footfalls_m": [x - near for _, x in before],
            "burst_s": [s.burst_s for s in steps if not math.isnan(s.burst_s)],
            "gated_range_m": [s.gated_range_m for s in decided],
            "gated_cells": [s.cell for s in decided],
            "gated_contexts": [s.context for s in decided],
            "modulation_s": [s.modulation_s for s in decided],
            "gated_decisions": sum(1 for s in decided if s.modulation_s != 0.0),
            "lift_steps": sum(1 for s in steps if s.amplitude > 1.0),
            "sim_s": ls.t_s - t0,
            **({"trace": trace} if trace is not None else {}),
        }

    def run(self, progress: bool = False, before_trial: Callable[[int], None] | None = None,
            after_trial: Callable[[int, dict[str, Any]], None] | None = None) -> list[dict[str, Any]]:
        """Bring the leg up and run every trial, appending each record to ``trials``.
        ``before_trial(i)`` and ``after_trial(i, record)``, if given, are called around trial ``i``
        (a tuning run reads the weights each trial began with there)."""
        self.bring_up()
        bar = None
        if progress:
            from tqdm import tqdm

            bar = tqdm(total=self.config.trials, unit="trial", desc="learn" if self.config.learning else "no-learning")
        successes = 0
        for i in range(self.config.trials):
            if before_trial is not None:
                before_trial(i)
            trial = self.trial(i)
            self.trials.append(trial)
            if after_trial is not None:
                after_trial(i, trial)
            successes += trial["success"]
            if bar is not None:
                bar.update(1)
                bar.set_postfix(success=f"{successes / (i + 1):.0%}")
        if bar is not None:
            bar.close()
        return self.trials

    def close(self) -> None:
        self.ls.close()


MISS_SLACK_S = 0.01
"""A reflex up to this long after a contact's end still heard it (the switch's frame, the next tick)."""


def contact_misses(contacts: list[list[float]], reflex_t_s: list[float], refractory_s: float) -> int:
    """How many episodes of obstacle contact (ground truth, ``[start, end]`` [s]) no contact reflex
    heard: none fired from ``refractory_s`` before the episode's start (a reflex still refractory
    from the same collision covers it) to :data:`MISS_SLACK_S` after its end. Every miss is a
    contact the learner never heard of. An episode is contact on consecutive physics steps
    (:meth:`firmware_sim.plant.RigPlant.obstacle_contact`, the ground truth of ``success``)."""
    return sum(1 for start, end in contacts
               if not any(start - refractory_s <= t <= end + MISS_SLACK_S for t in reflex_t_s))


def summarize(trials: list[dict[str, Any]], wall_s: float, sim_s: float) -> dict[str, Any]:
    n = len(trials)
    return {
        "trials": n,
        "success_rate": window_success(trials, 1, n),
        "success_1_20": window_success(trials, 1, 20),
        "success_21_40": window_success(trials, 21, 40),
        "mistakes_101_150": mistakes_101_150(trials),
        "reflexes": sum(len(t["reflexes"]) for t in trials),
        "contact_misses": sum(t.get("contact_misses", 0) for t in trials),
        "wall_s": wall_s,
        "sim_s": sim_s,
        "trials_per_minute": n / wall_s * 60.0 if wall_s > 0 else None,
    }


def _weights_of(premotor) -> np.ndarray | None:
    """The learned weights of a premotor that has them ((n_cells,) or (n_contexts, n_cells)), else None."""
    from controller.stepping.improved import ImprovedPremotor

    return premotor.weights if isinstance(premotor, (AdaptivePremotor, ContextPremotor, ImprovedPremotor)) else None


def run_learning(config: LearnConfig, out_dir: str | Path | None = None, progress: bool = False,
                 figures: bool = False, overwrite: bool = False) -> dict[str, Any]:
    """Run; with ``out_dir``, into that run folder (:func:`learn_into`: each trial written as it
    finishes, resumed where a stopped run left off); return the metrics."""
    if out_dir is not None:
        return learn_into(config, out_dir, progress=progress, figures=figures, overwrite=overwrite).metrics
    wall0 = time.perf_counter()
    run = LearningRun(config)
    try:
        trials = run.run(progress=progress)
        sim_s = run.ls.t_s
    finally:
        run.close()
    return {"config": dataclasses.asdict(config), "trials": trials,
            "summary": summarize(trials, time.perf_counter() - wall0, sim_s)}


# ---- the run folder ----------------------------------------------------------------------------------------------

METRICS_VERSION = 1
WEIGHTS_FILE = "weights.npz"
CHECKPOINT_EVERY = 10
"""The learned weights are saved every this many trials (and at the end)."""
WEIGHTS_METHODS_V0 = frozenset({"paper", "learner", "none", "context"})
"""The methods whose runs wrote ``weights.npz`` before ``metrics.json`` said so (version 0 files)."""


def is_run_file(name: str) -> bool:
    """Whether a name in a folder is one a learn run writes (what ``--overwrite`` may remove)."""
    return (name in (LOCK_FILE, TRIALS_FILE, METRICS_FILE, WEIGHTS_FILE, "figures")
            or name.startswith(WEIGHTS_FILE + ".")  # .prev, .prev2, temporaries, .incompatible-*
            or (name.startswith((f".{METRICS_FILE}.", f".{TRIALS_FILE}.")) and name.endswith(".tmp")))


ADDED_KEYS: dict[str, Any] = {"rail_speed_m_s": 0.5, "believed_rail_speed_m_s": 0.5}
"""Learn configuration keys added after runs were written, with the value every run written
before them had (issue 18's rail speeds): a folder without the key resumes if that is asked."""
CONDITION_OPTIONS = {"obstacle_height_m": "--obstacle-heights-m", "obstacle_heights_m": "--obstacle-heights-m",
                     "obstacle_depth_m": "--obstacle-depth-m", "range_noise_m": "--range-noise-m",
                     "range_dropout_prob": "--range-dropout", "start_min_m": "--start-m", "start_max_m": "--start-m",
                     "rail_speed_m_s": "--rail-speed-m-s", "believed_rail_speed_m_s": "--believed-rail-speed-m-s"}
"""The learn configuration's condition keys -> the option (and experiment key) that sets them."""


def config_difference(have: Any, want: Any, where: str = "") -> str | None:
    """The first key where the configuration ``have`` (read from a folder) differs from ``want``
    (both as JSON gives them), as ``key: X in the folder, Y asked``; None if they are equal. A
    top-level key of :data:`ADDED_KEYS` absent in the folder counts as its old value; an
    experimental condition's difference names its option (another experiment: a clear refusal)."""
    if isinstance(have, dict) and isinstance(want, dict):
        for key in [*want, *(k for k in have if k not in want)]:
            name = f"{where}.{key}" if where else str(key)
            if key not in have and not where and key in ADDED_KEYS and key in want \
                    and json.dumps(want[key]) == json.dumps(ADDED_KEYS[key]):
                continue
            if key not in have:
                return f"{name}: absent in the folder, {want[key]!r} asked"
            if not where and key in CONDITION_OPTIONS and key in want \
                    and json.dumps(have[key]) != json.dumps(want[key]):
                return (f"{name}: {have[key]!r} in the folder, {want[key]!r} asked: another experiment "
                        f"({CONDITION_OPTIONS[key]})")
            if key not in want:
                return f"{name}: {have[key]!r} in the folder, absent in this version's configuration"
            found = config_difference(have[key], want[key], name)
            if found:
                return found
        return None
    if json.dumps(have) == json.dumps(want):
        return None
    return f"{where or 'config'}: {have!r} in the folder, {want!r} asked"


def finished_problem(out: Path, metrics: dict[str, Any], trials: int) -> str | None:
    """Why a run folder whose ``metrics.json`` (``metrics``, stamp and structure already checked)
    names the right configuration is not a finished run of ``trials`` trials; None if it is.

    A finished run has every trial with its success flag and, if it learns weights (version 1:
    ``metrics.json``'s ``weights_file``; version 0: its method), a ``weights.npz`` that loads
    with its checksum verified (:func:`controller.stepping.weights.read_weights`)."""
    if len(metrics["trials"]) != trials:
        return f"{out / METRICS_FILE} holds {len(metrics['trials'])} trials, not {trials}"
    if "format" in metrics:
        weights = metrics.get("weights_file")
    else:
        weights = WEIGHTS_FILE if metrics["config"].get("method", CONTROLLER_METHOD) in WEIGHTS_METHODS_V0 else None
    if weights is not None:
        try:
            read_weights(out / str(weights))
        except WeightsError as exc:
            return f"its weights cannot be used: {exc}"
    return None


@dataclass(frozen=True)
class FolderState:
    """What a run folder holds for a configuration: ``kind`` ``"new"`` (nothing of a run),
    ``"finished"`` (``metrics``: a verified finished run of it) or ``"resume"`` (``journal``: an
    unfinished run of it)."""

    kind: str
    metrics: dict[str, Any] | None = None
    journal: Journal | None = None


def folder_state(out: Path, config: LearnConfig, what: str = "--out", overwrite: bool = False) -> FolderState:
    """What ``out`` (an existing folder) holds for ``config``; with ``overwrite``, a learn run's
    folder is cleared first (and is then ``"new"``).

    Same configuration means the same ``dataclasses.asdict(config)`` after a JSON round trip,
    every key, ``trials`` included (the last trial's trace, ``trace_trials`` -1, depends on it).

    Raises:
        InputError: the folder holds a run of another configuration, a damaged or unverifiable
            run, or files that are not a learn run's (never cleared, not even with ``overwrite``);
            the message names ``what``, the folder and the first differing key.
    """
    names = sorted(p.name for p in out.iterdir())
    if not [n for n in names if n != LOCK_FILE]:
        return FolderState("new")
    foreign = [n for n in names if not is_run_file(n)]
    if TRIALS_FILE not in names and METRICS_FILE not in names:
        shown = [n for n in names if n != LOCK_FILE]
        raise InputError(f"{what} {out}: holds files that are not a learn run's ({', '.join(shown[:3])}"
                         f"{', ...' if len(shown) > 3 else ''}); give an empty or new folder"
                         + ("; --overwrite clears only a learn run's folder" if overwrite else ""))
    if overwrite:
        if foreign:
            raise InputError(f"{what} {out}: also holds {', '.join(foreign[:3])}, which a learn run does not write; "
                             f"not clearing it: move it away or give another folder")
        for name in names:
            if name == LOCK_FILE:
                continue  # we hold it
            path = out / name
            shutil.rmtree(path) if path.is_dir() and not path.is_symlink() else path.unlink()
        fsync_dir(out)
        log.info("%s: cleared the learn run in %s (--overwrite)", what, out)
        return FolderState("new")
    want = json.loads(json.dumps(dataclasses.asdict(config)))
    again = "use another folder, or --overwrite to replace it"
    if METRICS_FILE in names:
        metrics = read_metrics(out / METRICS_FILE)
        diff = config_difference(metrics["config"], want)
        if diff:
            raise InputError(f"{what} {out}: holds a finished run of another configuration ({diff}); {again}")
        problem = finished_problem(out, metrics, config.trials)
        if problem:
            raise InputError(f"{what} {out}: holds a run of this configuration that does not verify ({problem}); "
                             f"{again}")
        return FolderState("finished", metrics=metrics)
    journal = read_journal(out / TRIALS_FILE)
    diff = config_difference(journal.config, want)
    if diff:
        raise InputError(f"{what} {out}: holds an unfinished run of another configuration ({diff}); {again}")
    if len(journal.records) > config.trials:
        raise InputError(f"{out / TRIALS_FILE}: holds {len(journal.records)} trials, more than its configuration's "
                         f"{config.trials}; {again}")
    return FolderState("resume", journal=journal)


class RunStopped(KeyboardInterrupt):
    """A run stopped by SIGINT (or SIGTERM, where the command line maps it): ``recorded`` of
    ``total`` trials are kept in ``folder``'s ``trials.jsonl``."""

    def __init__(self, recorded: int, total: int, folder: Path) -> None:
        super().__init__(f"stopped after {recorded} of {total} trials")
        self.recorded, self.total, self.folder = recorded, total, folder


class NotReproduced(InputError):
    """A resumed run's re-run of a kept trial gave another record (exit 3)."""


@dataclass(frozen=True)
class LearnOutcome:
    """What :func:`learn_into` did: ``status`` ``"ran"`` (a new run), ``"resumed"`` (``kept``
    trials were re-run, checked and continued) or ``"finished"`` (the folder already held this
    run: nothing ran); ``metrics`` as in ``metrics.json``."""

    metrics: dict[str, Any]
    status: str
    kept: int = 0


ADDED_TRIAL_KEYS = ("contacts", "contact_misses", "stalled")
"""Fields a trial record gained after runs were kept (issue 18): a kept record without them is
checked on the fields it has (its run resumes; the new trials carry them)."""


def _check_rerun(trial: dict[str, Any], kept: dict[str, Any], index: int, path: Path) -> None:
    """The re-run's record of trial ``index`` must be the kept one, bit for bit (as JSON), but for
    :data:`ADDED_TRIAL_KEYS` a kept record lacks."""
    trial = {k: v for k, v in trial.items() if k in kept or k not in ADDED_TRIAL_KEYS}
    if json.dumps(trial) == json.dumps(kept):
        return
    from hil.analysis.records import first_difference

    diff = first_difference(kept, json.loads(json.dumps(trial)), f"trial {index}") or f"trial {index}"
    raise NotReproduced(f"{path}: the run does not reproduce here: the re-run of kept trial {index} differs "
                        f"({diff}: kept vs re-run); its records were written by another version or machine; "
                        f"rerun with --overwrite to start over")


def learn_into(config: LearnConfig, out_dir: str | Path, *, progress: bool = False, figures: bool = False,
               overwrite: bool = False, what: str = "--out",
               run_class: Callable[[LearnConfig], LearningRun] | None = None, desc: str | None = None) -> LearnOutcome:
    """Run ``config`` into the run folder ``out_dir``, surviving stops.

    The folder is checked and locked before PyBullet starts (:func:`hil.experiments.journal.prepare_folder`,
    :class:`~hil.experiments.journal.FolderLock`; a second writer is refused). Then, by what it
    holds (:func:`folder_state`): nothing, a new run; a finished run of ``config``, nothing runs;
    an unfinished run of ``config``, it resumes: the kept trials are re-run deterministically from
    the start, each checked against its record (:class:`NotReproduced` if one differs), and the
    run continues from there. Each new trial is appended to ``trials.jsonl`` as it finishes; the
    weights are saved every :data:`CHECKPOINT_EVERY` trials and at the end (atomically, one
    generation: the trial record, not the weights, is what a resume starts from). At the end:
    ``weights.npz``, ``figures/`` (with ``figures``), then ``metrics.json`` last (its presence
    marks a finished run). ``run_class``: what runs the trials (default :class:`LearningRun`; the
    course's :class:`hil.experiments.course.CourseRun`); ``desc``: the progress bar's label.

    Raises:
        InputError: the folder (see :func:`folder_state`), a damaged trial record, a kept trial
            that does not reproduce.
        FolderBusy: another run writes the folder.
        RunStopped: SIGINT (a ``KeyboardInterrupt``) during the run; the finished trials are kept.
    """
    out = prepare_folder(out_dir, what)
    with FolderLock(out, f"{what} {out}"):
        state = folder_state(out, config, what, overwrite)
        if state.kind == "finished":
            return LearnOutcome(state.metrics, "finished", len(state.metrics["trials"]))
        kept = state.journal.records if state.journal is not None else []
        if kept:
            log.info("%s: resuming after %d of %d trials (re-running them first)", out, len(kept), config.trials)
        wall0 = time.perf_counter()
        run = writer = bar = None
        recorded = len(kept)
        try:
            if state.journal is not None:
                writer = JournalWriter(out / TRIALS_FILE, keep_bytes=state.journal.good_bytes)
            else:
                writer = JournalWriter.create(out / TRIALS_FILE, dataclasses.asdict(config))
            run = (run_class or LearningRun)(config)
            run.bring_up()
            if progress:
                from tqdm import tqdm

                desc = ((desc or ("learn" if config.learning else "no-learning"))
                        + (f" (re-run {len(kept)})" if kept else ""))
                bar = tqdm(total=config.trials, unit="trial", desc=desc)
            for i in range(config.trials):
                trial = run.trial(i)
                run.trials.append(trial)
                if i < len(kept):
                    _check_rerun(trial, kept[i], i, out / TRIALS_FILE)
                else:
                    writer.append(trial)
                    recorded = len(kept) + writer.appended
                    weights = _weights_of(run.premotor)
                    if weights is not None and recorded % CHECKPOINT_EVERY == 0 and recorded < config.trials:
                        save_weights(out / WEIGHTS_FILE, weights, config.controller.encoder.cell_width_m, generations=1)
                if bar is not None:
                    bar.update(1)
                    bar.set_postfix(success=f"{sum(t['success'] for t in run.trials) / (i + 1):.0%}")
            sim_s = run.ls.t_s
        except KeyboardInterrupt:  # a signal held during an append arrives once the record is durable
            raise RunStopped(len(kept) + (writer.appended if writer is not None else 0), config.trials, out) from None
        finally:
            if bar is not None:
                bar.close()
            if writer is not None:
                writer.close()
            if run is not None:
                run.close()
        trials = run.trials
        weights = _weights_of(run.premotor)
        metrics = {
            **stamp(METRICS_FORMAT, METRICS_VERSION),
            "config": dataclasses.asdict(config),
            "trials": trials,
            "summary": summarize(trials, time.perf_counter() - wall0, sim_s),
            "weights_file": None if weights is None else WEIGHTS_FILE,
        }
        try:
            if weights is not None:
                save_weights(out / WEIGHTS_FILE, weights, config.controller.encoder.cell_width_m, generations=1)
            if figures:
                write_figures(out, metrics, run.premotor)
            write_json_atomic(out / METRICS_FILE, metrics, indent=1)
        except KeyboardInterrupt:  # every trial is recorded: the next run re-runs them and writes the rest
            raise RunStopped(recorded, config.trials, out) from None
        return LearnOutcome(metrics, "resumed" if kept else "ran", len(kept))


def write_figures(out: Path, metrics: dict[str, Any], premotor) -> None:
    from hil.analysis import figures

    fig_dir = out / "figures"
    trials = metrics["trials"]
    figures.learning_curve(trials, fig_dir)
    controller = metrics["config"]["controller"]
    weights = _weights_of(premotor)
    if weights is not None and weights.ndim == 1:
        figures.weights_by_distance(weights, controller["encoder"]["cell_width_m"], fig_dir)
    elif weights is not None:  # a row of weights per height context
        figures.weights_by_context(weights, controller["encoder"]["cell_width_m"],
                                   controller["height"]["beam_heights_m"], fig_dir)
    late = last_window(len(trials))
    figures.footfall_spread(footfall_std_by_step([metrics], *late), fig_dir)


def one_or_mixed(heights: tuple[float, ...]) -> float | tuple[float, ...]:
    """:func:`learn_config`'s ``obstacle_height_m`` for a tool's list of heights: one height alone,
    several as a tuple, mixed per trial. A tuple of one would still draw each trial's height from
    the seeded generator, and so change every later start distance."""
    return heights if len(heights) > 1 else heights[0]


def learn_config(method: str, *, seed: int, trials: int, obstacle_height_m: float | tuple[float, ...],
                 conditions: Conditions | None = None, **overrides: Any) -> LearnConfig:
    """The learning run's configuration for ``method``; a tuple of heights mixes them per trial.
    ``conditions``: the run's other conditions (its heights are replaced by ``obstacle_height_m``,
    the sweep's cell); default the declared defaults."""
    m = get_method(method)
    heights = tuple(obstacle_height_m) if isinstance(obstacle_height_m, (tuple, list)) else ()
    height = heights[0] if heights else float(obstacle_height_m)
    fields = conditions.learn_fields() if conditions is not None else {}
    fields.update(obstacle_height_m=height, obstacle_heights_m=heights)
    return LearnConfig(trials=trials, seed=seed, learning=m.learns, method=m.name, **{**fields, **overrides})


def run_method(method: str, *, seed: int, trials: int, obstacle_height_m: float | tuple[float, ...],
               out_dir: str | Path | None = None, progress: bool = False, what: str = "--out",
               **overrides: Any) -> dict[str, Any]:
    """Run one sweep cell; the metrics have the format of ``elegant-stepping learn`` (with
    ``out_dir``, the folder is a learn run folder: :func:`learn_into`, never ``overwrite``)."""
    config = learn_config(method, seed=seed, trials=trials, obstacle_height_m=obstacle_height_m, **overrides)
    if out_dir is None:
        return run_learning(config, progress=progress)
    return learn_into(config, out_dir, progress=progress, what=what).metrics
