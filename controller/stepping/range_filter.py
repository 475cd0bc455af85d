"""The range filter: a Kalman filter (filterpy) on the sensor board's range readings.

State: distance to the target ahead [m] and its rate [m/s], a constant-velocity model. The
filter predicts at the controller's rate and is corrected by each new valid reading (50 Hz).
A dropout (``Range_Valid = 0``) means predict only. A reading is rejected and counted when it is
NaN, outside ``[0, max_range_m]``, stale (older than the last one used), or an outlier (its
innovation beyond ``gate_sigma`` standard deviations once the filter has converged; a run of
``reacquire_after`` consecutive outliers re-initialises the filter on the new target instead:
that is a new obstacle coming into view, not noise). Out-of-sequence frames never get here:
:mod:`controller.io.sensors` drops them.

With no valid reading for ``stale_s`` the estimate is withdrawn (``None``): no target in view.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from controller.settings.schema import check_settings, setting
from controller.stepping.filterpy_kf import KalmanFilter  # filterpy's class, without scipy at import (see there)
from protocol.compiled import interpreted


@interpreted  # a configuration: plain Python even when compiled (protocol.compiled)
@dataclass(frozen=True)
class RangeFilterConfig:
    """The filter. The process noise is small: the sensor rides the carriage, which runs at
    constant speed."""

    noise_m: float = setting(0.02, "m", 0.0001, 1.0, "standard deviation of one range reading")
    accel_noise_m_s2: float = setting(0.3, "m/s^2", 0.0, 100.0, "white-acceleration process noise")
    max_range_m: float = setting(3.0, "m", 0.01, 100.0, "readings beyond this are out of range")
    stale_s: float = setting(0.25, "s", 0.001, 10.0, "no valid reading for this long: no target")
    gate_sigma: float = setting(5.0, "standard deviations", 0.5, 100.0, "innovation gate for outliers")
    reacquire_after: int = setting(3, "readings", 1, 1000, "consecutive outliers that mean a new target")

    def __post_init__(self) -> None:
        check_settings(self, "range_filter")


def inverse_1x1(s: np.ndarray) -> np.ndarray:
    """The inverse of the filter's 1x1 innovation covariance ``S``: its reciprocal, bit for bit what
    ``numpy.linalg.inv`` returns for a 1x1 matrix (LAPACK's solve divides 1 by the pivot), at a
    fifth of its cost (4.4 us against 0.9 us alone, more inside a run). filterpy's documented knob
    for it is ``KalmanFilter.inv``. Anything but a finite positive 1x1 (never here: S = P00 + R, R
    > 0) goes to ``numpy.linalg.inv``, which raises on a singular matrix as before."""
    if s.shape == (1, 1):
        v = s[0, 0]
        if 0.0 < v < math.inf:
            return 1.0 / s
    return np.linalg.inv(s)


class RangeFilter:
    def __init__(self, config: RangeFilterConfig = RangeFilterConfig()) -> None:
        self.config = config
        self.kf = KalmanFilter(dim_x=2, dim_z=1)
        self.kf.inv = inverse_1x1  # S is 1x1 (one range reading): no LAPACK call per update
        self.kf.H = np.array([[1.0, 0.0]])
        self.kf.R = np.array([[config.noise_m**2]])
        self.rejected = {"nan": 0, "out_of_range": 0, "stale": 0, "outlier": 0}
        self.used = 0
        self.dropouts = 0
        self._t_s = math.nan
        self._last_reading_t_s = -math.inf
        self._last_valid_t_s = -math.inf
        self._outliers_in_a_row = 0
        self.active = False
        # F and Q by dt [s]: the tick's dt takes a handful of float values (the clock is a sum of
        # steps), so each pair is built once, not every tick (filterpy's predict never changes them)
        self._fq: dict[float, tuple[np.ndarray, np.ndarray]] = {}

    def _init(self, z: float) -> None:
        self.kf.x = np.array([[z], [0.0]])
        self.kf.P = np.diag([self.config.noise_m**2, 1.0])
        self.active = True
        self._outliers_in_a_row = 0

    def predict(self, now_s: float) -> None:
        """Advance the state to ``now_s`` (called every tick)."""
        if not math.isnan(self._t_s) and self.active:
            dt = now_s - self._t_s
            if dt > 0.0:
                fq = self._fq.get(dt)
                if fq is None:  # built once per dt: the same floats give the same matrices, bit for bit
                    if len(self._fq) >= 16:
                        self._fq.clear()
                    q = self.config.accel_noise_m_s2**2
                    fq = self._fq[dt] = (np.array([[1.0, dt], [0.0, 1.0]]),
                                         q * np.array([[dt**4 / 4, dt**3 / 2], [dt**3 / 2, dt**2]]))
                self.kf.F, self.kf.Q = fq
                self.kf.predict()
        self._t_s = now_s
        if self.active and now_s - self._last_valid_t_s > self.config.stale_s:
            self.active = False

    def reading(self, range_m: float, valid: bool, reading_t_s: float) -> bool:
        """Offer one sensor sample (taken at ``reading_t_s``); True if it corrected the estimate."""
        if reading_t_s <= self._last_reading_t_s:
            self.rejected["stale"] += 1
            return False
        self._last_reading_t_s = reading_t_s
        if not valid:
            self.dropouts += 1
            return False
        if not math.isfinite(range_m):
            self.rejected["nan"] += 1
            return False
        if not 0.0 <= range_m <= self.config.max_range_m:
            self.rejected["out_of_range"] += 1
            return False
        self._last_valid_t_s = reading_t_s
        if not self.active:
            self._init(range_m)
            self.used += 1
            return True
        innovation = range_m - float(self.kf.x[0, 0])
        s = float(self.kf.P[0, 0]) + self.config.noise_m**2
        if abs(innovation) > self.config.gate_sigma * math.sqrt(s):
            self._outliers_in_a_row += 1
            self.rejected["outlier"] += 1
            if self._outliers_in_a_row >= self.config.reacquire_after:
                self._init(range_m)
                return True
            return False
        self._outliers_in_a_row = 0
        self.kf.update(np.array([[range_m]]))
        self.used += 1
        return True

    @property
    def estimate_m(self) -> float | None:
        """The filtered distance [m], or None when no target is in view."""
        return float(self.kf.x[0, 0]) if self.active else None

    @property
    def rate_m_s(self) -> float | None:
        """The filtered range rate [m/s] (negative: closing), or None when no target is in view."""
        return float(self.kf.x[1, 0]) if self.active else None

    @property
    def rate_var_m2_s2(self) -> float | None:
        """The variance of :attr:`rate_m_s` [m^2/s^2] (1 when a target was just acquired), or None
        when no target is in view."""
        return float(self.kf.P[1, 1]) if self.active else None
