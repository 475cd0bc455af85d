"""The platform's floor beside a session (hil.bench.floor) and the allowance it gives a real-time
outcome (hil.profile.Profile.late_allowance_s). Time comes from a clock the test controls; the
one real probe process is checked for its structure only."""

from __future__ import annotations

import pytest

from hil.bench.floor import FloorProbe, probe
from hil.profile import NATIVE, SCHEDULING_S, UML


class Clock:
    """A monotonic clock the test moves: each sleep advances it by the time asked, plus ``extra``
    once when ``stall_at`` sleeps have been done."""

    def __init__(self, stall_at: int | None = None, stall_s: float = 0.0) -> None:
        self.t = 100.0
        self.sleeps = 0
        self.stall_at = stall_at
        self.stall_s = stall_s

    def __call__(self) -> float:
        return self.t

    def sleep(self, s: float) -> None:
        self.sleeps += 1
        self.t += s
        if self.sleeps == self.stall_at:
            self.t += self.stall_s


def _run(clock: Clock, ticks: int, rate_hz: float = 100.0) -> dict:
    n = {"k": 0}

    def stop() -> bool:
        n["k"] += 1
        return n["k"] > ticks

    return probe(rate_hz, stop, clock=clock, sleep=clock.sleep)


def test_the_probe_reports_the_longest_stall_it_had():
    steady = _run(Clock(), 200)
    assert steady["ticks"] == 201 and steady["late_ticks"] == 0 and steady["skipped"] == 0
    assert steady["max_period_s"] == pytest.approx(0.01)
    stalled = _run(Clock(stall_at=50, stall_s=0.2355), 200)
    # the stalled tick's period is the 10 ms it slept plus the stall; the deadlines missed meanwhile
    # are skipped at the next tick, not caught up (the controller's pacing)
    assert stalled["max_period_s"] == pytest.approx(0.2455)
    assert stalled["late_ticks"] == 1 and stalled["skipped"] == 22
    assert stalled["period_s"] == pytest.approx(0.01) and stalled["rate_hz"] == 100.0


def test_the_probe_without_a_period_has_no_figure_and_refuses_a_bad_rate():
    assert _run(Clock(), 0)["max_period_s"] is None
    with pytest.raises(ValueError, match="rate_hz"):
        probe(0.0, lambda: True)


def test_the_probe_process_reports_its_figures():
    with FloorProbe(rate_hz=200.0) as p:
        pass
    r = p.result
    assert r["error"] is None, r
    assert r["ticks"] >= 1 and r["period_s"] == pytest.approx(0.005)  # "ready" comes after the first tick
    assert r["max_period_s"] is None or r["max_period_s"] > 0
    assert p.stop() is r  # idempotent


def test_the_probe_can_be_started_as_the_processes_it_stands_beside():
    r = FloorProbe(prefix=["nice", "-n", "0"]).start().stop()  # e.g. a nice that undoes the harness's own
    assert r["error"] is None and r["ticks"] >= 1, r


def test_a_probe_never_started_says_so():
    r = FloorProbe().stop()
    assert r["max_period_s"] is None and "not started" in r["error"]


def test_the_allowance_is_the_measured_stalls_plus_one_wake_up():
    assert NATIVE.late_allowance_s() == pytest.approx(SCHEDULING_S)
    assert NATIVE.late_allowance_s(0.012, 0.003) == pytest.approx(0.015 + SCHEDULING_S)
    assert UML.late_allowance_s(0.012, 0.003) == NATIVE.late_allowance_s(0.012, 0.003)  # measured: no platform guess
    # not measured: the platform's fixed fallback stands in for that one process only
    assert NATIVE.late_allowance_s(None, 0.003) == pytest.approx(0.020 + 0.003 + SCHEDULING_S)
    assert UML.late_allowance_s(None) == pytest.approx(0.050 + SCHEDULING_S)
    for bad in (float("nan"), -1.0, float("inf")):
        assert NATIVE.late_allowance_s(bad) == pytest.approx(0.020 + SCHEDULING_S), bad
