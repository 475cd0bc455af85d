"""``elegant-stepping bringup`` over real SocketCAN: against ``firmware-sim`` on vcan0, and against
an empty vcan0. Natively where the kernel has vcan, else inside User-Mode Linux (one VM boot for
both: tests/vcan/bringup_vcan_session.py). Without either these tests FAIL with what to install; to
leave them out on purpose: ``python3 -m pytest -m 'not vcan'``.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from hil.uml.runner import VcanUnavailable, run_in_uml, where

SESSION = Path(__file__).resolve().parent / "bringup_vcan_session.py"
ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    try:
        place = where("auto")
    except VcanUnavailable as exc:
        pytest.fail(f"this test needs a SocketCAN vcan0: {exc}", pytrace=False)
    out = tmp_path_factory.mktemp("bringup")
    argv = [sys.executable, str(SESSION), str(out)]
    if place == "native":
        done = subprocess.run(argv, capture_output=True, text=True, timeout=300, cwd=ROOT)
    else:
        done = run_in_uml(argv, timeout_s=240, capture=True, cwd=ROOT)
    path = out / "session.json"
    assert path.exists(), f"the session wrote nothing (exit {done.returncode}):\n{(done.stdout or '')[-3000:]}"
    return json.loads(path.read_text()), out



def test_bringup_passes_against_firmware_sim(session):
    s, out = session
    assert s["firmware_ready_s"] is not None, "firmware-sim sent no heartbeat"
    b = s["bringup"]
    assert b["rc"] == 0, f"{b['stdout']}\n{b['stderr']}"
    report = json.loads((out / "bringup.json").read_text())
    assert report["passed"] and report["counts"]["FAIL"] == 0, report["summary"]
    names = {i["name"] for i in report["items"]}
    for axis in ("hip", "knee"):
        assert {f"{axis}: move", f"{axis}: move back", f"{axis}: IDLE"} <= names
    assert all(i["status"] == "PASS" for i in report["items"]), [i for i in report["items"] if i["status"] != "PASS"]
    assert {a["state_at_end"] for a in report["axes"].values()} == {"IDLE"}
    assert "passed, 0 failed" in b["stdout"]
    assert s["firmware_rc"] == 0



def test_bringup_fails_fast_on_an_empty_bus(session):
    s, out = session
    silent = s["silent"]
    assert silent["rc"] == 1, f"{silent['stdout']}\n{silent['stderr']}"
    assert "no frame at all on vcan0" in silent["stdout"] and "termination" in silent["stdout"]
    report = json.loads((out / "silent.json").read_text())
    assert [i["status"] for i in report["items"]] == ["FAIL"]  # nothing after the listen: no check waits
    # Fast: it listened its whole window (1.5 s, measured by the command itself) and not longer
    # than the window plus one poll of the bus plus the platform's longest stall measured beside it
    # in this very session (hil.profile.Profile.late_allowance_s): no fixed wall-clock budget.
    from controller.bringup.procedure import BringupConfig
    from hil.profile import named

    cfg, floor = BringupConfig(), s["silent_floor"]
    assert floor["error"] is None and floor["ticks"] > 0, floor
    assert report["elapsed_s"] >= cfg.listen_s - 1e-3  # (rounded to 0.1 ms in the report)
    limit_s = cfg.listen_s + cfg.poll_s + named(s["where"]).late_allowance_s(floor["max_period_s"])
    assert report["elapsed_s"] <= limit_s, (report["elapsed_s"], floor)
