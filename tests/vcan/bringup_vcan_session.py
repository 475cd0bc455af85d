"""One bring-up session on a kernel with vcan0 (natively, or inside User-Mode Linux): run by
tests/vcan/test_bringup_vcan.py, not collected by pytest.

1. ``elegant-stepping bringup --channel vcan0`` with nothing else on vcan0: must fail fast; the
   platform's floor (:class:`hil.bench.floor.FloorProbe`) is measured beside it, for the test's
   bound on how long it may take;
2. ``elegant-stepping firmware-sim --channel vcan0`` started, waited for (its first heartbeat),
   then ``elegant-stepping bringup --channel vcan0 --json OUT/bringup.json``: must pass;
3. firmware-sim stopped with SIGTERM.

Usage: python3 tests/vcan/bringup_vcan_session.py OUT_DIR. Writes OUT_DIR/session.json (each
command's exit code, wall time and output; ``silent_floor``: the floor beside the first) and exits
0 once everything ran (the test judges).
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import can

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # a script: the repository's packages, as its children get them
from hil.bench.floor import FloorProbe  # noqa: E402
from hil.profile import current  # noqa: E402

CHANNEL = "vcan0"
HEARTBEAT_CMD = 0x01


def run(argv: list[str], timeout_s: float) -> dict:
    t0 = time.monotonic()
    done = subprocess.run(argv, capture_output=True, text=True, timeout=timeout_s, stdin=subprocess.DEVNULL)
    return {"argv": argv, "rc": done.returncode, "wall_s": round(time.monotonic() - t0, 3),
            "stdout": done.stdout[-6000:], "stderr": done.stderr[-4000:]}


def wait_for_heartbeat(timeout_s: float) -> float | None:
    """Seconds until an axis heartbeat is heard on vcan0, or None."""
    bus = can.Bus(interface="socketcan", channel=CHANNEL)
    t0 = time.monotonic()
    try:
        while time.monotonic() - t0 < timeout_s:
            msg = bus.recv(timeout=0.5)
            if msg is not None and not msg.is_remote_frame and msg.arbitration_id & 0x1F == HEARTBEAT_CMD \
                    and msg.arbitration_id >> 5 != 16:
                return time.monotonic() - t0
    finally:
        bus.shutdown()
    return None


def main(out: Path) -> int:
    out.mkdir(parents=True, exist_ok=True)
    es = [sys.executable, "-m", "hil.cli"]
    with FloorProbe() as floor:
        silent = run(es + ["bringup", "--channel", CHANNEL, "--json", str(out / "silent.json")], 120)
    session: dict = {"where": current().name, "silent": silent, "silent_floor": floor.result}
    fw_log = (out / "firmware-sim.log").open("w")
    fw = subprocess.Popen(es + ["firmware-sim", "--channel", CHANNEL], stdout=subprocess.DEVNULL, stderr=fw_log,
                          stdin=subprocess.DEVNULL)
    try:
        session["firmware_ready_s"] = wait_for_heartbeat(120.0)
        if session["firmware_ready_s"] is not None:
            session["bringup"] = run(es + ["bringup", "--channel", CHANNEL, "--json", str(out / "bringup.json")], 180)
    finally:
        fw.send_signal(signal.SIGTERM)
        try:
            session["firmware_rc"] = fw.wait(timeout=30)
        except subprocess.TimeoutExpired:
            fw.kill()
            session["firmware_rc"] = fw.wait()
        fw_log.close()
    (out / "session.json").write_text(json.dumps(session, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main(Path(sys.argv[1])))
