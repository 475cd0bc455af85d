"""The oracle baseline: a geometric planner that knows exactly where the obstacle is.

The "model the world, then plan" approach the paper argues against, given everything it needs:
at every step onset it reads the true distance from the stance foot to the obstacle's near edge
(ground truth from the simulation, never from the bus) and plans the remaining strides so that the
last footfall before the obstacle lands at ``takeoff_m`` from the near edge, the middle of the
take-off window (the last footfalls from which the leg clears a 0.08 m obstacle without
adaptation). It splits the remaining distance into the whole number of strides closest to
the natural stride, each within the CPG's burst bounds, and sets the burst for the coming swing:
``stride = v * (stance + burst)``.

It is given the obstacle's true height too, and sets the lift for it (:meth:`OraclePremotor.lift_amplitude`):
``max(reflexes.lift_amplitude, (height + lift_margin_m) / step_height)``, within the leg's limit,
where the hardwired reflex would lift (the gated range below ``reflexes.lift_range_m``). At 0.08 m
and below that is the hardwired lift itself, so the oracle's records there are those of before. So
it stays an upper bound for the learners, which must learn their lift.

A lift above ``gait.tuck_from_amplitude`` (3.0) tucks the gait's swing (``controller.motion.gait``:
the foot up early, held back, forward and down late), by the fraction :func:`controller.motion.gait.tuck_fraction`
of that lift. The tucked swing needs the block farther ahead when it starts (the shin, near the
near edge when stance ends, has to be clear of it before the foot is up) and longer to let the
block pass under the held foot. So, by the same fraction, the oracle plans the take-off at
``tucked_takeoff_m`` instead of ``takeoff_m`` and gives the crossing swing the CPG's longest burst
(``cpg.burst_max_s``) instead of the base one. Up to 0.16 m (a lift of at most 2.9) the fraction is
0: the plan of before.

It is a Premotor (``controller.stepping.premotor``) like the learner, so it drives the same CPG through the
same loop, bus and plant; it never learns.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

from controller.config import ControllerConfig
from controller.motion.gait import tuck_fraction
from controller.stepping.reflexes import lift_amplitude


@dataclass(frozen=True)
class OracleConfig:
    """Attributes:
    takeoff_m: planned last footfall relative to the near edge [m]; default -0.16 (the foot
        settles a few cm past the plan, so -0.16 lands near the take-off window's middle).
    lift_margin_m: the lift's peak above the obstacle's top, over the step height [m]; default
        0.07 (the gait's half-sine swing is at its peak only mid-swing: 0.12 m obstacles need an
        amplitude of about 2.4, 0.16 m about 2.9; measured on seed 5 with the oracle, docs/improved.md).
        With the tucked swing the foot's height is bounded by the knee's flexion rather than the
        amplitude above about 3 (0.16 m and up), so the margin there only makes the swing tucked.
    tucked_takeoff_m: the planned last footfall for a fully tucked swing [m]; default -0.22
        (the foot settles about 0.02-0.03 m past it: the near edge is then about 0.1 m ahead of the
        hip when the swing starts, where the knee and the shin rise clear of it in time; at -0.19
        the shin of a 0.20 m block's lift still struck it, seed 5).
    """

    takeoff_m: float = -0.16
    lift_margin_m: float = 0.07
    tucked_takeoff_m: float = -0.22


class OraclePremotor:
    """Plans stride lengths from the true distance ``truth()`` (foot to near edge [m], or None)."""

    def __init__(self, controller: ControllerConfig, truth: Callable[[], float | None],
                 config: OracleConfig = OracleConfig(), height: Callable[[], float | None] | None = None) -> None:
        """``truth()``: the foot's distance to the near edge [m]; ``height()``: the obstacle's
        height [m] (None: no obstacle; no ``height``: the hardwired lift)."""
        self.config = config
        self.truth = truth
        self.height = height
        self._reflexes = controller.reflexes
        self._step_height_m = controller.gait.step_height_m
        self._gait = controller.gait
        self._lift_max = None
        if height is not None:
            from controller.motion.reach import max_lift_amplitude

            self._lift_max = max_lift_amplitude(geometry=controller.geometry, axes=controller.axes,
                                                cpg=controller.cpg, gait=controller.gait)
        cpg = controller.cpg
        self.v_m_s = controller.gait.ground_speed_m_s
        self.stance_s = cpg.stance_s
        self.base_burst_s = cpg.burst_s
        self.longest_burst_s = cpg.burst_max_s
        self.stride_min_m = self.stride_m(cpg.burst_min_s)
        self.stride_max_m = self.stride_m(cpg.burst_max_s)
        self.stride_base_m = self.stride_m(cpg.burst_s)
        self._burst_s = cpg.burst_s
        self.plans: list[tuple[float, int, float]] = []  # (distance to plan [m], strides, stride [m])

    def stride_m(self, burst_s: float) -> float:
        return self.v_m_s * (self.stance_s + burst_s)

    def tuck(self) -> float:
        """How tucked the crossing swing will be (0..1): the gait's tuck fraction of the lift the
        obstacle's true height calls for (0 without a height, or at the hardwired lift)."""
        h = self.height() if self.height is not None else None
        if h is None or self._lift_max is None:
            return 0.0
        return tuck_fraction(self._gait, self._lift_for(h))

    def _lift_for(self, h: float) -> float:
        """The lift for an obstacle ``h`` high [m]: its top plus the margin, over the step height,
        at least the hardwired reflex's and at most the leg's highest."""
        return min(self._lift_max,
                   max(self._reflexes.lift_amplitude, (h + self.config.lift_margin_m) / self._step_height_m))

    def plan(self, distance_m: float | None) -> float:
        """Burst [s] for the coming swing, given the foot's distance to the near edge."""
        if distance_m is None:
            return self.base_burst_s
        u = self.tuck()
        takeoff_m = self.config.takeoff_m
        if u > 0.0:
            takeoff_m += u * (self.config.tucked_takeoff_m - takeoff_m)
        remaining = distance_m + takeoff_m  # from this footfall to the planned take-off
        if remaining < 0.5 * self.stride_min_m:
            # this is the take-off step: the swing crosses (a tucked one, for longer)
            return self.base_burst_s + u * (self.longest_burst_s - self.base_burst_s) if u > 0.0 \
                else self.base_burst_s
        lo = max(1, math.ceil(remaining / self.stride_max_m - 1e-9))
        hi = max(lo, math.floor(remaining / self.stride_min_m + 1e-9))
        n = min(max(round(remaining / self.stride_base_m), lo), hi)
        stride = min(self.stride_max_m, max(self.stride_min_m, remaining / n))
        self.plans.append((distance_m, n, stride))
        return stride / self.v_m_s - self.stance_s

    def on_step_onset(self, now_s: float, cell: int | None, context: int | None = None) -> None:
        distance = self.truth()
        self._burst_s = self.plan(distance if distance is not None and distance > 0.0 else None)

    def burst_s(self, now_s: float) -> float:
        return self._burst_s

    def lift_amplitude(self, gated_range_m: float | None, context: int | None) -> float:
        """The hardwired reflex's rule for when to lift; how high from the true height."""
        hardwired = lift_amplitude(self._reflexes, gated_range_m)
        h = self.height() if self.height is not None else None
        if hardwired == 1.0 or h is None or self._lift_max is None:
            return hardwired
        return self._lift_for(h)  # (hardwired is the reflex's lift_amplitude here)

    def on_reflex(self, kind: str, now_s: float) -> None:
        pass

    def gated_weight(self) -> float:
        return self._burst_s - self.base_burst_s
