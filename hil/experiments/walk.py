"""The walking experiment: flat ground, a fixed burst length, measured through the whole stack.

:func:`run_walk`'s metrics (``elegant-stepping walk --json``) carry the stamp ``format: "walk"``,
``format_version`` :data:`WALK_VERSION` and ``project_version`` first
(:func:`controller.errors.stamp`); they are not records of the walk (``compare`` leaves them out).
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import replace
from typing import Any, Callable

from controller.config import ControllerConfig
from controller.errors import stamp
from controller.supervisor import Phase
from hil.lockstep.groundtruth import FootfallTracker
from hil.lockstep.harness import Lockstep, LockstepConfig

log = logging.getLogger(__name__)

WALK_KIND = "walk"
WALK_VERSION = 1  # the walk metrics' format version: raise it when a reader of the old one could misread it


def walk_config(seed: int = 0, burst_s: float | None = None) -> LockstepConfig:
    ctl = ControllerConfig()
    if burst_s is not None:
        ctl = replace(ctl, cpg=replace(ctl.cpg, burst_s=burst_s))
    return LockstepConfig(seed=seed, controller=ctl)


def run_walk(seconds: float, seed: int = 0, burst_s: float | None = None, *, progress: bool = False,
             config: LockstepConfig | None = None,
             harness: Callable[..., Lockstep] = Lockstep) -> dict[str, Any]:
    """Walk for ``seconds`` of simulated time and return the metrics (see ``elegant-stepping walk``),
    stamped (:data:`WALK_KIND`, :data:`WALK_VERSION`). ``harness``: what builds the lockstep from
    the configuration (default :class:`Lockstep`; ``walk --gui`` passes
    :func:`hil.experiments.gui.watched_harness`, a window on the same run)."""
    cfg = config or walk_config(seed, burst_s)
    from firmware_sim.plant import RigPlant

    if seconds * cfg.rig.rail_speed_m_s > RigPlant.GROUND_END_X_M - 1.0:
        raise ValueError(f"a {seconds} s walk at {cfg.rig.rail_speed_m_s} m/s would run off the "
                         f"{RigPlant.GROUND_END_X_M:.0f} m of ground; walk for less time")
    wall0 = time.perf_counter()
    with harness(cfg) as ls:
        tracker = FootfallTracker(ls.plant)
        n_steps = int(round(seconds * cfg.rig.physics_hz))
        bar = None
        if progress:
            from tqdm import tqdm

            bar = tqdm(total=n_steps, unit="step", unit_scale=True, desc="walk", leave=False)
        walking = False
        for i in range(n_steps):
            ls.step()
            walking = walking or ls.loop.phase is Phase.WALK
            if walking:
                tracker.update()
            if bar is not None and i % 1000 == 999:
                bar.update(1000)
        if bar is not None:
            bar.close()
        wall_s = time.perf_counter() - wall0
        return {**stamp(WALK_KIND, WALK_VERSION), **collect_metrics(ls, tracker, wall_s)}


def collect_metrics(ls: Lockstep, tracker: FootfallTracker, wall_s: float) -> dict[str, Any]:
    loop = ls.loop
    footfalls = tracker.footfalls_x_m
    strides = [b - a for a, b in zip(footfalls, footfalls[1:])]
    bursts = [s.burst_s for s in loop.stats.steps if not math.isnan(s.burst_s)]
    clearance = tracker.swing_clearance_m
    return {
        "steps": len(footfalls),
        "footfalls_m": footfalls,
        "stride_m": strides,
        "mean_stride_m": sum(strides) / len(strides) if strides else None,
        "burst_s": bursts,
        "swing_clearance_min_m": min(clearance) if clearance else None,
        "commands_outside_limits": sum(a.targets_outside_limits for a in ls.leg.axes.values()),
        "targets_clamped_by_controller": sum(a.clamped_targets for a in loop.axes),
        "frames_tx": dict(sorted(loop.io.tx.items())),
        "frames_rx": dict(sorted(loop.io.rx.items())),
        "frames_dropped": dict(sorted(loop.io.dropped.items())),
        "ticks": loop.stats.ticks,
        "command_ticks": loop.stats.command_ticks,
        "late_ticks": loop.stats.late_ticks,
        "phase": loop.phase.value,
        "fault_cause": loop.supervisor.fault_cause,
        "sim_s": ls.t_s,
        "wall_s": wall_s,
    }
