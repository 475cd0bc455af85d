"""Hardware-in-the-loop over real SocketCAN: the controller and the leg as two processes on vcan0.

Runs natively where the kernel has vcan, else inside User-Mode Linux (``hil.uml.runner``). Where neither
can be had these tests FAIL with what to install: they never pass silently. To leave them out on
purpose: ``python3 -m pytest -m 'not vcan'``.

Two clocks (issue 16). What the session *does* (frames both ways, the axes armed, the learner's
updates, the records of ``learn`` for a seed, 5% frame loss, a silent node's safe stop) is checked in
simulated time (``hil --clock sim``), where a loaded host slows the session and changes nothing in
it. What exists only on the wall clock (the recording's timestamps and timing figures, replay of a
wall-clock session, every axis IDLE after a kill -9) is checked on a wall-clock session, with
bounds scaled by the stalls measured in that same session.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import can
import pytest

from hil.uml.runner import run_in_uml, smoke

TRIALS = 3



def test_python_can_sends_and_receives_on_vcan0(vcan_place):
    if vcan_place == "native":
        result = smoke("vcan0", 200)
    else:
        done = run_in_uml([sys.executable, "-m", "hil.uml.runner", "smoke", "--frames", "200"], timeout_s=180, capture=True)
        lines = [ln for ln in done.stdout.splitlines() if ln.startswith("{")]
        assert done.returncode == 0 and lines, done.stdout[-2000:]
        result = json.loads(lines[-1])
        assert result["in_uml"]
    assert result["round_trips"] == 200 and result["lost"] == 0


SIM_TRIALS = 3


@pytest.fixture(scope="module")
def sim_run(vcan_place, tmp_path_factory):
    out = tmp_path_factory.mktemp("hil_sim")
    cmd = [sys.executable, "-m", "hil.cli", "hil", "--clock", "sim", "--trials", str(SIM_TRIALS), "--seed", "0",
           "--out", str(out), "--log-format", "log", "--quiet"]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=1200, stdin=subprocess.DEVNULL)
    metrics_path = out / "metrics.json"
    assert metrics_path.exists(), f"hil wrote no metrics (exit {done.returncode}):\n{done.stdout[-3000:]}\n{done.stderr[-3000:]}"
    return done, json.loads(metrics_path.read_text()), out


def test_in_simulated_time_the_session_gives_learn_s_records(sim_run):
    """The done-when of issue 16, on 3 trials: the same seed gives, trial for trial and field for
    field (traces included), the in-process learning run's records."""
    from hil.analysis.records import compare
    from hil.experiments.learn import FIGURE_TRACES, LearnConfig, run_learning

    done, m, _ = sim_run
    assert done.returncode == 0, f"{m['hil']['error']}\n{done.stderr[-3000:]}"
    assert m["timing"]["clock"] == "sim" and m["hil"]["clock"] == "sim"
    learn = run_learning(LearnConfig(trials=SIM_TRIALS, seed=0, trace_trials=FIGURE_TRACES))
    result = compare(json.loads(json.dumps(learn)), m)
    assert result["same"], result
    assert any(t.get("trace") for t in m["trials"])  # the traces came through too
    sync = m["hil"]["sync"]
    assert sync["controller_gone"] is False and sync["plant"]["alone"] == 0 and sync["plant"]["stale_ends"] == 0
    # every sync answered (the opening one, sent until answered, without a tick)
    assert sync["plant"]["syncs"] >= sync["plant"]["ends"] == m["timing"]["ticks"] + 1


def test_in_simulated_time_frames_flow_both_ways_and_the_axes_arm(sim_run):
    _, m, _ = sim_run
    h = m["hil"]
    assert h["exit_codes"] == {"controller": 0, "firmware_sim": 0}
    assert h["bus"]["controller_to_leg"] > 1000 and h["bus"]["leg_to_controller"] > 1000
    assert h["frames_controller_tx"]["Set_Input_Pos"] > 1000
    for name in ("Heartbeat", "Get_Encoder_Estimates", "SB_Range", "SB_Contacts"):
        assert h["frames_controller_rx"].get(name, 0) > 0, name
    assert h["frames_controller_dropped"] == {}  # no sync, end of period or state reached the controller's BusIO
    assert h["firmware_host"]["rx"] > 1000 and h["firmware_host"]["unknown"] == 0  # ... nor the drivers
    assert [p for p in h["phases"] if p != "wait_nodes"][:3] == ["arming", "ramp", "walk"]
    assert h["axes_while_running"] == {"hip": "CLOSED_LOOP_CONTROL", "knee": "CLOSED_LOOP_CONTROL"}
    assert h["axes_at_end"] == {"hip": "IDLE", "knee": "IDLE"}  # put there by the controller's clean stop
    assert h["watchdog_expired_axes"] == 0 and "fault" not in h["phases"], h["fault_cause"]


def test_in_simulated_time_the_trials_complete_and_the_learner_updates(sim_run):
    _, m, out = sim_run
    assert m["hil"]["trials_completed"] == SIM_TRIALS and len(m["trials"]) == SIM_TRIALS
    assert sum(len(t["gated_cells"]) for t in m["trials"]) >= SIM_TRIALS  # decisions gated from the range sensor
    assert m["hil"]["reflexes"] > 0 and m["hil"]["weights_l1"] > 0.0  # the learner moved its weights
    assert (out / "weights.npz").exists()


def test_in_simulated_time_replay_is_the_live_run_tick_for_tick(sim_run):
    _, m, out = sim_run
    done = subprocess.run([sys.executable, "-m", "hil.cli", "replay", str(out / "bus.log"), "--json", "-"],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    result = json.loads(done.stdout)
    assert result["tick_source"] == "sync frames" and result["ticks"] == m["timing"]["ticks"]
    lost = result["frames_lost"]
    assert isinstance(lost, int) and lost >= 0, lost
    if lost:  # honest: the count, and no claim of a reproduction
        assert result["as_live"] is False and f"the recorder lost {lost} frame" in done.stderr
        return
    assert result["as_live"] is True and result["compared_steps"] > 10
    assert result["matching_steps"] == result["compared_steps"], result["mismatches"][:5]


@pytest.fixture(scope="module")
def hil_run(vcan_place, tmp_path_factory):
    out = tmp_path_factory.mktemp("hil")
    cmd = [sys.executable, "-m", "hil.cli", "hil", "--trials", str(TRIALS), "--seed", "0", "--out", str(out),
           "--log-format", "log", "--quiet"]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=900, stdin=subprocess.DEVNULL)
    metrics_path = out / "metrics.json"
    assert metrics_path.exists(), f"hil wrote no metrics (exit {done.returncode}):\n{done.stdout[-3000:]}\n{done.stderr[-3000:]}"
    return done, json.loads(metrics_path.read_text()), out



def test_the_session_ends_cleanly(hil_run):
    done, m, _ = hil_run
    assert done.returncode == 0, f"{m['hil']['error']}\n{done.stderr[-3000:]}"
    assert m["hil"]["exit_codes"] == {"controller": 0, "firmware_sim": 0}
    assert m["hil"]["where"] in ("native", "uml")











def test_the_bus_was_recorded_and_timing_reported(hil_run):
    _, m, out = hil_run
    log = out / "bus.log"
    n = sum(1 for _ in can.LogReader(str(log)))
    assert n == m["hil"]["bus"]["frames"] > 0
    t = m["timing"]
    assert t["ticks"] > 1000 and t["late_ticks"] >= 0
    assert set(t["period_jitter_us"]) >= {"median", "p99", "max"}
    assert t["command_to_feedback_us"]["median"] is not None and t["command_to_feedback_us"]["p99"] is not None
    # reported beside the platform's floor, measured in the same session (issue 16, part 2)
    assert t["clock"] == "wall" and t["floor"]["error"] is None and t["floor"]["ticks"] > 100, t["floor"]
    af = t["against_floor"]
    assert af["error"] is None and af["period_jitter_p99_us"]["hil"] == t["period_jitter_us"]["p99"]
    assert af["period_jitter_p99_us"]["floor"] == t["floor"]["period_jitter_us"]["p99"] is not None
    assert af["max_period_us"]["floor"] == pytest.approx(t["floor"]["max_period_s"] * 1e6)



def test_the_log_decodes_with_our_dbc(hil_run):
    _, _, out = hil_run
    done = subprocess.run([sys.executable, "-m", "hil.cli", "decode", str(out / "bus.log")],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert "Set_Input_Pos" in done.stdout and "Get_Encoder_Estimates" in done.stdout
    assert "Input_Pos=" in done.stdout



def test_replay_reproduces_the_controllers_decisions(hil_run):
    _, _, out = hil_run
    done = subprocess.run([sys.executable, "-m", "hil.cli", "replay", str(out / "bus.log"), "--json", "-"],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    result = json.loads(done.stdout)
    assert result["compared_steps"] > 10
    lost = result["frames_lost"]
    assert isinstance(lost, int) and lost >= 0, lost  # counted on SocketCAN (SO_RXQ_OVFL), never unknown here
    if lost:  # the replayed controller cannot read what the live one read: no reproduction is claimed
        assert result["as_live"] is False
        assert f"the recorder lost {lost} frame" in done.stderr and "not a reproduction" in done.stderr, done.stderr[-2000:]
        return
    assert result["as_live"] is True
    assert result["tick_source"] == "live ticks and frame counts"
    # With nothing lost, every decision is reproduced (issue 16). (Replay finds where the live
    # controller's reads start in the log from the median over all ticks, not from tick 0 alone,
    # which was 14-17 frames off inside User-Mode Linux and cost one decision in 42.)
    assert result["matching_steps"] == result["compared_steps"], result["mismatches"][:5]


# -- fault injection: kill -9 of the controller, frame loss through the man-in-the-middle node ------
KILL_TRIALS, KILL_AT = 3, 1
DROP_TRIALS = 3


def _hil(out: Path, *extra: str, trials: int) -> tuple[subprocess.CompletedProcess, dict]:
    cmd = [sys.executable, "-m", "hil.cli", "hil", "--trials", str(trials), "--seed", "0", "--out", str(out),
           "--log-format", "log", "--quiet", *extra]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=600, stdin=subprocess.DEVNULL)
    path = out / "metrics.json"
    assert path.exists(), f"hil wrote no metrics (exit {done.returncode}):\n{done.stdout[-3000:]}\n{done.stderr[-3000:]}"
    return done, json.loads(path.read_text())


@pytest.fixture(scope="module")
def kill_run(vcan_place, tmp_path_factory):
    return _hil(tmp_path_factory.mktemp("hil_kill"), "--kill-controller-at-trial", str(KILL_AT), trials=KILL_TRIALS)


@pytest.fixture(scope="module")
def drop_run(vcan_place, tmp_path_factory):
    return _hil(tmp_path_factory.mktemp("hil_drop"), "--clock", "sim", "--faults-to-leg", "drop=0.05",
                "--faults-from-leg", "drop=0.05", trials=DROP_TRIALS)


@pytest.fixture(scope="module")
def silence_run(vcan_place, tmp_path_factory):
    return _hil(tmp_path_factory.mktemp("hil_silence"), "--clock", "sim", "--silence-node", "0",
                "--silence-at-trial", "1", trials=3)


def test_a_silent_hip_stops_the_leg_safely_within_the_bound_in_simulated_time(silence_run):
    done, m = silence_run
    f, h = m["fault"], m["hil"]
    assert done.returncode == 0, f"{h['error']}\n{done.stderr[-3000:]}"
    assert f["kind"] == "silence" and f["clock"] == "sim" and f["node"] == 0
    assert h["trials_completed"] == 1 and f["silenced_at_sim_s"] is not None
    assert f["frames_silenced"] > 0
    assert h["controller_final_phase"] == "fault" and "hip" in (h["fault_cause"] or ""), h["fault_cause"]
    # the bound: the controller's silence timeout plus one heartbeat period, in simulated time,
    # so no allowance for the host: the same number on a loaded and a quiet machine
    assert f["safe_state_sim_ms"] is not None and f["within_bound"], f
    assert set(f["axes_idle_sim_ms"]) == {"hip", "knee"}
    assert h["axes_at_end"] == {"hip": "IDLE", "knee": "IDLE"}



def test_kill_9_of_the_controller_leaves_every_axis_idle_within_the_bound(kill_run):
    done, m = kill_run
    f, h = m["fault"], m["hil"]
    assert done.returncode == 0, f"{h['error']}\n{done.stderr[-3000:]}"
    assert f["kind"] == "kill" and f["at_trial"] == KILL_AT and h["trials_completed"] == KILL_AT
    assert f["states_before"] == {"hip": "CLOSED_LOOP_CONTROL", "knee": "CLOSED_LOOP_CONTROL"}
    # The bound: the drivers' watchdog (0.1 s, or the platform's allowance inside User-Mode Linux,
    # which the controller wrote to the drivers at arming) plus one heartbeat period (0.1 s), as
    # the leg's heartbeats show it. Every axis IDLE is the outcome asserted; no wall-clock budget
    # is: both run on the plant process's clock, so the slack is the longest stall the plant had
    # in this very session (its longest period), as the platform profile adds it
    # (hil.profile.Profile.late_allowance_s), the rule the session's own ``within_bound`` uses. A
    # kill alone runs with no man-in-the-middle node: the leg shares the controller's channel.
    from hil.profile import named

    profile = named(h["where"])
    watchdog_ms = (profile.driver_watchdog_s or 0.1) * 1e3
    assert f["bound_ms"] == pytest.approx(watchdog_ms + 100.0)
    stalls_ms = f["stalls_ms"]
    assert f["mitm"] is None and f["channels"] == {"controller": "vcan0", "leg": "vcan0"}
    assert set(stalls_ms) == {"plant"} and None not in stalls_ms.values(), stalls_ms  # measured, no fallback
    assert stalls_ms["plant"] == pytest.approx(m["timing"]["firmware"]["max_period_us"] / 1e3)
    slack_ms = profile.late_allowance_s(*(v / 1e3 for v in stalls_ms.values())) * 1e3
    assert f["tolerance_ms"] == pytest.approx(slack_ms)
    assert f["safe_state_ms"] is not None and f["within_bound"], f
    assert f["safe_state_ms"] <= f["bound_ms"] + slack_ms, f
    for axis in ("hip", "knee"):  # each driver went IDLE on its watchdog, before its heartbeat said so
        assert f["driver_idle_ms"][axis] is not None
        assert f["driver_idle_ms"][axis] <= watchdog_ms + slack_ms, f
        # the same instant on two clocks (the plant's monotonic wake-up, the heartbeat's kernel
        # timestamp), each taken against the kill on its own clock: an order, not a duration
        assert f["driver_idle_ms"][axis] <= f["axes_idle_ms"][axis] + 5.0
    assert f["watchdog_trips_after_event"] == 2  # both axes stopped by their own watchdogs
    assert f["axes_after"] == {"hip": "IDLE", "knee": "IDLE"}



def test_after_the_kill_the_session_ends_cleanly(kill_run):
    _, m = kill_run
    f, h = m["fault"], m["hil"]
    assert h["exit_codes"] == {"controller": -9, "firmware_sim": 0}  # -9: killed on purpose
    assert f["controller_exit_expected"] and f["mitm_exit_code"] is None  # no mitm node in a kill alone
    assert f["commands"]["controller_outside_limits"] == 0 and f["commands"]["driver_targets_outside_limits"] == 0
    assert not (f["weights"]["exists"] and not f["weights"]["loads"])  # no half-written weights



def test_frames_flow_through_the_mitm_with_5_percent_loss(drop_run):
    done, m = drop_run
    f, h = m["fault"], m["hil"]
    assert done.returncode == 0, f"{h['error']}\n{done.stderr[-3000:]}"
    assert f["kind"] == "rate" and f["clock"] == "sim" and f["mitm_exit_code"] == 0
    assert f["mitm"]["clock"] == "sim"
    for direction in ("to_leg", "from_leg"):
        c = f["mitm"][direction]
        assert c["frames_in"] > 1000, c
        faultable = c["frames_in"] - c["sim_frames"]  # sync, end of period and state frames pass untouched
        assert 0.02 < c["drop"] / faultable < 0.08, c
        assert c["forwarded"] == c["frames_in"] - c["drop"] and c["send_errors"] == 0, c
    assert h["sync"]["controller_gone"] is False and h["sync"]["plant"]["alone"] == 0
    assert h["bus"]["leg_to_controller"] == f["mitm"]["from_leg"]["forwarded"]  # the recorder is on the controller's side
    assert h["firmware_host"]["rx"] > 1000



def test_with_5_percent_loss_the_axes_stay_in_closed_loop_and_the_trials_complete(drop_run):
    _, m = drop_run
    h = m["hil"]
    assert h["trials_completed"] == DROP_TRIALS and len(m["trials"]) == DROP_TRIALS
    assert h["axes_while_running"] == {"hip": "CLOSED_LOOP_CONTROL", "knee": "CLOSED_LOOP_CONTROL"}
    assert "fault" not in h["phases"], h["fault_cause"]
    assert h["watchdog_expired_axes"] == 0
    assert h["axes_at_end"] == {"hip": "IDLE", "knee": "IDLE"}
