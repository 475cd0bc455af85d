"""The deployment dry run end to end over SocketCAN (natively where the kernel has vcan, else
inside User-Mode Linux): ``elegant-stepping dryrun`` runs the systemd unit's own ExecStart, the
leg's ``elegant-stepping-leg run``, against firmware-sim on vcan0 and plays systemd's notify socket."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest


def test_the_deployment_dry_run_against_the_simulated_leg(tmp_path):
    """systemd's part and the person's, played in full: the unit's own ExecStart (only --config
    swapped for a copy of configs/sim.toml that waits for a person) as a separate process against
    firmware-sim on vcan0, NOTIFY_SOCKET and WATCHDOG_USEC from the unit; READY when inactive,
    `status`, `arm` walks, `estop` stops, a restart keeps it stopped (arm refused: the e-stop is
    latched in the drivers), `clear-faults` then `arm` walks again; regular pings, STOPPING after
    SIGTERM, exit 0."""
    from hil.profile import named
    from hil.uml.runner import VcanUnavailable, where

    try:
        where("auto")
    except VcanUnavailable as exc:
        pytest.fail(f"this test needs a SocketCAN vcan0: {exc}", pytrace=False)
    out = tmp_path / "dryrun"
    seconds = 6.0
    done = subprocess.run([sys.executable, "-m", "hil.cli", "dryrun", "--seconds", str(seconds), "--out", str(out),
                           "--quiet"], capture_output=True, text=True, timeout=600, stdin=subprocess.DEVNULL)
    path = out / "dryrun.json"
    assert path.exists(), f"no report (exit {done.returncode}):\n{done.stdout[-3000:]}\n{done.stderr[-3000:]}"
    report = json.loads(path.read_text())
    failed = [c for c in report["checks"] if not c["ok"]]
    log = (out / "controller.log").read_text()[-3000:] if (out / "controller.log").exists() else ""
    assert done.returncode == 0 and report["ok"] and not failed, f"{done.stdout}\n{failed}\n{report['error']}\n{log}"
    notes = report["notifications"]
    checks = {c["check"] for c in report["checks"]}
    assert {"status while inactive", "arm walks the leg", "estop stops it", "stays stopped across a restart",
            "clear-faults, then arm walks again"} <= checks
    pids = report["daemon_pids"]
    assert len(pids) == 2 and {n["pid"] for n in notes} == set(pids)  # each from its daemon's main pid
    assert [o["verb"] for o in report["operator"] if o["verb"] != "status"] == ["arm", "estop", "arm", "clear-faults", "arm"]
    assert [o["exit"] for o in report["operator"] if o["verb"] == "arm"] == [0, 1, 0]
    notes = [n for n in notes if n["pid"] == pids[-1]]  # the restarted daemon's
    ready = next(i for i, n in enumerate(notes) if n.get("READY") == "1")
    stopping = next(i for i, n in enumerate(notes) if n.get("STOPPING") == "1")
    assert ready < stopping and notes[ready]["STATUS"].startswith("inactive")
    assert report["watchdog_usec"] == 1_000_000
    assert report["format"] == "dryrun" and report["format_version"] == 1
    pings = [n["t_s"] for n in notes[ready:stopping] if n.get("WATCHDOG") == "1"]
    assert len(pings) >= 2.0 / 0.5 * 0.5  # every 0.5 s (this daemon runs at least 2 s after its READY)
    # Never a gap systemd would have killed it for, on this platform: WatchdogSec, plus the
    # platform's longest stall measured beside the daemon in this very run (a process doing no
    # work at the daemon's priority), once for the daemon's loop and once for the listener that
    # stamps each ping's arrival (hil.profile.Profile.late_allowance_s; the dry run's own check).
    # No fixed wall-clock budget: natively the stall is a few ms and the limit is WatchdogSec.
    floor = report["floor"]
    assert floor["error"] is None and floor["ticks"] > 0 and floor["max_period_s"] >= floor["period_s"], floor
    stall_s = floor["max_period_s"]
    limit_s = report["watchdog_usec"] / 1e6 + named(report["where"]).late_allowance_s(stall_s, stall_s)
    assert max(np.diff(pings)) < limit_s, (max(np.diff(pings)), floor)
    assert any(n.get("STATUS", "").endswith("walking") for n in notes[ready:stopping])
    assert report["final"]["stopped_by"] == "SIGTERM" and report["final"]["steps"] > 0
    assert report["final"]["sd_notify"]["errors"] == 0
    assert report["exec_start"][-2:] == ["--config", "/etc/elegant-stepping/leg.toml"]
    assert report["ran"][-2] == "--config" and report["ran"][-1].endswith(".toml")
