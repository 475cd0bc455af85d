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
