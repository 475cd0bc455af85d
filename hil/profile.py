"""The platform profile: every timing allowance that differs between a native kernel and User-Mode Linux.

Where the kernel has no vcan, HIL sessions, the dry run and the bench run inside User-Mode Linux
(:mod:`hil.uml.runner`): one virtual CPU, near saturation, shared by the controller, the plant,
the recorder and the harness, where every wake-up and system call is a host ptrace round trip.
What the harness does differently there is decided here, once, by :func:`current`, and read
from the returned :class:`Profile` by every site; nothing else asks where it runs.

The reasons behind each value, and the sessions that measured them, are in docs/ and in the
modules that use them (:mod:`hil.faults.mitm` for the poll period).
"""

from __future__ import annotations

import dataclasses
import math
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from controller.config import ControllerConfig


@dataclass(frozen=True)
class Profile:
    """What differs between the platforms.

    Attributes:
        name: ``"native"`` or ``"uml"`` (as the metrics' ``where`` says it).
        mitm_poll_s: the man-in-the-middle node's pause after each batch of frames [s]; a longer
            one inside UML, where each wake-up is costly.
        plant_steps_per_wake: physics steps the firmware-sim process does per wake-up (the plant
            is paced in 1 ms or 2 ms slices).
        min_silence_periods: the least node-silence (and stale-heartbeat) timeout of the
            controller [heartbeat periods], or None to keep the configured one. Inside UML a node
            can look silent for a few hundred ms while the plant catches up; the drivers' own
            watchdogs still stop the leg, the controller only waits longer before calling a node lost.
        safe_state_tolerance_ms: the stall [ms] counted for a process on a real-time outcome's
            path when the session did not measure that process's stall (it did not report):
            :meth:`late_allowance_s`'s fallback, never used where a measurement exists.
        work_on_shm: write a session's files to /dev/shm and copy them out at the end (inside UML
            a write to the host's file system stalls the whole VM for its duration).
        coarse_time_preload: give the firmware-sim process the coarse-clock preload (PyBullet's
            profiler reads gettimeofday() several times a step, a trapped system call in UML).
        driver_watchdog_s: the drivers' command watchdog of a session's controller (its
            ``[drivers] watchdog_timeout_s``, which the controller writes to every driver through
            RxSdo at arming and reads back), or None to keep the configured one [s]. Inside UML
            the four processes of a fault session (plant, controller, man-in-the-middle node,
            harness) share one slow virtual CPU, and any one of them can stall for tens of ms;
            a longer watchdog keeps such a stall from stopping the leg, while the kill and silence
            rows still measure the drivers' watchdog, against the bound it gives.
    """

    name: str
    mitm_poll_s: float
    plant_steps_per_wake: int
    min_silence_periods: float | None
    safe_state_tolerance_ms: float
    work_on_shm: bool
    coarse_time_preload: bool
    driver_watchdog_s: float | None = None

    @property
    def uml(self) -> bool:
        return self.name == "uml"

    def controller_config(self, ctl: "ControllerConfig") -> "ControllerConfig":
        """``ctl`` as the controller runs on this platform: waiting at least
        :attr:`min_silence_periods` heartbeat periods (and as long for a stale heartbeat) before it
        calls a node lost; ``ctl`` itself natively."""
        if self.min_silence_periods is None:
            return ctl
        n = self.min_silence_periods
        return dataclasses.replace(ctl, silence_periods=max(n, ctl.silence_periods),
                                   stale_heartbeat_periods=max(n, ctl.stale_heartbeat_periods))

    def late_allowance_s(self, *stalls_s: float | None) -> float:
        """How far past its bound a real-time outcome of a session may come and still count as in
        time [s]: the sum of ``stalls_s``, each the longest stall *measured in that very session*
        of one process on the outcome's path, plus :data:`SCHEDULING_S`.

        Rule: a safety outcome that exists only in real time (every axis IDLE after a kill, a
        systemd watchdog ping every half WatchdogSec) is checked against its bound plus this,
        never against a fixed wall-clock budget: each process the outcome passes through (the
        plant whose clock runs the drivers' watchdogs, the man-in-the-middle node that forwards
        the last command, the daemon whose loop pings, the harness that stamps a ping's arrival)
        delays it by at most its own longest stall, and nothing else of the platform can. The
        stalls are the platform's floor as measured beside the session (a process's longest
        period, :class:`hil.bench.floor.FloorProbe` for a process doing no work); timing itself
        is reported by ``bench --hil``, not asserted. A stall that was not measured (None: the
        process did not report, NaN, negative) counts as :attr:`safe_state_tolerance_ms`, this
        platform's fixed fallback, so a missing measurement never widens the bound without limit.
        """
        total = SCHEDULING_S
        for stall in stalls_s:
            ok = stall is not None and isinstance(stall, (int, float)) and math.isfinite(stall) and stall >= 0
            total += float(stall) if ok else self.safe_state_tolerance_ms / 1e3
        return total

    def work_folder(self, out: Path, prefix: str) -> Path:
        """Where a session writes while it runs: ``out``, or a fresh folder on /dev/shm (if there)."""
        if self.work_on_shm and os.path.isdir("/dev/shm"):
            return Path(tempfile.mkdtemp(prefix=prefix, dir="/dev/shm"))
        return out


SCHEDULING_S = 0.001
"""One wake-up's latency on top of the measured stalls [s]: a process that becomes due is not run
the instant it is (:meth:`Profile.late_allowance_s`)."""

NATIVE = Profile(name="native", mitm_poll_s=0.0005, plant_steps_per_wake=1, min_silence_periods=None,
                 safe_state_tolerance_ms=20.0, work_on_shm=False, coarse_time_preload=False)
UML = Profile(name="uml", mitm_poll_s=0.002, plant_steps_per_wake=2, min_silence_periods=10.0,
              safe_state_tolerance_ms=50.0, work_on_shm=True, coarse_time_preload=True, driver_watchdog_s=0.3)
PROFILES = {p.name: p for p in (NATIVE, UML)}


def current() -> Profile:
    """The profile of the platform this process runs on: :data:`UML` inside a VM started by
    :mod:`hil.uml.runner`, else :data:`NATIVE`."""
    from hil.uml.runner import in_uml

    return UML if in_uml() else NATIVE


def named(where: str) -> Profile:
    """The profile of a metrics' ``where`` (``native`` or ``uml``; anything else counts as native)."""
    return PROFILES.get(where, NATIVE)
