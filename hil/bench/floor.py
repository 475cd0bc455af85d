"""The platform's floor beside a real-time session: how long this platform stalls a process doing no work.

A safety outcome that exists only in real time (a systemd watchdog ping every half WatchdogSec,
every axis IDLE after a kill) comes late by as much as the platform stalls the processes that
make it. A test checks such an outcome against its bound plus the stall measured *in the same
session* (:meth:`hil.profile.Profile.late_allowance_s`), never against a fixed wall-clock budget;
this module measures that stall where no process of the session does.

:class:`FloorProbe` runs, from :meth:`~FloorProbe.start` to :meth:`~FloorProbe.stop`, a child
process (``python -m hil.bench.floor``) that ticks at ``rate_hz`` with the controller's own
pacing code (:class:`controller.daemon.pacing.Pacer`, missed periods skipped) and does nothing
else: the floor loop of ``bench --hil`` (:mod:`hil.bench.socketcan`), run beside the session
instead of alone. Its longest period (wake-up to wake-up, :func:`probe`) is the longest stall
the platform gave a process of its priority in that window; the child inherits the caller's
niceness, so start it where the processes under test are started. 100 Hz by default: the stall
is known to 10 ms, which is fine beside bounds of 0.1-1 s, and the probe costs the session
little (inside User-Mode Linux every wake-up is a host round trip).
"""

from __future__ import annotations

import argparse
import json
import math
import signal
import subprocess
import sys
from typing import Any, Callable, Sequence

DEFAULT_RATE_HZ = 100.0


def probe(rate_hz: float, stop: Callable[[], bool], *, clock: Callable[[], float] | None = None,
          sleep: Callable[[float], None] | None = None, on_first_tick: Callable[[], None] = lambda: None) -> dict[str, Any]:
    """Tick at ``rate_hz`` until ``stop()`` (asked after each tick, the first included); the
    floor: ``max_period_s`` (the longest period, the platform's longest stall of this process,
    the nominal period included; None before a second tick), ``ticks``, ``late_ticks`` (periods
    over 1.5 nominal), ``skipped``, ``period_s``, ``period_jitter_us`` (|period - nominal|:
    median, p99, max, as the controller's pacer reports its own). ``clock``/``sleep``: the pacer's (a test's own
    clock; default the monotonic clock). ``on_first_tick``: called once the first tick is done."""
    from controller.daemon.pacing import Pacer

    if not (math.isfinite(rate_hz) and rate_hz > 0):
        raise ValueError(f"rate_hz must be positive, got {rate_hz!r}")
    kw: dict[str, Any] = {}
    if clock is not None:
        kw["clock"] = clock
    if sleep is not None:
        kw["sleep"] = sleep
    pacer = Pacer(1.0 / rate_hz, catch_up=False, **kw)
    pacer.wait()
    on_first_tick()
    while not stop():
        pacer.wait()
    s = pacer.summary()
    periods = max(0, s["ticks"] - 1)
    return {"rate_hz": rate_hz, "period_s": pacer.period_s, "ticks": s["ticks"], "late_ticks": s["late_ticks"],
            "skipped": s["skipped"], "max_period_s": pacer.max_period_s if periods else None,
            "period_jitter_us": s["period_jitter_us"]}


def side_by_side(figure: float | None, floor: float | None) -> dict[str, Any]:
    """A figure beside its floor: ``{"hil", "floor", "ratio", "excess"}`` (ratio = figure / floor,
    None when the floor is 0 or either is missing; excess = figure - floor)."""
    ratio = None
    if figure is not None and floor is not None and floor > 0:
        ratio = figure / floor
    excess = None if figure is None or floor is None else figure - floor
    return {"hil": figure, "floor": floor, "ratio": ratio, "excess": excess}


class FloorProbe:
    """The probe process beside a session: :meth:`start`, then :meth:`stop` returns its figures
    (:func:`probe`'s, plus ``error``: None, or why there are none; ``max_period_s`` is then None).
    ``prefix``: words put before the command (a ``nice`` that gives it the priority of the
    processes it stands beside)."""

    def __init__(self, rate_hz: float = DEFAULT_RATE_HZ, prefix: Sequence[str] = ()) -> None:
        self.rate_hz = rate_hz
        self.prefix = list(prefix)  # e.g. ["nice", "-n", "-10"]: start it as the processes it stands beside
        self.proc: subprocess.Popen | None = None
        self.result: dict[str, Any] | None = None

    def start(self) -> FloorProbe:
        """Start the probe and wait until it ticks (its window then covers what follows)."""
        self.proc = subprocess.Popen([*self.prefix, sys.executable, "-m", "hil.bench.floor", "--rate-hz", str(self.rate_hz)],
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, stdin=subprocess.DEVNULL)
        line = self.proc.stdout.readline() if self.proc.stdout is not None else ""
        if line.strip() != "ready":
            self.result = self._failed(f"the floor probe did not start: {line.strip()!r}")
        return self

    def _failed(self, why: str) -> dict[str, Any]:
        return {"rate_hz": self.rate_hz, "period_s": 1.0 / self.rate_hz, "ticks": 0, "late_ticks": 0, "skipped": 0,
                "max_period_s": None, "error": why}

    def stop(self) -> dict[str, Any]:
        """Stop the probe (SIGTERM) and return its figures; idempotent."""
        if self.proc is None:
            return self._failed("the floor probe was not started")
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
        try:
            out, err = self.proc.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            out, err = self.proc.communicate()
        if self.result is not None:
            return self.result
        lines = [ln for ln in (out or "").splitlines() if ln.startswith("{")]
        if self.proc.returncode != 0 or not lines:
            self.result = self._failed(f"the floor probe exited {self.proc.returncode}: {(err or '')[-500:].strip()}")
        else:
            self.result = {**json.loads(lines[-1]), "error": None}
        return self.result

    def __enter__(self) -> FloorProbe:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m hil.bench.floor",
                                description="tick, doing nothing, until SIGTERM; print the longest period (JSON)")
    p.add_argument("--rate-hz", type=float, default=DEFAULT_RATE_HZ)
    a = p.parse_args(argv)
    flag = {"stop": False}
    signal.signal(signal.SIGTERM, lambda *_: flag.update(stop=True))
    signal.signal(signal.SIGINT, lambda *_: flag.update(stop=True))
    result = probe(a.rate_hz, lambda: flag["stop"], on_first_tick=lambda: print("ready", flush=True))
    print(json.dumps(result), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
