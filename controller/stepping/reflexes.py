"""Reflexes: the contact reflexes that train the weights, and the hardwired lift reflex.

Contact reflexes. An obstacle contact is, as the controller can tell from its own sensors:
  * the shin switch closing; or
  * the foot switch closing during the swing before ``touchdown_phase`` (the foot struck
    something in the air); or
  * the foot switch closing while the encoders put the foot higher than ``on_top_height_m`` above
    the ground (it landed on something).
Its kind follows the leg's phase, as the paper says: while the leg flexes it is a *placement*
reflex (strides should be shorter), while it extends an *extension* reflex (strides should be
longer). Modelling choice: the flexion movement is taken as the half cycle centred on lift-off
(the second half of stance, when the hip has passed over the foot and the leg is loaded to
flex, and the first half of the swing, the foot rising); extension is the half centred on
touchdown (the second half of the swing, the foot reaching down, and the first half of stance).
On this rig a foot that landed too close to the obstacle strikes its edge with the shin just
before lift-off, and needs shorter strides; one that landed too far back comes down on top of it
and needs longer ones. A reflex is followed by a refractory period: one collision, one reflex.

Lift reflex (hardwired): at the step onset, when the gated distance says the obstacle is within
reach of the coming swing (``distance < lift_range_m``), the CPG's amplitude is raised to
``lift_amplitude`` for that step cycle; otherwise it is 1.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

from controller.motion.cpg import CpgOutput
from controller.settings.schema import check_settings, setting
from protocol.compiled import interpreted


@interpreted  # a configuration: plain Python even when compiled (protocol.compiled)
@dataclass(frozen=True)
class ReflexConfig:
    """The reflexes. The default ``refractory_s`` is about a step cycle: a collision and what
    follows from it in the same step are one reflex."""

    touchdown_phase: float = setting(0.8, "(fraction of the swing)", 0.0, 1.0,
                                     "after this a foot contact is a touchdown")
    on_top_height_m: float = setting(0.025, "m", 0.0, 0.5, "foot contact this high means it landed on something")
    refractory_s: float = setting(1.0, "s", 0.0, 10.0, "minimum time between two contact reflexes")
    lift_range_m: float = setting(0.40, "m", 0.0, 3.0, "gated range below which the lift reflex fires")
    lift_amplitude: float = setting(1.9, "x step height", 0.1, 5.0, "CPG amplitude during a lift")

    def __post_init__(self) -> None:
        check_settings(self, "reflexes")


@dataclass(frozen=True)
class Reflex:
    """Attributes: kind ("extension" or "placement"), t_s, cause ("shin", "foot_in_air",
    "foot_on_top"), swing (True if in the swing half), phase (0-1 within that half)."""

    kind: str
    t_s: float
    cause: str
    swing: bool
    phase: float


def flexing(cpg: CpgOutput) -> bool:
    """True during the flexion movement: the second half of stance and the first half of swing."""
    return (cpg.phase < 0.5) if cpg.flexing else (cpg.phase >= 0.5)


class ContactReflexes:
    def __init__(self, config: ReflexConfig = ReflexConfig()) -> None:
        self.config = config
        self._foot = False
        self._shin = False
        self._last_reflex_s = -math.inf

    def update(self, now_s: float, cpg: CpgOutput, foot: bool, shin: bool,
               foot_height_m: Callable[[], float]) -> Reflex | None:
        """``foot_height_m`` is asked only when the foot switch closes (it costs a forward kinematics)."""
        cause = None
        if shin and not self._shin:
            cause = "shin"
        elif foot and not self._foot:
            if cpg.flexing and cpg.phase < self.config.touchdown_phase:
                cause = "foot_in_air"
            else:
                height = foot_height_m()
                if math.isfinite(height) and height > self.config.on_top_height_m:
                    cause = "foot_on_top"
        self._foot, self._shin = foot, shin
        if cause is None or now_s - self._last_reflex_s < self.config.refractory_s:
            return None
        self._last_reflex_s = now_s
        kind = "placement" if flexing(cpg) else "extension"
        return Reflex(kind, now_s, cause, cpg.flexing, cpg.phase)


def lift_amplitude(config: ReflexConfig, gated_range_m: float | None) -> float:
    """The CPG amplitude for the step cycle that begins with this gate."""
    if gated_range_m is not None and gated_range_m < config.lift_range_m:
        return config.lift_amplitude
    return 1.0
