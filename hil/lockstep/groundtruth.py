"""Ground truth of a run, measured on the plant (never on the bus): footfalls and swing clearance.

A touchdown is the foot switch closing after the foot has been off the ground for at least
``min_air_s``; a lift-off, the switch open for at least ``min_air_s`` (both debounce the brief
bounces of a stiff contact). Mid-swing is the middle half of a swing in time; the clearance of a
swing is the lowest foot height seen then.
"""

from __future__ import annotations

import math


class FootfallTracker:
    """``plant``: the :class:`~firmware_sim.plant.RigPlant` watched. ``min_air_s``: the debounce
    [s], default 0.04. ``clearance``: record the foot's height at every physics step in the air, for
    ``swing_clearance_m`` (default True); one ``getLinkState`` a step in the air (a third of the
    run's steps, ~40k instructions of PyBullet's each): a run that reports no clearance (``learn``)
    turns it off, and its footfalls are the same."""

    def __init__(self, plant, min_air_s: float = 0.04, *, clearance: bool = True) -> None:
        self.plant = plant
        self.min_air_s = min_air_s
        self.clearance = clearance
        self.footfalls_x_m: list[float] = []
        self.touchdown_t_s: list[float] = []
        self.swing_clearance_m: list[float] = []
        self._on_ground = True
        self._last_contact_s = -math.inf
        self._liftoff_s = math.nan
        self._swing: list[tuple[float, float]] = []

    def update(self) -> None:
        plant = self.plant
        t = plant.t_s
        foot, _shin = plant.contacts()
        if foot:
            if not self._on_ground:
                self._on_ground = True
                x, _z = plant.foot_position()
                self.footfalls_x_m.append(x)
                self.touchdown_t_s.append(t)
                self._close_swing(t)
            self._last_contact_s = t
            return
        if self._on_ground:
            if t - self._last_contact_s >= self.min_air_s:
                self._on_ground = False
                self._liftoff_s = self._last_contact_s
                self._swing = []
            else:
                return
        if self.clearance:
            self._swing.append((t, plant.foot_position()[1]))

    def _close_swing(self, t_touchdown: float) -> None:
        t0 = self._liftoff_s
        if math.isnan(t0):
            return
        lo = t0 + 0.25 * (t_touchdown - t0)
        hi = t0 + 0.75 * (t_touchdown - t0)
        mid = [z for (t, z) in self._swing if lo <= t <= hi]
        if mid:
            self.swing_clearance_m.append(min(mid))
        self._swing = []
