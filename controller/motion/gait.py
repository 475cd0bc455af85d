"""Foot trajectories in the hip frame, shaped by the CPG's output.

Stance (extensor half): the foot target moves backward at the ground speed, from
``foot_ahead_m`` to ``foot_ahead_m - ground_speed_m_s * stance_s``, just below the ground so
the contact is firm. Swing (flexor half): the foot returns forward on a cosine profile and lifts
by ``step_height_m`` times the CPG's flexor drive (the lift reflex raises the drive's
amplitude), on a half-sine in the swing's phase. The swing's duration is the CPG's burst
length, so at a constant ground speed the stride is ``ground_speed * (stance_s + burst_s)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from controller.motion.cpg import CpgConfig, CpgOutput
from controller.motion.kinematics import LegGeometry
from controller.settings.schema import check_settings, setting
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

    def __post_init__(self) -> None:
        check_settings(self, "gait")


class FootTrajectory:
    def __init__(self, gait: GaitConfig, cpg: CpgConfig, geometry: LegGeometry) -> None:
        self.gait = gait
        self.x_front_m = gait.foot_ahead_m
        self.x_back_m = gait.foot_ahead_m - gait.ground_speed_m_s * cpg.stance_s
        self.z_ground_m = -(geometry.hip_height_m - geometry.foot_radius_m)
        self.z_stance_m = self.z_ground_m - gait.stance_press_m

    def target(self, out: CpgOutput) -> tuple[float, float]:
        """Foot centre (x, z) relative to the hip [m] for this CPG output."""
        s = out.phase
        if not out.flexing:
            return self.x_front_m + (self.x_back_m - self.x_front_m) * s, self.z_stance_m
        x = self.x_back_m + (self.x_front_m - self.x_back_m) * 0.5 * (1.0 - math.cos(math.pi * s))
        z = self.z_ground_m + self.gait.step_height_m * out.flexor_drive * math.sin(math.pi * s)
        return x, z

    def start_pose(self) -> tuple[float, float]:
        """Where the foot is when the ring starts (stance onset)."""
        return self.x_front_m, self.z_stance_m
