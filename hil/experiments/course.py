"""The course: one long walk over many obstacles at random spacing, the controller learning throughout.

A course is a learning run (:mod:`hil.experiments.learn`) whose obstacles are laid out ahead of
time. The layout (:func:`course_layout`) is drawn from its own random generator, seeded by the
run's seed and nothing else, so every method walks the same course for a seed: the first
obstacle's near edge ``start_m`` ahead of the hip where the course starts, then each next one a
gap (far edge to near edge) drawn from ``gap_m`` behind the last, each with a height from
``heights_m`` and a depth from ``depths_m`` (uniform; heights and depths rounded to 0.1 mm, the
plant's obstacle models are named to that precision). The first ``k`` obstacles of a layout are the
same whatever the course's length.

:class:`CourseRun` is a :class:`~hil.experiments.learn.LearningRun` with the obstacles of the
layout in the world ahead of the leg: every obstacle whose near edge is within
:attr:`CourseRun.HORIZON_M` of where the current one's trial ends is placed, so the range sensor
(which reports the first hit along its ray: :meth:`firmware_sim.plant.RigPlant.range_m`) sees the
next obstacle while the current one is being crossed when they are close. Trial ``k`` is obstacle
``k``: it runs from the end of trial ``k - 1`` until the hip is ``past_obstacle_m`` past obstacle
``k``'s far edge, exactly :meth:`LearningRun.trial <hil.experiments.learn.LearningRun.trial>`
(its record, with the course's fields added: :data:`COURSE_FIELDS`); only the placing and removing
of obstacles (two hooks) and the rail's rewind differ. The oracle's ground truth is the nearest
obstacle ahead of the foot.

**The minimum gap** (:data:`GAP_FLOOR_M`, 0.6 m far edge to near edge; docs/course.md has the
measurement, :func:`gap_study`): below it the leg cannot recover from one obstacle before the
next. After the crossing swing lands the foot about 0.1 m past the far edge, at least one stance
and one stride (the shortest is 0.275 m) must come before the take-off footfall, which has to be
0.16-0.22 m before the next near edge: 0.55-0.6 m. Measured with the oracle (which knows every
distance: the leg's own ability, no learner's), fixed gaps, 20-30 blocks each: from 0.6 m on it
clears them all, 0.04-0.16 m high, but for a band about 0.75-0.8 m where its stride plan (not the
leg) fails on tall blocks; at 0.4-0.5 m it fails most, often striking the next block. And at
0.6 m a contact is also always the right trial's: a trial ends 0.45 m past the far edge and the
foot was never more than 0.13 m ahead of the hip there. A course refuses a smaller ``gap_m``.

A course folder ``DIR`` (:func:`course_into`) holds one learn run folder per method
(``DIR/<method>/``: ``trials.jsonl``, ``metrics.json``, ``weights.npz``; resumable exactly as
``learn``'s: :func:`hil.experiments.learn.learn_into`), ``course.json`` (the layout and each
method's summary) and ``figures/course.png`` / ``.svg``.
"""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Callable, ClassVar, Sequence

import numpy as np

from controller.errors import InputError, stamp

from hil.experiments.learn import LearnConfig, LearningRun

COURSE_SEED_SALT = 0x636F75727365
"""Mixed with the seed for the layout's generator (``"course"``): another stream than the run's own."""
GAP_FLOOR_M = 0.6
"""The smallest gap (far edge to near edge) a course allows [m]: see the module docstring."""
DEFAULT_GAP_M = (GAP_FLOOR_M, 3.0)
DEFAULT_HEIGHTS_M = (0.04, 0.12)
DEFAULT_DEPTHS_M = (0.05, 0.15)
DEFAULT_METHODS = ("paper", "improved", "none", "oracle")
GAP_MAX_M = 20.0
HEIGHT_MIN_M = 0.03  # the range sensor sees only what is taller (conditions.SENSOR_FLOOR_M)
DEPTH_RANGE_M = (0.01, 0.30)  # as the learn conditions' obstacle_depth_m
COURSE_FIELDS = ("obstacle_depth_m", "course_near_m", "gap_m", "walked_m")
"""What a course trial's record adds to a learn trial's: the obstacle's depth [m], its near edge
from where the course started [m], its gap from the previous far edge [m] (None for the first) and
the distance the hip has walked from the course's start when the trial ends [m]."""
COURSE_FILE = "course.json"
COURSE_FORMAT = "course"
COURSE_VERSION = 1


@dataclass(frozen=True)
class CourseObstacle:
    """One obstacle of a layout: ``near_m`` is its near edge ahead of the hip where the course
    starts [m]; ``gap_m`` from the previous one's far edge (None for the first)."""

    index: int
    near_m: float
    height_m: float
    depth_m: float
    gap_m: float | None


def _pair(name: str, value: Sequence[float], low: float, high: float, low_open: bool = False) -> tuple[float, float]:
    """``value`` as a (MIN, MAX) pair within [low, high] (``low`` excluded with ``low_open``); else ValueError."""
    try:
        pair = tuple(float(v) for v in value)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: {value!r} is not MIN,MAX (two numbers)") from None
    if len(pair) != 2 or not all(math.isfinite(v) for v in pair):
        raise ValueError(f"{name}: {value!r} is not MIN,MAX (two finite numbers)")
    lo, hi = pair
    if lo > hi:
        raise ValueError(f"{name}: MIN must not exceed MAX ({lo:g} > {hi:g})")
    if (lo <= low if low_open else lo < low) or hi > high:
        raise ValueError(f"{name}: {lo:g},{hi:g} m is outside {'(' if low_open else '['}{low:g}, {high:g}] m")
    return lo, hi


@dataclass(frozen=True)
class CourseConfig(LearnConfig):
    """A course: a :class:`~hil.experiments.learn.LearnConfig` (``trials`` is the number of
    obstacles, ``start_min_m``/``start_max_m`` the first one's near edge ahead of the hip) and the
    layout's ranges, each (MIN, MAX), uniform:

    Attributes:
        gap_m: far edge to the next near edge [m]; default (0.6, 3.0); MIN at least
            :attr:`GAP_FLOOR_M`.
        heights_m: obstacle heights [m]; default (0.04, 0.12); above 0.03 m (the range sensor's
            floor) and the tallest within the leg's limit for the deepest block
            (:func:`hil.experiments.conditions.check_leg_limit`).
        depths_m: obstacle depths along the rail [m]; default (0.05, 0.15); within [0.01, 0.30].

    ``obstacle_height_m`` and ``obstacle_depth_m`` are set to the tallest and deepest the layout
    may draw (what the learn configuration's own leg-limit check then checks); ``obstacle_heights_m``
    is empty.
    """

    gap_m: tuple[float, float] = DEFAULT_GAP_M
    heights_m: tuple[float, float] = DEFAULT_HEIGHTS_M
    depths_m: tuple[float, float] = DEFAULT_DEPTHS_M
    GAP_FLOOR_M: ClassVar[float] = GAP_FLOOR_M

    def __post_init__(self) -> None:
        floor = type(self).GAP_FLOOR_M
        gap = _pair("gap_m", self.gap_m, 0.0, GAP_MAX_M)
        if gap[0] < floor:
            raise ValueError(f"gap_m: MIN {gap[0]:g} m is below {floor:g} m, the closest spacing the leg recovers "
                             f"from (docs/course.md)")
        heights = _pair("heights_m", self.heights_m, HEIGHT_MIN_M, 0.5, low_open=True)
        depths = _pair("depths_m", self.depths_m, *DEPTH_RANGE_M)
        for name, value in (("gap_m", gap), ("heights_m", heights), ("depths_m", depths)):
            object.__setattr__(self, name, value)
        from hil.experiments.conditions import check_leg_limit

        speed = self.believed_rail_speed_m_s if self.believed_rail_speed_m_s is not None else self.rail_speed_m_s
        controller = replace(self.controller, gait=replace(self.controller.gait, ground_speed_m_s=speed))
        check_leg_limit((heights[1],), depths[1], controller, f"heights_m: the tallest, {heights[1]:g} m, for the "
                                                              f"deepest block, {depths[1]:g} m")
        object.__setattr__(self, "obstacle_height_m", heights[1])
        object.__setattr__(self, "obstacle_heights_m", ())
        object.__setattr__(self, "obstacle_depth_m", depths[1])
        super().__post_init__()


def course_layout(config: CourseConfig) -> list[CourseObstacle]:
    """The course's ``config.trials`` obstacles, drawn from a generator seeded by ``config.seed``
    alone (every method, every length: the same course). Per obstacle, in this order: the first's
    start distance or the gap, the height, the depth."""
    rng = np.random.default_rng([COURSE_SEED_SALT, config.seed])
    out: list[CourseObstacle] = []
    near = 0.0
    for k in range(config.trials):
        if k == 0:
            gap = None
            near = float(rng.uniform(config.start_min_m, config.start_max_m))
        else:
            gap = float(rng.uniform(*config.gap_m))
            near = out[-1].near_m + out[-1].depth_m + gap
        height = round(float(rng.uniform(*config.heights_m)), 4)
        depth = round(float(rng.uniform(*config.depths_m)), 4)
        out.append(CourseObstacle(k, near, height, depth, gap))
    return out


class CourseRun(LearningRun):
    """A learning run over the course's layout (see the module docstring)."""

    HORIZON_M = 3.7
    """Obstacles are placed up to this far ahead of where the current trial ends [m]: the range
    sensor's origin (0.2 m ahead of the hip) plus its 3 m reach, and 0.5 m to spare."""
    REWIND_CLEAR_M = 0.7
    """The rail is rewound (:attr:`REWIND_AFTER_M`) only at a trial's start, and then at once if
    the foot is in the air, else with the next obstacle at least this far ahead of the hip: while
    it waits for the foot to lift (at most a stance, 0.2 m of rail) the leg, reaching at most about
    0.15 m ahead of the hip, cannot touch the obstacle unwatched."""
    GROUND_LIMIT_M = 380.0

    def __init__(self, config: CourseConfig, premotor=None, **kwargs: Any) -> None:
        self.layout = course_layout(config)
        self._origin_m = 0.0  # world x of the course's 0 (the hip where it started), less the rewinds
        self._placed: list[CourseObstacle] = []  # in the world now, nearest first
        self._next = 0  # the next layout index to place
        self._current = 0  # the obstacle of the next (or running) trial
        super().__init__(config, premotor, **kwargs)

    def bring_up(self, timeout_s: float = 10.0) -> None:
        super().bring_up(timeout_s)
        self._origin_m = self.ls.plant.carriage_x_m

    def _world(self, o: CourseObstacle) -> float:
        return self._origin_m + o.near_m

    def _add(self, o: CourseObstacle) -> None:
        from firmware_sim.plant import Obstacle

        self.ls.plant.add_obstacle(Obstacle(self._world(o), o.height_m, o.depth_m))

    def _place_obstacle(self, x0: float) -> tuple[float, float, float]:
        o = self.layout[self._current]
        reach = self._world(o) + o.depth_m + self.config.past_obstacle_m + self.HORIZON_M
        while self._next < len(self.layout) and (self._next <= o.index or self._world(self.layout[self._next]) < reach):
            nxt = self.layout[self._next]
            self._add(nxt)
            self._placed.append(nxt)
            self._next += 1
        return self._world(o), o.height_m, o.depth_m

    def _reload(self) -> None:
        plant = self.ls.plant
        plant.clear_obstacles()
        for o in self._placed:
            self._add(o)

    def _remove_obstacle(self) -> None:
        self._current += 1
        self._placed = [o for o in self._placed if o.index >= self._current]
        self._reload()

    def _rewind_if_far(self) -> None:
        """Past :attr:`REWIND_AFTER_M`, at a trial's start with the foot in the air or the next
        obstacle at least :attr:`REWIND_CLEAR_M` ahead (wait for the foot to lift): take the
        obstacles away, move the rig back and put them back where they were relative to it."""
        plant = self.ls.plant
        x = plant.carriage_x_m
        if x < self.REWIND_AFTER_M:
            return
        if not self._foot_in_air() and self._placed and self._world(self._placed[0]) - x < self.REWIND_CLEAR_M:
            if x > self.GROUND_LIMIT_M:
                raise RuntimeError(f"the course ran {x:.0f} m without a moment to rewind the rail in")
            return  # at a later trial's start
        self._wait_foot_in_air()
        plant.clear_obstacles()
        plant.rewind_rail(self.REWIND_AFTER_M)
        self._origin_m -= self.REWIND_AFTER_M
        self._reload()

    def _ahead_of_foot(self) -> tuple[CourseObstacle, float] | None:
        """The nearest obstacle whose near edge is ahead of the foot, and that distance [m]."""
        fx = self.ls.plant.foot_position()[0]
        for o in self._placed:
            d = self._world(o) - fx
            if d > 0.0:
                return o, d
        return None

    def _true_distance_m(self) -> float | None:
        ahead = self._ahead_of_foot()
        return None if ahead is None else ahead[1]

    def _true_height_m(self) -> float | None:
        ahead = self._ahead_of_foot()
        return None if ahead is None else ahead[0].height_m

    def trial(self, index: int, on_step: Callable | None = None) -> dict[str, Any]:
        if index != self._current:
            raise ValueError(f"a course runs its obstacles in order: trial {index} asked, "
                             f"obstacle {self._current} next")
        o = self.layout[index]
        record = super().trial(index, on_step)
        record.update(obstacle_depth_m=o.depth_m, course_near_m=o.near_m, gap_m=o.gap_m,
                      walked_m=self.ls.plant.carriage_x_m - self._origin_m)
        return record


# ---- the course folder ----------------------------------------------------------------------------------------------


def method_config(base: CourseConfig, method: str) -> CourseConfig:
    """``base`` for ``method`` (a registry name), learning as the method does."""
    from hil.experiments.methods import get

    return replace(base, method=method, learning=get(method).learns)


def rolling_success(trials: Sequence[dict[str, Any]], window: int) -> list[float]:
    """Success over the last ``window`` obstacles (fewer at the start: all so far), per obstacle
    (:func:`hil.analysis.stats.running_success` of the records' ``success``)."""
    from hil.analysis.stats import running_success

    return running_success([bool(t["success"]) for t in trials], window)


def course_summary(trials: Sequence[dict[str, Any]], window: int) -> dict[str, Any]:
    """A method's course in numbers: successes overall, in the first and the last ``window``
    obstacles, and the distance walked [m]."""
    n = len(trials)
    ok = [bool(t["success"]) for t in trials]
    w = min(window, n)
    return {
        "obstacles": n,
        "success_rate": sum(ok) / n if n else None,
        "success_first": sum(ok[:w]) / w if w else None,
        "success_last": sum(ok[-w:]) / w if w else None,
        "window": w,
        "walked_m": trials[-1]["walked_m"] if n else 0.0,
        "stalled": sum(1 for t in trials if t.get("stalled")),
        "reflexes": sum(len(t["reflexes"]) for t in trials),
    }


_TOP_NAMES = (COURSE_FILE, "figures", ".lock")


def _check_top(out: Path, methods: Sequence[str]) -> None:
    """A course folder holds only its method folders, ``course.json``, ``figures/`` and its lock."""
    from hil.experiments.methods import METHODS

    foreign = sorted(p.name for p in out.iterdir() if p.name not in _TOP_NAMES and p.name not in METHODS)
    if foreign:
        raise InputError(f"--out {out}: holds files that are not a course's ({', '.join(foreign[:3])}"
                         f"{', ...' if len(foreign) > 3 else ''}); give an empty or new folder (never cleared, "
                         f"not even with --overwrite)")


def course_into(base: CourseConfig, methods: Sequence[str], out_dir: str | Path, *, progress: bool = False,
                overwrite: bool = False, window: int = 20, figure: bool = True,
                on_method: Callable[[str, Any], None] | None = None) -> dict[str, Any]:
    """Walk ``base``'s course with each of ``methods`` into ``out_dir`` (see the module
    docstring), each method's run resumable as ``learn``'s; then ``course.json`` and the figure.
    ``on_method(method, outcome)`` is called after each method's run. Returns ``course.json``'s content.

    Raises:
        InputError: the folder (foreign files; a method folder of another configuration, as
            :func:`~hil.experiments.learn.folder_state` says), a kept trial that does not reproduce.
        RunStopped: SIGINT; every finished obstacle is kept.
    """
    from hil.experiments.journal import FolderLock, prepare_folder
    from hil.experiments.learn import learn_into

    out = prepare_folder(out_dir, "--out")
    results: dict[str, Any] = {}
    with FolderLock(out, f"--out {out}"):
        _check_top(out, methods)
        for m in methods:
            config = method_config(base, m)
            outcome = learn_into(config, out / m, progress=progress, overwrite=overwrite, what="--out",
                                 run_class=CourseRun, desc=f"course {m}")
            results[m] = outcome.metrics["trials"]
            if on_method is not None:
                on_method(m, outcome)
        layout = course_layout(base)
        course = {
            **stamp(COURSE_FORMAT, COURSE_VERSION),
            "seed": base.seed,
            "methods": list(methods),
            "window": window,
            "config": {k: v for k, v in json.loads(json.dumps(dataclasses.asdict(base))).items()
                       if k not in ("method", "learning", "controller")},
            "layout": [dataclasses.asdict(o) for o in layout],
            "summary": {m: course_summary(results[m], window) for m in methods},
        }
        from controller.atomic import write_json_atomic

        if figure:
            from hil.analysis.course_figures import success_by_distance

            success_by_distance(results, out / "figures", window=window, layout=layout)
        write_json_atomic(out / COURSE_FILE, course, indent=1)
    return course


# ---- the minimum gap: how it was measured ---------------------------------------------------------------------------


class _AnyGap(CourseConfig):
    """A course configuration without the gap floor: for :func:`gap_study` only."""

    GAP_FLOOR_M = 0.0


def gap_study(gaps: Sequence[float], heights: Sequence[float], *, depth_m: float = 0.15, obstacles: int = 30,
              seed: int = 5, method: str = "oracle") -> list[dict[str, Any]]:
    """For each height and gap, a course of ``obstacles`` identical blocks (``depth_m`` deep) at that
    fixed gap, walked by ``method`` (the oracle: the leg's own ability, with the distance known):
    its successes, stalls, the trials with contact on an obstacle other than the trial's own (a
    contact the records would give to the wrong obstacle), and how far ahead of the hip the foot
    ever was [m]. The minimum gap (:data:`GAP_FLOOR_M`) is read from it (docs/course.md)."""
    rows = []
    for h in heights:
        for g in gaps:
            config = _AnyGap(trials=obstacles, seed=seed, method=method, gap_m=(g, g), heights_m=(h, h),
                             depths_m=(depth_m, depth_m))
            run = CourseRun(config)
            plant = run.ls.plant
            seen = {"ahead": 0.0, "foreign": 0}
            try:
                run.bring_up()
                for i in range(obstacles):
                    foreign = [False]

                    def watch(ls, i=i, foreign=foreign):
                        seen["ahead"] = max(seen["ahead"], plant.foot_position()[0] - plant.carriage_x_m)
                        if foreign[0] or len(plant.obstacles) < 2:
                            return
                        own = run._world(run.layout[i])
                        others = {b for b, o in plant._obstacles if abs(o.near_edge_x_m - own) > 1e-9}
                        foreign[0] = any(c[2] in others for c in plant._p.getContactPoints(plant.robot))

                    run.trials.append(run.trial(i, on_step=watch))
                    seen["foreign"] += foreign[0]
            finally:
                run.close()
            rows.append({"height_m": h, "gap_m": g, "obstacles": obstacles,
                         "successes": sum(t["success"] for t in run.trials),
                         "stalled": sum(t["stalled"] for t in run.trials), "foreign_contacts": seen["foreign"],
                         "foot_ahead_max_m": round(seen["ahead"], 3)})
    return rows


def _main(argv: Sequence[str] | None = None) -> int:
    """``python -m hil.experiments.course --gaps 0.3,0.6 --heights 0.12``: the gap study as a table."""
    import argparse

    p = argparse.ArgumentParser(description=gap_study.__doc__)
    floats = lambda text: [float(v) for v in text.split(",")]  # noqa: E731
    p.add_argument("--gaps", type=floats, default=[0.4, 0.5, 0.6, 0.7, 0.8, 1.0, 3.0])
    p.add_argument("--heights", type=floats, default=[0.04, 0.08, 0.12, 0.16])
    p.add_argument("--depth-m", type=float, default=0.10)
    p.add_argument("--obstacles", type=int, default=30)
    p.add_argument("--seed", type=int, default=5)
    p.add_argument("--method", default="oracle")
    a = p.parse_args(argv)
    print("| method | height [m] | gap [m] | cleared | stalled | contact on the next obstacle "
          "| foot ahead of hip, max [m] |")
    print("|---|---|---|---|---|---|---|")
    for r in gap_study(a.gaps, a.heights, depth_m=a.depth_m, obstacles=a.obstacles, seed=a.seed, method=a.method):
        print(f"| {a.method} | {r['height_m']:g} | {r['gap_m']:g} | {r['successes']}/{r['obstacles']} | {r['stalled']} "
              f"| {r['foreign_contacts']} | {r['foot_ahead_max_m']:.3f} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(_main())


__all__ = ["COURSE_FIELDS", "CourseConfig", "CourseObstacle", "CourseRun", "DEFAULT_DEPTHS_M", "DEFAULT_GAP_M",
           "DEFAULT_HEIGHTS_M", "DEFAULT_METHODS", "GAP_FLOOR_M", "course_into", "course_layout", "course_summary",
           "method_config", "rolling_success"]
