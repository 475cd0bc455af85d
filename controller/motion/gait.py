"""Foot trajectories in the hip frame, shaped by the CPG's output.

Stance (extensor half): the foot target moves backward at the ground speed, from
``foot_ahead_m`` to ``foot_ahead_m - ground_speed_m_s * stance_s``, just below the ground so
the contact is firm. Swing (flexor half): the foot returns forward on a cosine profile and lifts
by ``step_height_m`` times the CPG's flexor drive (the lift reflex raises the drive's
amplitude), on a half-sine in the swing's phase. The swing's duration is the CPG's burst
length, so at a constant ground speed the stride is ``ground_speed * (stance_s + burst_s)``.

High lifts: the tucked swing. The half-sine is at its peak only mid-swing, and the foot moves
forward all the while, so the shin meets a tall block's near edge before the foot is up, and the
foot passes over the block where it is not yet (or no longer) at its peak: the oracle, lifting 3.0
x the step height, cleared 0.16 m but never 0.18 m. The leg's own limit (0.223 m for a 0.10 m deep
block, :mod:`controller.motion.reach`) is set by a tucked pose: the knee fully flexed, the foot
just behind the hip. So above ``tuck_from_amplitude`` (3.0: above the hardwired lift's 1.9 and
the lifts a learner reaches for 0.16 m, which the half-sine clears) the swing blends,
continuously in the amplitude, into a *tucked* path (:meth:`FootTrajectory.tucked`):
the foot rises early (a quarter-sine up to ``tuck_rise_phase``, then a flat top), drawing back by
``tuck_back_m`` while it rises (the shank clears the near edge); it moves forward only from
``tuck_forward_phase`` (on a cosine, reaching the front at ``tuck_land_phase``) and descends only
from ``tuck_descend_phase``, so the block passes under a high foot. Its height is the step height
x the flexor drive as before, but never above the circle round the hip on which the knee is bent
to ``tuck_knee_rad`` (the knee's flexion limit): a higher target would ask the knee past its limit.
At or below ``tuck_from_amplitude`` the path is the half-sine, float for float.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from controller.motion.cpg import CpgConfig, CpgOutput
from controller.motion.kinematics import LegGeometry
from controller.settings.schema import check_settings, setting, settings_of
from protocol.compiled import interpreted


@interpreted  # a configuration: plain Python even when compiled (protocol.compiled)
@dataclass(frozen=True)
class GaitConfig:
    """Foot trajectory shaping. ``ramp_s``: the move from the pose found at bring-up to the gait's
    start pose."""

    ground_speed_m_s: float = setting(0.5, "m/s", 0.0, 3.0, "rail speed the stance foot matches")
    foot_ahead_m: float = setting(0.10, "m", -0.5, 0.5, "foot x at touchdown, ahead of the hip")
    step_height_m: float = setting(0.08, "m", 0.0, 0.3, "foot lift at full amplitude")
    stance_press_m: float = setting(0.005, "m", 0.0, 0.05, "stance target below the ground")
    muscle_tau_s: float = setting(0.015, "s", 0.0, 1.0, "muscle low-pass time constant")
    ramp_s: float = setting(1.0, "s", 0.0, 10.0, "move to the start pose in this long")
    tuck_from_amplitude: float = setting(3.0, "x step height", 1.0, 5.0,
                                         "lift amplitude above which the swing starts to tuck")
    tuck_full_amplitude: float = setting(3.44, "x step height", 1.0, 5.0,
                                         "lift amplitude from which the swing is fully tucked")
    tuck_rise_phase: float = setting(0.2, "(fraction of the swing)", 0.05, 0.5, "tucked swing: foot up by then")
    tuck_descend_phase: float = setting(0.72, "(fraction of the swing)", 0.3, 0.95,
                                        "tucked swing: foot starts down then")
    tuck_forward_phase: float = setting(0.5, "(fraction of the swing)", 0.0, 0.9,
                                        "tucked swing: foot starts forward then")
    tuck_land_phase: float = setting(0.95, "(fraction of the swing)", 0.1, 1.0,
                                     "tucked swing: foot at the front by then")
    tuck_back_m: float = setting(0.03, "m", 0.0, 0.1, "tucked swing: foot drawn back this far while it rises")
    tuck_knee_rad: float = setting(-2.15, "rad", -3.0, -0.1,
                                   "tucked swing: the foot rises no higher than with the knee bent this far")

    def __post_init__(self) -> None:
        check_settings(self, "gait")
        if not self.tuck_from_amplitude < self.tuck_full_amplitude:
            raise ValueError(f"gait.tuck_full_amplitude must be above gait.tuck_from_amplitude = "
                             f"{self.tuck_from_amplitude}, got {self.tuck_full_amplitude!r}")
        if not self.tuck_forward_phase < self.tuck_land_phase:
            raise ValueError(f"gait.tuck_land_phase must be after gait.tuck_forward_phase = "
                             f"{self.tuck_forward_phase}, got {self.tuck_land_phase!r}")
        if not self.tuck_rise_phase < self.tuck_descend_phase:
            raise ValueError(f"gait.tuck_descend_phase must be after gait.tuck_rise_phase = "
                             f"{self.tuck_rise_phase}, got {self.tuck_descend_phase!r}")


def tuck_fraction(gait: GaitConfig, amplitude: float) -> float:
    """How far the swing is tucked at this lift amplitude: 0 up to ``tuck_from_amplitude`` (the
    half-sine), rising linearly to 1 at ``tuck_full_amplitude`` (so a learner raising its lift step
    by step sees the path change step by step)."""
    lo, hi = gait.tuck_from_amplitude, gait.tuck_full_amplitude
    if not amplitude > lo:
        return 0.0
    return 1.0 if amplitude >= hi else (amplitude - lo) / (hi - lo)


class FootTrajectory:
    def __init__(self, gait: GaitConfig, cpg: CpgConfig, geometry: LegGeometry) -> None:
        self.gait = gait
        self.x_front_m = gait.foot_ahead_m
        self.x_back_m = gait.foot_ahead_m - gait.ground_speed_m_s * cpg.stance_s
        self._stance_s = cpg.stance_s
        # the fastest sweep a stance may be told: the ground speed's declared bound, read once
        bound = next(x.hi for x in settings_of(GaitConfig) if x.key == "ground_speed_m_s")
        assert bound is not None  # the setting declares its range
        self._max_ground_speed_m_s: float = bound
        self.z_ground_m = -(geometry.hip_height_m - geometry.foot_radius_m)
        self.z_stance_m = self.z_ground_m - gait.stance_press_m
        l1, l2 = geometry.thigh_m, geometry.shank_m
        # the foot's distance from the hip with the knee bent to tuck_knee_rad (law of cosines)
        self.tuck_radius_m = math.sqrt(l1 * l1 + l2 * l2 + 2.0 * l1 * l2 * math.cos(gait.tuck_knee_rad))

    def follow_ground_speed(self, speed_m_s: float) -> None:
        """The stance sweeps back at ``speed_m_s`` from now on (told at a touchdown, so the sweep
        never jumps mid-stance); NaN, or a speed outside (0, the bound ``GaitConfig.ground_speed_m_s``
        declares], keeps the sweep as it is. The gait's ``ground_speed_m_s`` again gives its own
        sweep, float for float."""
        if 0.0 < speed_m_s <= self._max_ground_speed_m_s:
            self.x_back_m = self.x_front_m - speed_m_s * self._stance_s

    def target(self, out: CpgOutput, amplitude: float = 1.0, descend_phase: float = math.nan) -> tuple[float, float]:
        """Foot centre (x, z) relative to the hip [m] for this CPG output; ``amplitude``: the CPG's
        lift amplitude this step cycle (above ``tuck_from_amplitude`` the swing tucks);
        ``descend_phase``: where this cycle's tucked swing starts down (NaN, or a phase not between
        ``tuck_rise_phase`` and 1: the gait's ``tuck_descend_phase``)."""
        s = out.phase
        if not out.flexing:
            return self.x_front_m + (self.x_back_m - self.x_front_m) * s, self.z_stance_m
        x = self.x_back_m + (self.x_front_m - self.x_back_m) * 0.5 * (1.0 - math.cos(math.pi * s))
        z = self.z_ground_m + self.gait.step_height_m * out.flexor_drive * math.sin(math.pi * s)
        if amplitude > self.gait.tuck_from_amplitude:
            u = tuck_fraction(self.gait, amplitude)
            x_t, z_t = self.tucked(s, out.flexor_drive, descend_phase)
            x, z = x + u * (x_t - x), z + u * (z_t - z)
        # never above the circle on which the knee is bent to tuck_knee_rad (below the hip): the
        # knee could not follow. At any lift, so the path is continuous where the tuck starts; the
        # hardwired lift's half-sine (1.9 x 0.08 m) stays below it, float for float.
        r = self.tuck_radius_m
        if x * x < r * r:
            z = min(z, -math.sqrt(r * r - x * x))
        return x, z

    def tucked(self, s: float, flexor_drive: float, descend_phase: float = math.nan) -> tuple[float, float]:
        """The fully tucked swing's foot centre (x, z) at swing phase ``s`` [m], before the knee's
        circle bounds it. Height: ``step_height_m * flexor_drive`` times a profile that rises on a
        quarter-sine to 1 at ``tuck_rise_phase``, stays at 1, and falls on a half-cosine from
        ``tuck_descend_phase`` to 0 at the swing's end. Forward: from ``x_back_m``, drawn back by up
        to ``tuck_back_m`` (a half-sine over the swing up to ``tuck_land_phase``), and carried to
        ``x_front_m`` on a half-cosine from ``tuck_forward_phase`` to ``tuck_land_phase``. Both
        start and end where the half-sine swing does, so stance joins it without a jump.
        ``descend_phase`` replaces ``tuck_descend_phase`` for this swing when it lies between
        ``tuck_rise_phase`` and 1 (a premotor's choice for a tall block, see
        :mod:`controller.stepping.improved` rule 18); otherwise (NaN) the gait's is used."""
        g = self.gait
        rise, descend = g.tuck_rise_phase, g.tuck_descend_phase
        if rise < descend_phase < 1.0:
            descend = descend_phase
        if s < rise:
            lift = math.sin(0.5 * math.pi * s / rise)
        elif s < descend:
            lift = 1.0
        else:
            lift = 0.5 * (1.0 + math.cos(math.pi * min(1.0, (s - descend) / (1.0 - descend))))
        forward, land = g.tuck_forward_phase, g.tuck_land_phase
        if s <= forward:
            ahead = 0.0
        elif s < land:
            ahead = 0.5 * (1.0 - math.cos(math.pi * (s - forward) / (land - forward)))
        else:
            ahead = 1.0
        back = g.tuck_back_m * math.sin(math.pi * s / land) if s < land else 0.0
        x = self.x_back_m - back + (self.x_front_m - self.x_back_m) * ahead
        return x, self.z_ground_m + g.step_height_m * flexor_drive * lift

    def start_pose(self) -> tuple[float, float]:
        """Where the foot is when the ring starts (stance onset)."""
        return self.x_front_m, self.z_stance_m
