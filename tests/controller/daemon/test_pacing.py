"""The real-time pacer, on a fake clock: deadlines, late ticks, skipping and catching up."""

from __future__ import annotations

import pytest

from controller.daemon.pacing import Pacer


class FakeClock:
    def __init__(self) -> None:
        self.t = 100.0
        self.oversleep = 0.0

    def __call__(self) -> float:
        return self.t

    def sleep(self, s: float) -> None:
        self.t += s + self.oversleep


def test_on_time_ticks_land_on_their_deadlines_with_no_drift():
    c = FakeClock()
    p = Pacer(0.002, clock=c, sleep=c.sleep)
    times = [p.wait() for _ in range(1000)]
    assert times[-1] - times[0] == pytest.approx(999 * 0.002)
    s = p.summary()
    assert s["ticks"] == 1000 and s["late_ticks"] == 0 and s["skipped"] == 0
    assert s["period_jitter_us"]["median"] == 0.0 and s["period_jitter_us"]["max"] < 1.0


def test_oversleep_shows_as_jitter_but_does_not_drift():
    c = FakeClock()
    c.oversleep = 0.0001
    p = Pacer(0.002, clock=c, sleep=c.sleep)
    times = [p.wait() for _ in range(500)]
    assert times[-1] - times[0] == pytest.approx(499 * 0.002, abs=2e-4)
    assert p.summary()["period_jitter_us"]["max"] < 120.0


def test_a_fixed_rate_loop_skips_missed_periods_and_counts_the_late_tick():
    c = FakeClock()
    p = Pacer(0.002, clock=c, sleep=c.sleep)
    p.wait()
    p.wait()
    c.t += 0.0075  # the work of one tick overran by almost four periods
    t = p.wait()
    assert p.late_ticks == 1 and p.skipped == 2
    nxt = p.wait()
    assert nxt > t and (nxt - p.start_s) / 0.002 == pytest.approx(round((nxt - p.start_s) / 0.002))


def test_catch_up_runs_back_to_back_then_slips_when_far_behind():
    c = FakeClock()
    p = Pacer(0.001, clock=c, sleep=c.sleep, catch_up=True, max_behind_s=0.05)
    p.wait()
    c.t += 0.0035
    before = c.t
    for _ in range(3):
        p.wait()  # three overdue deadlines: no sleeping
    assert c.t == before and p.slipped_s == 0.0
    c.t += 0.2
    p.wait()
    assert p.slipped_s == pytest.approx(0.2 - 0.0005, abs=1e-3)
