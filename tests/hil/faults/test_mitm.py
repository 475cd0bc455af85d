"""The man-in-the-middle node's logic on python-can ``virtual`` buses, the safe-state timing from
heartbeats, and the HIL fault options (no vcan needed)."""

from __future__ import annotations

import argparse
import uuid

import can
import pytest

from hil.faults.model import FaultSpec
from hil.faults.session import FaultPlan, add_hil_fault_args, weights_state
from hil.session.legwatch import Beat, safe_state
from hil.faults.mitm import ManInTheMiddle
from protocol import AxisState
from tests.fakes import drain


def _pair():
    """(the controller's end, the node's end) of one virtual channel."""
    name = f"mitm-test-{uuid.uuid4().hex[:8]}"
    return (can.Bus(interface="virtual", channel=name, receive_own_messages=False),
            can.Bus(interface="virtual", channel=name, receive_own_messages=False))


@pytest.fixture
def buses():
    ctl, ctl_node = _pair()
    leg, leg_node = _pair()
    yield ctl, ctl_node, leg, leg_node
    for b in (ctl, ctl_node, leg, leg_node):
        b.shutdown()


def _frame(arb: int, payload: bytes = b"\x01\x02\x03\x04") -> can.Message:
    return can.Message(arbitration_id=arb, data=payload, is_extended_id=False)


def test_frames_pass_both_ways_unchanged_without_faults(buses):
    ctl, ctl_node, leg, leg_node = buses
    node = ManInTheMiddle(ctl_node, leg_node)
    for i in range(20):
        ctl.send(_frame(0x00C, bytes([i]) * 8))
        leg.send(_frame(0x009, bytes([i, 1]) * 4))
    node.pump(0.0)
    to_leg, from_leg = drain(leg), drain(ctl)
    assert [bytes(m.data) for m in to_leg] == [bytes([i]) * 8 for i in range(20)]
    assert [bytes(m.data) for m in from_leg] == [bytes([i, 1]) * 4 for i in range(20)]
    s = node.summary()
    assert s["to_leg"]["frames_in"] == s["to_leg"]["forwarded"] == 20
    assert s["from_leg"]["frames_in"] == s["from_leg"]["forwarded"] == 20
    assert s["to_leg"]["drop"] == s["from_leg"]["corrupt"] == 0


def test_drop_rate_is_counted_and_seeded(buses):
    ctl, ctl_node, leg, leg_node = buses

    def run(seed: int) -> tuple[int, dict]:
        node = ManInTheMiddle(ctl_node, leg_node, to_leg=FaultSpec(drop=0.2), seed=seed)
        for i in range(500):
            ctl.send(_frame(0x00C))
        node.pump(0.0)
        return len(drain(leg)), node.summary()["to_leg"]

    n1, c1 = run(3)
    n2, c2 = run(3)
    assert n1 == n2 == 500 - c1["drop"] and c1 == c2  # same seed, same faults
    assert 60 <= c1["drop"] <= 140  # 20% of 500, well within 4 sigma
    assert c1["forwarded"] == n1


def test_delayed_frames_leave_when_due(buses):
    ctl, ctl_node, leg, leg_node = buses
    node = ManInTheMiddle(ctl_node, leg_node, from_leg=FaultSpec(delay=1.0, delay_s=0.004))
    leg.send(_frame(0x001))
    node.pump(10.0)
    assert drain(ctl) == []
    assert node.summary()["from_leg"]["in_flight"] == 1
    node.pump(10.003)
    assert drain(ctl) == []
    node.pump(10.0041)
    assert len(drain(ctl)) == 1 and node.summary()["from_leg"]["delay"] == 1


def test_silencing_drops_only_that_nodes_frames_to_the_controller(buses):
    ctl, ctl_node, leg, leg_node = buses
    node = ManInTheMiddle(ctl_node, leg_node, silence_node=0)
    leg.send(_frame(0x001))  # hip heartbeat, before the silence
    node.pump(0.0)
    assert len(drain(ctl)) == 1
    node.start_silence(1.0)
    for arb in (0x001, 0x009, 0x021, 0x029, 0x208):  # hip x2, knee x2, sensor board
        leg.send(_frame(arb))
    ctl.send(_frame(0x00C))  # the controller's command to the hip still gets through
    node.pump(1.0)
    assert sorted(m.arbitration_id for m in drain(ctl)) == [0x021, 0x029, 0x208]
    assert [m.arbitration_id for m in drain(leg)] == [0x00C]
    s = node.summary()
    assert s["from_leg"]["silenced"] == 2 and s["silence"]["node"] == 0 and s["silence"]["started_mono"] == 1.0


def test_corrupted_frames_reach_the_other_side_changed(buses):
    ctl, ctl_node, leg, leg_node = buses
    node = ManInTheMiddle(ctl_node, leg_node, to_leg=FaultSpec(corrupt=1.0), seed=1)
    payload = bytes(range(8))
    for _ in range(50):
        ctl.send(_frame(0x00C, payload))
    node.pump(0.0)
    got = drain(leg)
    assert len(got) == 50 and all(bytes(m.data) != payload for m in got)
    assert node.summary()["to_leg"]["corrupt"] == 50


def test_safe_state_is_the_last_axis_first_idle_after_the_event():
    closed, idle = int(AxisState.CLOSED_LOOP_CONTROL), int(AxisState.IDLE)
    beats = [Beat(99.95, "hip", closed, 0), Beat(99.97, "knee", closed, 0),
             Beat(100.05, "hip", closed, 0), Beat(100.07, "knee", idle, 1),
             Beat(100.15, "hip", idle, 1), Beat(100.17, "knee", idle, 1)]
    r = safe_state(beats, ["hip", "knee"], 100.0)
    assert r["safe_state_ms"] == pytest.approx(150.0)
    assert r["axes_idle_ms"]["knee"] == pytest.approx(70.0)
    assert r["states_before"] == {"hip": "CLOSED_LOOP_CONTROL", "knee": "CLOSED_LOOP_CONTROL"}
    never = safe_state(beats[:4], ["hip", "knee"], 100.0)
    assert never["safe_state_ms"] is None and never["axes_idle_ms"]["hip"] is None


def _hil_args(*argv: str) -> argparse.Namespace:
    p = argparse.ArgumentParser()
    p.add_argument("--seed", type=int, default=0)
    add_hil_fault_args(p)
    return p.parse_args(list(argv))


def test_fault_options_make_a_plan_and_round_trip():
    assert FaultPlan.from_args(_hil_args()) is None  # no fault option: the session stays as it was
    plan = FaultPlan.from_args(_hil_args("--kill-controller-at-trial", "1", "--faults-to-leg", "drop=0.05",
                                         "--seed", "4"))
    assert plan.kind == "kill" and plan.event_trial == 1 and plan.seed == 4
    assert FaultPlan.from_args(_hil_args(*plan.argv(), "--seed", "4")) == plan
    silence = FaultPlan.from_args(_hil_args("--silence-node", "0", "--silence-at-trial", "2"))
    assert silence.kind == "silence" and silence.silence_node == 0
    assert FaultPlan.from_args(_hil_args("--faults-from-leg", "delay=0.1")).kind == "rate"


@pytest.mark.parametrize("argv", [("--silence-node", "0"), ("--faults-to-leg", "drop=2"),
                                  ("--faults-to-leg", "lose=0.1"),
                                  ("--kill-controller-at-trial", "1", "--silence-node", "0", "--silence-at-trial", "1")])
def test_bad_fault_options_are_refused(argv):
    with pytest.raises(ValueError):
        FaultPlan.from_args(_hil_args(*argv))


def test_weights_state_tells_missing_from_damaged(tmp_path):
    assert weights_state(tmp_path / "weights.npz")["exists"] is False
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"PK\x03\x04 not really")
    s = weights_state(bad)
    assert s["exists"] and not s["loads"] and s["error"]


# -- the mitm's counts file: stamped, checked ------------------------------------------------------
def test_the_counts_file_is_stamped_and_read_back_without_the_stamp(tmp_path):
    import json

    from controller.errors import InputError
    from hil.faults.mitm import COUNTS_KIND, _write_json, read_counts

    path = tmp_path / "mitm.json"
    _write_json(path, {"to_leg": {"frames_in": 3}, "pacing": {"max_gap_ms": 2.5}})
    raw = json.loads(path.read_text())
    assert list(raw)[:3] == ["format", "format_version", "project_version"]
    assert raw["format"] == COUNTS_KIND == "mitm-counts" and raw["format_version"] == 1
    assert read_counts(path) == {"to_leg": {"frames_in": 3}, "pacing": {"max_gap_ms": 2.5}}
    raw["format_version"] = 99
    path.write_text(json.dumps(raw))
    with pytest.raises(InputError) as info:
        read_counts(path)
    assert "mitm-counts format version 99" in str(info.value) and "\n" not in str(info.value)


# -- the safe state's tolerance: the stalls measured in the session, never a fixed budget ----------
def _session(tmp_path, kind: str = "kill"):
    from controller.config import ControllerConfig
    from hil.faults.session import FaultSession

    plan = FaultPlan(kill_at_trial=1) if kind == "kill" else FaultPlan(silence_node=0, silence_at_trial=1)
    fs = FaultSession(plan, "vcan0", tmp_path, ControllerConfig(), {})
    fs.watchdog_s, fs.heartbeat_s = 0.1, 0.1
    fs.t_event_unix, fs.t_event_mono = 1000.0, 50.0
    return fs


class _Watcher:
    def __init__(self, beats):
        self.beats = beats
        self.error = None

    def snapshot(self):
        return list(self.beats)


def _idle_after(ms: float) -> list[Beat]:
    """Both axes closed loop before the event (t = 1000 s), IDLE ``ms`` after it (the test's clock)."""
    closed, idle = int(AxisState.CLOSED_LOOP_CONTROL), int(AxisState.IDLE)
    return [Beat(999.95, a, closed, 0) for a in ("hip", "knee")] + [Beat(1000.0 + ms / 1e3, a, idle, 0)
                                                                   for a in ("hip", "knee")]


def _section(fs, *, plant_us, mitm_ms, controller_us=None, where="native"):
    bye = {"axes": {}, "watchdog_trips": 2}
    if plant_us is not None:
        bye["pacing"] = {"max_period_us": plant_us}
    fs.mitm_summary = {} if mitm_ms is None else {"pacing": {"max_gap_ms": mitm_ms}}
    final = {} if controller_us is None else {"max_period_us": controller_us}

    class Recorder:
        commanded = None

    return fs.section(where=where, bye=bye, final=final, rc_controller=-9, recorder=Recorder(), out=fs.work)


def test_a_kills_safe_state_is_in_time_within_the_stalls_measured_on_its_path(tmp_path):
    from hil.faults.session import fault_problems
    from hil.profile import NATIVE

    fs = _session(tmp_path)
    fs.watcher = _Watcher(_idle_after(230.0))  # 30 ms past the 200 ms bound
    sec = _section(fs, plant_us=28_000.0, mitm_ms=2.0)  # the plant stalled 28 ms, the mitm 2 ms
    assert sec["bound_ms"] == pytest.approx(200.0) and sec["safe_state_ms"] == pytest.approx(230.0)
    assert sec["stalls_ms"] == pytest.approx({"plant": 28.0, "mitm": 2.0})
    assert sec["tolerance_ms"] == pytest.approx(NATIVE.late_allowance_s(0.028, 0.002) * 1e3) == pytest.approx(31.0)
    assert sec["within_bound"]
    late = _section(fs, plant_us=5_000.0, mitm_ms=2.0)  # only 5 ms of stall: 30 ms late is the code's
    assert not late["within_bound"] and late["tolerance_ms"] == pytest.approx(8.0)
    m = {"fault": late, "hil": {"error": None, "trials_completed": 1, "exit_codes": {"firmware_sim": 0}}}
    late.update(mitm_exit_code=0, controller_exit_expected=True, weights={"exists": False})
    problems = fault_problems(m, 3)
    assert len(problems) == 1 and "over the bound of 200 ms + 8 ms" in problems[0] and "plant" in problems[0]


def test_a_stall_not_measured_counts_as_the_platforms_fallback_and_a_silence_counts_the_controller(tmp_path):
    from hil.profile import NATIVE, UML

    fs = _session(tmp_path)
    fs.watcher = _Watcher(_idle_after(210.0))
    sec = _section(fs, plant_us=None, mitm_ms=2.0)  # firmware-sim said no bye
    assert sec["stalls_ms"]["plant"] is None
    assert sec["tolerance_ms"] == pytest.approx((NATIVE.safe_state_tolerance_ms / 1e3 + 0.002 + 0.001) * 1e3)
    uml = _section(fs, plant_us=None, mitm_ms=None, where="uml")
    assert uml["tolerance_ms"] == pytest.approx(2 * UML.safe_state_tolerance_ms + 1.0)
    silence = _session(tmp_path, "silence")
    silence.watcher = _Watcher(_idle_after(1100.0))
    sec = _section(silence, plant_us=3_000.0, mitm_ms=2.0, controller_us=40_000.0)
    assert sec["stalls_ms"] == pytest.approx({"plant": 3.0, "mitm": 2.0, "controller": 40.0})
    assert sec["tolerance_ms"] == pytest.approx(46.0)
