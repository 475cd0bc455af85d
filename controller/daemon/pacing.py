"""Real-time pacing: a fixed period on the monotonic clock, with measured jitter and late ticks.

:meth:`Pacer.wait` sleeps until the next deadline (``start + k * period``) and returns the time
it woke, which the caller uses as the tick's clock. Deadlines never drift: a late wake-up does
not push the later deadlines back. Two policies for a caller that falls behind:

- ``catch_up=True`` (the plant: simulated time must keep up with wall time): ``wait`` returns at
  once until the caller is back on schedule; when it is more than ``max_behind_s`` behind, the
  schedule is moved to now and the lost time counted in ``slipped_s``.
- ``catch_up=False`` (the controller: a fixed-rate loop): missed deadlines are skipped, counted
  in ``skipped``; the next tick is the next deadline still in the future.

Per tick it records the measured period (wake-up to wake-up): a tick is late when its period
exceeds ``late_factor`` periods; ``jitter`` is |period - nominal| in a 1 us histogram (up to
100 ms), so a run of any length costs constant memory. ``summary()`` gives median, p99 and max.
"""

from __future__ import annotations

import math
import time
from typing import Callable


def _absolute_sleeper() -> Callable[[float], None] | None:
    """``sleep_until(t)`` on CLOCK_MONOTONIC with TIMER_ABSTIME (Linux), or None: one system call
    per wait instead of a clock read and a relative sleep (each costs ~20 us in User-Mode Linux)."""
    try:
        import ctypes
        import ctypes.util

        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        fn = libc.clock_nanosleep
    except (OSError, AttributeError):
        return None

    class Timespec(ctypes.Structure):
        _fields_ = [("tv_sec", ctypes.c_long), ("tv_nsec", ctypes.c_long)]

    ts = Timespec()
    ref = ctypes.byref(ts)
    clock_monotonic, timer_abstime = 1, 1

    def sleep_until(t: float) -> None:
        sec = int(t)
        ts.tv_sec, ts.tv_nsec = sec, int((t - sec) * 1e9)
        while fn(clock_monotonic, timer_abstime, ref, None) == 4:  # EINTR: sleep on
            pass

    return sleep_until


class Pacer:
    HIST_US = 100_000

    def __init__(self, period_s: float, *, catch_up: bool = False, late_factor: float = 1.5,
                 max_behind_s: float = 0.05, clock: Callable[[], float] = time.monotonic,
                 sleep: Callable[[float], None] = time.sleep) -> None:
        if not (math.isfinite(period_s) and period_s > 0):
            raise ValueError(f"period_s must be positive, got {period_s!r}")
        self.period_s = period_s
        self.catch_up = catch_up
        self.late_factor = late_factor
        self.max_behind_s = max_behind_s
        self.clock = clock
        self.sleep = sleep
        self.start_s = math.nan
        self._k = 0
        self._last_s = math.nan
        self.ticks = 0
        self.late_ticks = 0
        self.skipped = 0
        self.slipped_s = 0.0
        self.max_period_s = 0.0
        self.min_period_s = math.inf
        self._hist = [0] * (self.HIST_US + 1)
        self._sleep_until = _absolute_sleeper() if (clock is time.monotonic and sleep is time.sleep) else None
        self._n_periods = 0

    @property
    def deadline_s(self) -> float:
        return self.start_s + self._k * self.period_s

    def start(self, now_s: float | None = None) -> float:
        self.start_s = self.clock() if now_s is None else now_s
        self._k = 0
        return self.start_s

    def wait(self) -> float:
        """Sleep until the next deadline; return the wake-up time (the tick's clock)."""
        clock = self.clock
        if math.isnan(self.start_s):
            self.start()
        else:
            self._k += 1
        deadline = self.start_s + self._k * self.period_s
        if self._sleep_until is not None:  # returns at once when the deadline has passed
            self._sleep_until(deadline)
        now = clock()
        if now < deadline:
            self.sleep(deadline - now)
            now = clock()
        elif self.catch_up:
            if now - deadline > self.max_behind_s:
                self.slipped_s += now - deadline
                self.start_s += now - deadline
        else:
            missed = int((now - deadline) // self.period_s)
            if missed > 0:
                self.skipped += missed
                self._k += missed
        self._record(now)
        return now

    def _record(self, now: float) -> None:
        self.ticks += 1
        last = self._last_s
        self._last_s = now
        if math.isnan(last):
            return
        period = now - last
        if period > self.max_period_s:
            self.max_period_s = period
        if period < self.min_period_s:
            self.min_period_s = period
        if period > self.late_factor * self.period_s:
            self.late_ticks += 1
        j = int(abs(period - self.period_s) * 1e6)
        self._hist[j if j < self.HIST_US else self.HIST_US] += 1
        self._n_periods += 1

    def _quantile_us(self, q: float) -> float | None:
        n = self._n_periods
        if n == 0:
            return None
        rank = min(n - 1, int(math.ceil(q * n)) - 1) if q > 0 else 0
        seen = 0
        for us, count in enumerate(self._hist):
            seen += count
            if seen > rank:
                return float(us)
        return float(self.HIST_US)

    def summary(self) -> dict:
        jmax = None
        if self._n_periods:
            jmax = max(self.max_period_s - self.period_s, self.period_s - self.min_period_s) * 1e6
        return {
            "period_us": self.period_s * 1e6,
            "ticks": self.ticks,
            "late_ticks": self.late_ticks,
            "skipped": self.skipped,
            "slipped_s": self.slipped_s,
            "max_period_us": self.max_period_s * 1e6,
            "period_jitter_us": {"median": self._quantile_us(0.5), "p99": self._quantile_us(0.99),
                                 "max": jmax},
        }
