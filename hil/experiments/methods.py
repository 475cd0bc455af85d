"""The methods a sweep compares, each run through the same plant, bus and controller loop.

- ``learner``: the Elegant Stepping model (reflex-trained weights on gated range cells).
- ``none``: no adaptation (the weights stay at zero: the CPG's natural stride).
- ``oracle``: a geometric planner that knows the exact distance (see :mod:`hil.experiments.oracle`).
- ``rl``: reinforcement learning on the same gated encoder (see :mod:`controller.stepping.rl`).
- ``context``: the learner with the obstacle height as context (see :mod:`controller.stepping.context`).

:func:`run_method` runs one (method, obstacle height, seed) cell and returns the same metrics as
``elegant-stepping learn`` (``config``, ``trials``, ``summary``), written to ``out_dir`` if given.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from hil.experiments.learn import LearnConfig, run_learning

METHODS = ("learner", "none", "oracle", "rl", "context")


def learn_config(method: str, *, seed: int, trials: int, obstacle_height_m: float | tuple[float, ...],
                 **overrides: Any) -> LearnConfig:
    """The learning run's configuration for ``method``; a tuple of heights mixes them per trial."""
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; choose from {', '.join(METHODS)}")
    heights = tuple(obstacle_height_m) if isinstance(obstacle_height_m, (tuple, list)) else ()
    height = heights[0] if heights else float(obstacle_height_m)
    return LearnConfig(trials=trials, seed=seed, obstacle_height_m=height, obstacle_heights_m=heights,
                       learning=method != "none", method=method, **overrides)


def run_method(method: str, *, seed: int, trials: int, obstacle_height_m: float | tuple[float, ...],
               out_dir: str | Path | None = None, progress: bool = False, **overrides: Any) -> dict[str, Any]:
    """Run one sweep cell; the metrics have the format of ``elegant-stepping learn``."""
    config = learn_config(method, seed=seed, trials=trials, obstacle_height_m=obstacle_height_m, **overrides)
    return run_learning(config, out_dir=out_dir, progress=progress)
