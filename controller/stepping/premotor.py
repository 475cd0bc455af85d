"""The premotor module's interface: what sets the CPG's burst length.

The learner of the Elegant Stepping model (:class:`controller.stepping.learner.AdaptivePremotor`)
implements it; so can any other stride policy (a baseline, a planner) that the loop should drive.

The loop also looks, once when it is built, for optional attributes: the lift's two methods
(:class:`LiftingPremotor`), and ``longest_burst_s``, a float [s] with which a premotor asks the
CPG to clip its bursts there instead of at the configured ``cpg.burst_max_s`` (the improved
learner's longer crossing, :mod:`controller.stepping.improved` rule 24). The controller's own
premotor has none of them, so the deployed leg keeps its configured bound.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol

if TYPE_CHECKING:
    from controller.stepping.reflexes import Reflex


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


class LiftingPremotor(Premotor, Protocol):
    """A premotor that also learns the lift (:class:`controller.stepping.improved.ImprovedPremotor`).

    The loop looks for these two methods once, when it is built; a premotor without them gets the
    hardwired lift reflex (:func:`controller.stepping.reflexes.lift_amplitude`) and ``on_reflex``."""

    def lift_amplitude(self, gated_range_m: float | None, context: int | None) -> float:
        """The CPG amplitude for the step cycle this gate begins (the loop keeps it within
        [``MIN_LIFT_AMPLITUDE``, ``MAX_LIFT_AMPLITUDE``] of :mod:`controller.loop`)."""

    def on_contact_reflex(self, reflex: "Reflex") -> None:
        """A contact reflex fired, in full (kind, time, cause, swing half, phase): called instead
        of ``on_reflex``."""
