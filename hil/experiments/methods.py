"""The method registry: every method a learning run or a sweep can use, and the only place one is added.

Each method runs through the same plant, bus and controller loop; what differs is the premotor
module that sets the CPG's burst length:

- ``paper``: the Elegant Stepping model (reflex-trained weights on gated range cells): the
  controller's own premotor.
- ``context``: the paper's learner with the obstacle height as context (see
  :mod:`controller.stepping.context`).
- ``none``: no adaptation (the weights stay at zero: the CPG's natural stride).
- ``oracle``: a geometric planner that knows the exact distance (see :mod:`hil.experiments.oracle`).
- ``rl``: reinforcement learning on the same gated encoder (see :mod:`controller.stepping.rl`).
- ``improved``: the paper's learner with height context, credit over neighbouring cells, a
  falling learning rate and the lift learned per context (see :mod:`controller.stepping.improved`).

``learn`` runs :data:`DEFAULT_METHOD` (``improved``) unless told; a :class:`LearnConfig` that
names no method, and so the HIL sessions, benchmarks and fault matrix, runs
:data:`CONTROLLER_METHOD` (``paper``), the learner the daemon deploys.

To add a method, add one :class:`Method` to :data:`REGISTRY`; ``learn --method``, ``sweep
--methods``, the sweep's report and the figures' legends all read it from here.

This module imports nothing heavy at module level (no simulation, no pybullet): parsing and
validating method names is cheap. The builders import what they need when called.

It imports no experiment: the learning run (:mod:`hil.experiments.learn`, which also has
:func:`~hil.experiments.learn.run_method` for one sweep cell) reads it.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, Callable, Optional

from controller.config import ControllerConfig

Truth = Callable[[], Optional[float]]
PremotorBuilder = Callable[[ControllerConfig, bool, int, Truth, Truth], Any]
"""``build(controller, learning, seed, truth, height)``: the premotor of a run, or None for the controller's own."""


def _controller_default(controller: ControllerConfig, learning: bool, seed: int, truth: Truth,
                        height: Truth) -> None:
    """None: the controller's own premotor (:class:`controller.stepping.learner.AdaptivePremotor`),
    learning or frozen as ``learning`` says."""
    return None


def _oracle(controller: ControllerConfig, learning: bool, seed: int, truth: Truth, height: Truth):
    from hil.experiments.oracle import OraclePremotor

    return OraclePremotor(controller, truth, height=height)


def _rl(controller: ControllerConfig, learning: bool, seed: int, truth: Truth, height: Truth):
    from controller.stepping.rl import QLearnerConfig, QLearningPremotor

    return QLearningPremotor(controller.encoder.n_cells, controller.cpg.burst_s, QLearnerConfig(seed=seed))


def _context(controller: ControllerConfig, learning: bool, seed: int, truth: Truth, height: Truth):
    from controller.stepping.context import ContextPremotor

    learner = controller.learner if learning else replace(controller.learner, learning=False)
    return ContextPremotor(controller.height.n_contexts, controller.encoder.n_cells, controller.cpg.burst_s, learner)


def lift_max(controller: ControllerConfig) -> float:
    """The highest lift amplitude the leg allows (:func:`controller.motion.reach.max_lift_amplitude`)."""
    from controller.motion.reach import max_lift_amplitude

    return max_lift_amplitude(geometry=controller.geometry, axes=controller.axes, cpg=controller.cpg,
                              gait=controller.gait)


def build_improved(controller: ControllerConfig, learning: bool = True, **settings):
    """The improved learner for this controller: its lift settings from the controller's reflexes,
    its highest lift from the leg (:func:`lift_max`), the gait's tuck and its longest burst
    (``longest_burst_s``, rule 24; 0: the CPG's) for a tucked swing, the ground speed the gait
    believes; ``settings``: other :class:`controller.stepping.improved.ImprovedConfig` settings
    (tuning). A ValueError names a setting the controller's gait cannot follow."""
    from functools import partial

    from controller.motion.gait import tuck_fraction
    from controller.stepping.improved import ImprovedConfig, ImprovedPremotor

    config = ImprovedConfig(**{"learning": learning, "lift_amplitude": controller.reflexes.lift_amplitude,
                               "lift_range_m": controller.reflexes.lift_range_m, "lift_max": lift_max(controller),
                               **settings})
    # rule 18's phase must be one the gait's tucked path takes (FootTrajectory.tucked keeps its own
    # descent for any other): refused here, where both are known, rather than ignored in the swing
    descend, rise = config.lifting_descend_phase, controller.gait.tuck_rise_phase
    if descend > 0.0 and not rise < descend:
        raise ValueError(f"improved.lifting_descend_phase must be 0 (the gait's descent) or after "
                         f"gait.tuck_rise_phase = {rise}, got {descend!r}")
    cpg = controller.cpg
    # rule 24: the tucked swing takes the learner's own longest burst (the loop lets the CPG give it;
    # the premotor refuses one shorter than the base burst), or the CPG's
    longest_s = config.longest_burst_s if config.longest_burst_s > 0.0 else cpg.burst_max_s
    return ImprovedPremotor(controller.height.n_contexts, controller.encoder.n_cells, cpg.burst_s, config,
                            tuck=partial(tuck_fraction, controller.gait), tucked_extra_s=longest_s - cpg.burst_s,
                            ground_speed_m_s=controller.gait.ground_speed_m_s,
                            cell_width_m=controller.encoder.cell_width_m)


def _improved(controller: ControllerConfig, learning: bool, seed: int, truth: Truth, height: Truth):
    return build_improved(controller, learning)


@dataclass(frozen=True)
class Method:
    """One method.

    Attributes:
        name: the registry name (``learn --method``, ``sweep --methods``, cell folder names).
        label: how the sweep's report names it in a sentence.
        learns: whether its runs learn (False: ``LearnConfig.learning`` is False in a sweep).
        sentence: what the sweep report's headline says of it: ``"criterion"`` (trials to
            criterion and mistakes after trial 100), ``"success"`` (its success rate), or None.
        build: ``build(controller, learning, seed, truth, height)`` returns the premotor module of
            a run (its controller configuration, whether it learns, its seed), or None for the
            controller's own. ``truth()`` is the true distance from the foot to the obstacle's
            near edge [m], ``height()`` the obstacle's true height [m] (None with no obstacle):
            ground truth only the oracle uses.
    """

    name: str
    label: str
    learns: bool
    build: PremotorBuilder
    sentence: str | None = "criterion"


REGISTRY: dict[str, Method] = {m.name: m for m in (
    Method("paper", "The learner (Elegant Stepping)", True, _controller_default),
    Method("context", "The context learner", True, _context, sentence=None),
    Method("none", "Without adaptation (none), the leg", False, _controller_default),
    Method("oracle", "The oracle", True, _oracle, sentence="success"),
    Method("rl", "Reinforcement learning (rl)", True, _rl),
    Method("improved", "The improved learner", True, _improved),
)}
METHODS: tuple[str, ...] = tuple(REGISTRY)  # the names, e.g. for argparse ``choices``
DEFAULT_METHOD = "improved"
"""What ``learn`` runs unless ``--method`` names another: the improved learner. It is the default
because it won issue 18's comparison with the paper's learner on the held-out seeds 1000-1019
(docs/improved.md, "Held-out"); ``--method paper`` runs the reproduction."""
CONTROLLER_METHOD = "paper"
"""The controller's own learner, the one the daemon deploys (its weights file is the daemon's):
:class:`~hil.experiments.learn.LearnConfig`'s default, so that whatever runs a learning loop
without naming a method (HIL sessions, benchmarks, the fault matrix) runs the deployed product;
and the method of a run folder that names none (made before methods were registered)."""
DEFAULT_SWEEP_METHODS: tuple[str, ...] = ("improved", "paper", "none", "oracle", "rl")

# Older sweep folders and learn output folders name the paper's learner "learner" (in
# config.json, summary.json, the cells' folder names and metrics.json). Only reading them
# resolves this alias (:func:`resolve`); new runs and sweeps take registry names only.
ALIASES: dict[str, str] = {"learner": "paper"}


def get(name: str) -> Method:
    """The method registered as ``name`` (registry names only)."""
    try:
        return REGISTRY[name]
    except KeyError:
        raise ValueError(f"unknown method {name!r}; choose from {', '.join(METHODS)}") from None


def resolve(name: str) -> Method:
    """The method of a name read from an existing output folder: a registry name or an old alias."""
    return get(ALIASES.get(name, name))
