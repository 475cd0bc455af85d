"""The muscle: a first-order low-pass filter between the CPG's shaped targets and the joints.

The paper simulates the muscle as a low-pass filter; here it smooths each joint target (and the
transitions between the CPG's halves) before it goes on the bus. Exact discretisation
(``1 - exp(-dt/tau)``), so the response does not depend on the loop rate.
"""

from __future__ import annotations

import math


class LowPass:
    """y' = (x - y) / tau, integrated exactly over each tick's measured dt."""

    def __init__(self, tau_s: float, initial: float = 0.0) -> None:
        if not tau_s >= 0.0:
            raise ValueError(f"tau_s must be >= 0 s, got {tau_s!r}")
        self.tau_s = tau_s
        self.y = initial
        self._dt_s = math.nan
        self._alpha = 1.0

    def reset(self, value: float) -> None:
        self.y = value

    def __call__(self, x: float, dt_s: float) -> float:
        if dt_s != self._dt_s:  # the loop's dt is nearly always the same: cache the coefficient
            self._dt_s = dt_s
            self._alpha = 1.0 if self.tau_s <= 0.0 else 1.0 - math.exp(-dt_s / self.tau_s)
        self.y += self._alpha * (x - self.y)
        return self.y
