"""The premotor module's interface: what sets the CPG's burst length.

The learner of the Elegant Stepping model (:class:`controller.stepping.learner.AdaptivePremotor`)
implements it; so can any other stride policy (a baseline, a planner) that the loop should drive.
"""

from __future__ import annotations

from typing import Protocol


class Premotor(Protocol):
    def on_step_onset(self, now_s: float, cell: int | None, context: int | None = None) -> None:
        """The gate: called on the tick the CPG's step-onset signal fires, with the encoder's cell
        and the obstacle's height context (:mod:`controller.stepping.height`; None: unknown or no target).
        A premotor without contexts ignores it."""

    def burst_s(self, now_s: float) -> float:
        """The burst length [s] the CPG should use now (the CPG clips it to its safe bounds)."""

    def on_reflex(self, kind: str, now_s: float) -> None:
        """A contact reflex fired: ``"extension"`` or ``"placement"``."""

    def gated_weight(self) -> float:
        """The burst change [s] the last gate asked for (0: the gate changed nothing)."""
