"""Planar hip-knee kinematics of the leg, in the hip frame (x forward, z up, angles from vertical).

Positive angles swing the distal segment forward. The knee bends backward (knee <= 0), so
inverse kinematics takes the knee-back solution.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final

from controller.settings.schema import check_settings, setting
from protocol.compiled import interpreted

REACH: Final = 0.999
"""The farthest :func:`inverse` stretches the leg, as a fraction of thigh + shank (a fully
straight knee is a singular pose)."""

# math functions mypyc has no C version of, bound once (compiled: a C global, not a lookup of the
# module's attribute on every call; sin and cos are C calls)
_hypot: Final = math.hypot
_acos: Final = math.acos
_atan2: Final = math.atan2


@interpreted  # a configuration: plain Python even when compiled (protocol.compiled)
@dataclass(frozen=True)
class LegGeometry:
    """Leg dimensions the controller's kinematics assume."""

    thigh_m: float = setting(0.25, "m", 0.01, 2.0, "hip to knee")
    shank_m: float = setting(0.25, "m", 0.01, 2.0, "knee to foot centre")
    hip_height_m: float = setting(0.47, "m", 0.01, 4.0, "hip axis above the ground")
    foot_radius_m: float = setting(0.02, "m", 0.0, 0.2, "foot sphere radius")

    def __post_init__(self) -> None:
        check_settings(self, "geometry")


def forward(geometry: LegGeometry, hip_rad: float, knee_rad: float) -> tuple[float, float]:
    """Foot centre (x, z) relative to the hip axis [m]."""
    l1, l2 = geometry.thigh_m, geometry.shank_m
    x = l1 * math.sin(hip_rad) + l2 * math.sin(hip_rad + knee_rad)
    z = -l1 * math.cos(hip_rad) - l2 * math.cos(hip_rad + knee_rad)
    return x, z


def inverse(geometry: LegGeometry, x_m: float, z_m: float) -> tuple[float, float]:
    """(hip, knee) [rad] that put the foot centre at (x, z) relative to the hip.

    A target beyond reach is pulled onto the reachable annulus along the same direction, so the
    result is always a valid pose (the loop's limit clamp is the last line of defence).
    """
    l1, l2 = geometry.thigh_m, geometry.shank_m
    r = _hypot(x_m, z_m)
    r_max = (l1 + l2) * REACH
    r_min = abs(l1 - l2) + 0.02
    if r > r_max or r < r_min:
        scale = (r_max if r > r_max else r_min) / max(r, 1e-9)
        x_m, z_m, r = x_m * scale, z_m * scale, min(max(r, r_min), r_max)
    cos_knee = (r * r - l1 * l1 - l2 * l2) / (2.0 * l1 * l2)
    knee = -_acos(max(-1.0, min(1.0, cos_knee)))
    # angle of the foot direction measured from straight down, positive forward
    alpha = _atan2(x_m, -z_m)
    beta = _atan2(l2 * math.sin(-knee), l1 + l2 * math.cos(knee))
    hip = alpha + beta
    return hip, knee
