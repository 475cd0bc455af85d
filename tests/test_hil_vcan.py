"""Hardware-in-the-loop over real SocketCAN: the controller and the leg as two processes on vcan0.

Runs natively where the kernel has vcan, else inside User-Mode Linux (``hil.uml``). Where neither
can be had these tests FAIL with what to install: they never pass silently. To leave them out on
purpose: ``python3 -m pytest -m 'not vcan'``.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import can
import pytest

from hil.uml import VcanUnavailable, run_in_uml, smoke, where

TRIALS = 5


@pytest.fixture(scope="module")
def vcan_place() -> str:
    try:
        return where("auto")
    except VcanUnavailable as exc:
        pytest.fail(f"this test needs a SocketCAN vcan0: {exc}", pytrace=False)


@pytest.mark.vcan
def test_python_can_sends_and_receives_on_vcan0(vcan_place):
    if vcan_place == "native":
        result = smoke("vcan0", 200)
    else:
        done = run_in_uml([sys.executable, "-m", "hil.uml", "smoke", "--frames", "200"], timeout_s=180, capture=True)
        lines = [ln for ln in done.stdout.splitlines() if ln.startswith("{")]
        assert done.returncode == 0 and lines, done.stdout[-2000:]
        result = json.loads(lines[-1])
        assert result["in_uml"]
    assert result["round_trips"] == 200 and result["lost"] == 0


@pytest.fixture(scope="module")
def hil_run(vcan_place, tmp_path_factory):
    out = tmp_path_factory.mktemp("hil")
    cmd = [sys.executable, "-m", "hil.cli", "hil", "--trials", str(TRIALS), "--seed", "0", "--out", str(out),
           "--log-format", "log", "--quiet"]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=900, stdin=subprocess.DEVNULL)
    metrics_path = out / "metrics.json"
    assert metrics_path.exists(), f"hil wrote no metrics (exit {done.returncode}):\n{done.stdout[-3000:]}\n{done.stderr[-3000:]}"
    return done, json.loads(metrics_path.read_text()), out


@pytest.mark.vcan
def test_the_session_ends_cleanly(hil_run):
    done, m, _ = hil_run
    assert done.returncode == 0, f"{m['hil']['error']}\n{done.stderr[-3000:]}"
    assert m["hil"]["exit_codes"] == {"controller": 0, "firmware_sim": 0}
    assert m["hil"]["where"] in ("native", "uml")


@pytest.mark.vcan
def test_frames_flowed_both_ways(hil_run):
    _, m, _ = hil_run
    h = m["hil"]
    assert h["bus"]["controller_to_leg"] > 1000 and h["bus"]["leg_to_controller"] > 1000
    assert h["frames_controller_tx"]["Set_Input_Pos"] > 1000
    for name in ("Heartbeat", "Get_Encoder_Estimates", "SB_Range", "SB_Contacts"):
        assert h["frames_controller_rx"].get(name, 0) > 0, name
    assert h["firmware_host"]["rx"] > 1000  # the drivers heard the controller


@pytest.mark.vcan
def test_the_axes_reached_closed_loop_control(hil_run):
    _, m, _ = hil_run
    h = m["hil"]
    assert [p for p in h["phases"] if p != "wait_nodes"][:3] == ["arming", "ramp", "walk"]  # ramp begins only once both axes are closed loop
    assert h["axes_while_running"] == {"hip": "CLOSED_LOOP_CONTROL", "knee": "CLOSED_LOOP_CONTROL"}
    assert h["axes_at_end"] == {"hip": "IDLE", "knee": "IDLE"}  # put there by the controller's clean stop


@pytest.mark.vcan
def test_the_trials_completed_and_the_learner_updated(hil_run):
    _, m, out = hil_run
    assert m["hil"]["trials_completed"] == TRIALS and len(m["trials"]) == TRIALS
    assert m["summary"]["trials"] == TRIALS
    assert all(t["sim_s"] > 3.0 for t in m["trials"])
    assert sum(len(t["gated_cells"]) for t in m["trials"]) >= TRIALS  # decisions gated from the range sensor
    assert any(c is not None for t in m["trials"] for c in t["gated_cells"])
    assert m["hil"]["reflexes"] > 0 and m["hil"]["weights_l1"] > 0.0  # the learner moved its weights
    assert (out / "weights.npz").exists()


@pytest.mark.vcan
def test_no_watchdog_tripped_and_no_safe_stop(hil_run):
    _, m, _ = hil_run
    assert m["hil"]["watchdog_trips"] == 0
    assert "fault" not in m["hil"]["phases"], m["hil"]["fault_cause"]


@pytest.mark.vcan
def test_the_bus_was_recorded_and_timing_reported(hil_run):
    _, m, out = hil_run
    log = out / "bus.log"
    n = sum(1 for _ in can.LogReader(str(log)))
    assert n == m["hil"]["bus"]["frames"] > 0
    t = m["timing"]
    assert t["ticks"] > 1000 and t["late_ticks"] >= 0
    assert set(t["period_jitter_us"]) >= {"median", "p99", "max"}
    assert t["command_to_feedback_us"]["median"] is not None and t["command_to_feedback_us"]["p99"] is not None


@pytest.mark.vcan
def test_the_log_decodes_with_our_dbc(hil_run):
    _, _, out = hil_run
    done = subprocess.run([sys.executable, "-m", "hil.cli", "decode", str(out / "bus.log")],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert "Set_Input_Pos" in done.stdout and "Get_Encoder_Estimates" in done.stdout
    assert "Input_Pos=" in done.stdout


@pytest.mark.vcan
def test_replay_reproduces_the_controllers_decisions(hil_run):
    _, _, out = hil_run
    done = subprocess.run([sys.executable, "-m", "hil.cli", "replay", str(out / "bus.log"), "--json", "-"],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    result = json.loads(done.stdout)
    assert result["compared_steps"] > 10
    assert result["matching_steps"] / result["compared_steps"] >= 0.95, result["mismatches"][:5]


def test_where_fails_with_an_instruction_when_nothing_gives_vcan(monkeypatch):
    import hil.uml as uml

    monkeypatch.setattr(uml, "native_vcan", lambda channel="vcan0", create=True: False)
    monkeypatch.setattr(uml, "uml_missing", lambda: "linux.uml not found")
    monkeypatch.delenv(uml.ENV_IN_UML, raising=False)
    with pytest.raises(VcanUnavailable, match="apt-get install -y user-mode-linux kmod"):
        uml.where("auto")
    with pytest.raises(VcanUnavailable, match="not vcan"):
        uml.where("auto")


def test_the_runner_is_shipped_with_the_project():
    root = Path(__file__).resolve().parents[1]
    for name in ("run-in-uml.sh", "uml-init", "xstate-shim.c", "coarse-time.c"):
        assert (root / "hil" / "uml" / name).exists(), name
