"""ODrive's trapezoidal trajectory planner (input mode TRAP_TRAJ), as firmware 0.6 plans it.

:class:`TrapezoidalTrajectory` follows ODrive's ``TrapezoidalTrajectory::planTrapezoidal`` and
``eval`` (Firmware/MotorControl/trapTraj.cpp, after "Planning of trapezoidal velocity profiles"):
from a start position ``xi`` and velocity ``vi`` to a goal ``xf``, accelerate at ``accel``
towards the cruise velocity ``±vel_limit``, cruise, and decelerate at ``decel`` to rest at the
goal. A move too short to reach the cruise velocity is a triangle (no cruise); a start faster
than the cruise velocity decelerates to it first. ``eval(t)`` gives the setpoints
``(position, velocity, acceleration)`` ``t`` seconds after the plan; at and after ``t_total_s``
the goal at rest.

The simulated driver (:mod:`firmware_sim.odrive_axis`) plans one on each Set_Input_Pos while in
TRAP_TRAJ and feeds ``acceleration * inertia`` forward as torque (Set_Traj_Inertia), as ODrive
does. Units: rev, rev/s, rev/s² (motor side).

May import: the standard library only.
"""

from __future__ import annotations

import math


def _sign_hard(x: float) -> float:
    """ODrive's sign_hard: -1 for a negative number (or -0.0), else +1."""
    return -1.0 if math.copysign(1.0, x) < 0.0 else 1.0


class TrapezoidalTrajectory:
    """One planned move. Attributes (after planning): ``t_accel_s``, ``t_cruise_s``, ``t_decel_s``,
    ``t_total_s``, ``cruise_vel`` (signed, the peak velocity of the profile), ``accel``,
    ``decel`` (signed, as applied), ``xi``, ``xf``, ``vi``."""

    __slots__ = ("xi", "xf", "vi", "cruise_vel", "accel", "decel", "t_accel_s", "t_cruise_s", "t_decel_s",
                 "t_total_s", "_y_accel")

    def __init__(self, xf: float, xi: float, vi: float, vel_limit: float, accel_limit: float,
                 decel_limit: float) -> None:
        for name, value in (("xf", xf), ("xi", xi), ("vi", vi)):
            if not math.isfinite(value):
                raise ValueError(f"{name} must be finite, got {value!r}")
        for name, value in (("vel_limit", vel_limit), ("accel_limit", accel_limit), ("decel_limit", decel_limit)):
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"{name} must be finite and > 0, got {value!r}")
        dx = xf - xi
        stop_dist = vi * vi / (2.0 * decel_limit)
        dx_stop = math.copysign(stop_dist, vi)
        s = _sign_hard(dx - dx_stop)
        ar = s * accel_limit
        dr = -s * decel_limit
        vr = s * vel_limit
        if s * vi > s * vr:  # faster than the cruise velocity: decelerate to it first
            ar = -s * accel_limit
        ta = (vr - vi) / ar
        td = -vr / dr
        dx_min = 0.5 * ta * (vr + vi) + 0.5 * td * vr
        if s * dx < s * dx_min:  # short move: a triangle, no cruise
            vr = s * math.sqrt(max((dr * vi * vi + 2.0 * ar * dr * dx) / (dr - ar), 0.0))
            ta = max(0.0, (vr - vi) / ar)
            td = max(0.0, -vr / dr)
            tv = 0.0
        else:
            tv = (dx - dx_min) / vr
        self.xi, self.xf, self.vi = xi, xf, vi
        self.cruise_vel, self.accel, self.decel = vr, ar, dr
        self.t_accel_s, self.t_cruise_s, self.t_decel_s = ta, tv, td
        self.t_total_s = ta + tv + td
        self._y_accel = xi + vi * ta + 0.5 * ar * ta * ta

    def eval(self, t: float) -> tuple[float, float, float]:
        """``(position, velocity, acceleration)`` at ``t`` seconds after the plan."""
        if t < 0.0:
            return self.xi, self.vi, 0.0
        ta = self.t_accel_s
        if t < ta:
            return self.xi + self.vi * t + 0.5 * self.accel * t * t, self.vi + self.accel * t, self.accel
        if t < ta + self.t_cruise_s:
            return self._y_accel + self.cruise_vel * (t - ta), self.cruise_vel, 0.0
        if t < self.t_total_s:
            td = t - self.t_total_s
            return self.xf + 0.5 * self.decel * td * td, self.decel * td, self.decel
        return self.xf, 0.0, 0.0

    def done(self, t: float) -> bool:
        """True once the move is over (``t`` at or past ``t_total_s``)."""
        return t >= self.t_total_s


__all__ = ["TrapezoidalTrajectory"]
