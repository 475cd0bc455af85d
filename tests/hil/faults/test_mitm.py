"""The man-in-the-middle node's logic on python-can ``virtual`` buses, the safe-state timing from
heartbeats, and the HIL fault options (no vcan needed)."""

from __future__ import annotations

import argparse
import math
import struct
import uuid

import can
import pytest

from hil.faults.model import FaultSpec
from hil.faults.session import FaultPlan, add_hil_fault_args, weights_state
from hil.session.legwatch import Beat, safe_state
from hil.faults.mitm import ManInTheMiddle
from protocol import AxisState
from protocol.contract import CONTROLLER_STATE_ID, END_OF_PERIOD_ID, SIM_SYNC_ID
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
def _session(tmp_path, kind: str = "kill", to_leg: str = ""):
    from controller.config import ControllerConfig
    from hil.faults.session import FaultSession

    plan = (FaultPlan(kill_at_trial=1, to_leg=to_leg) if kind == "kill"
            else FaultPlan(silence_node=0, silence_at_trial=1))
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

    fs = _session(tmp_path, to_leg="drop=0.05")  # a kill with frame loss: through the mitm
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
    late.update(mitm_exit_code=1)
    assert any("mitm node exit code 1" in p for p in fault_problems(m, 3))


def test_a_kill_alone_runs_without_the_mitm_the_leg_on_the_controllers_channel(tmp_path):
    """No forwarding process between the last command and the watchdogs: the plant's stall is
    the only one on the path, and no mitm exit code is asked for."""
    from hil.faults.session import fault_problems, fault_summary

    assert not FaultPlan(kill_at_trial=1).through_mitm
    assert FaultPlan(kill_at_trial=1, from_leg="drop=0.05").through_mitm
    assert FaultPlan(silence_node=0, silence_at_trial=1).through_mitm and FaultPlan(to_leg="drop=0.05").through_mitm
    fs = _session(tmp_path)
    assert fs.leg_channel == "vcan0"
    fs.watcher = _Watcher(_idle_after(190.0))
    sec = _section(fs, plant_us=28_000.0, mitm_ms=None)
    assert sec["mitm"] is None and sec["channels"] == {"controller": "vcan0", "leg": "vcan0"}
    assert sec["stalls_ms"] == pytest.approx({"plant": 28.0})
    assert sec["tolerance_ms"] == pytest.approx(29.0) and sec["within_bound"]
    m = {"fault": sec, "hil": {"error": None, "trials_completed": 1, "exit_codes": {"firmware_sim": 0}}}
    sec.update(controller_exit_expected=True, weights={"exists": False})
    assert sec["mitm_exit_code"] is None and fault_problems(m, 3) == []
    assert fault_summary(m).startswith("hil faults: no mitm node")
    assert _session(tmp_path, to_leg="drop=0.05").leg_channel == "vcan1"


def test_a_stall_not_measured_counts_as_the_platforms_fallback_and_a_silence_counts_the_controller(tmp_path):
    from hil.profile import NATIVE, UML

    fs = _session(tmp_path, to_leg="drop=0.05")
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


# -- simulated time: the plant's syncs are the clock, the sync protocol's frames pass untouched ----
def _ext(arb: int, payload: bytes) -> can.Message:
    return can.Message(arbitration_id=arb, data=payload, is_extended_id=True)


def _sync(t_s: float) -> can.Message:
    return _ext(SIM_SYNC_ID, struct.pack("<d", t_s))


def _eop(t_s: float) -> can.Message:
    return _ext(END_OF_PERIOD_ID, struct.pack("<d", t_s))


def _state(code: int) -> can.Message:
    return _ext(CONTROLLER_STATE_ID, bytes([code]))


def _key(m: can.Message) -> tuple:
    """What a receiver sees of a frame."""
    return m.arbitration_id, m.is_extended_id, m.is_remote_frame, m.dlc, bytes(m.data)


def _keys(frames) -> list[tuple]:
    return [_key(m) for m in frames]


def test_wall_mode_reports_its_clock_and_no_sim_frames(buses):
    ctl, ctl_node, leg, leg_node = buses
    node = ManInTheMiddle(ctl_node, leg_node)
    leg.send(_sync(0.002))
    node.pump(0.0)
    assert _keys(drain(ctl)) == _keys([_sync(0.002)])  # through the injector, as before this mode
    s = node.summary()
    assert s["clock"] == "wall" and s["sim_clock"] is None and s["from_leg"]["sim_frames"] == 0
    assert s["from_leg"]["forwarded"] == 1 and s["silence"]["started_sim_s"] is None


@pytest.mark.parametrize("spec", [FaultSpec(drop=1.0),
                                  FaultSpec(corrupt=1.0, duplicate=1.0, reorder=1.0, delay=0.5)],
                         ids=["drop-all", "corrupt-duplicate-reorder-delay"])
def test_sim_time_frames_pass_untouched_whatever_the_faults(buses, spec):
    ctl, ctl_node, leg, leg_node = buses
    node = ManInTheMiddle(ctl_node, leg_node, to_leg=spec, from_leg=spec, seed=2, sim_time=True)
    leg.send(_frame(0x009, bytes(range(8))))
    leg.send(_sync(0.002))
    node.pump(0.0)
    ctl.send(_frame(0x00C, bytes(range(8))))
    ctl.send(_state(4))
    ctl.send(_eop(0.002))
    node.pump(0.0)
    to_ctl, to_leg = drain(ctl), drain(leg)
    assert _keys(m for m in to_ctl if m.is_extended_id) == _keys([_sync(0.002)])
    assert _keys(m for m in to_leg if m.is_extended_id) == _keys([_state(4), _eop(0.002)])
    s = node.summary()
    assert s["clock"] == "sim" and s["from_leg"]["sim_frames"] == 1 and s["to_leg"]["sim_frames"] == 2
    # only the ordinary frames met the injectors
    assert node.from_leg.injector.counts["frames"] == node.to_leg.injector.counts["frames"] == 1
    if spec.drop == 1.0:
        assert len(to_ctl) == 1 and len(to_leg) == 2 and s["to_leg"]["drop"] == s["from_leg"]["drop"] == 1
        wall = ManInTheMiddle(ctl_node, leg_node, to_leg=spec, from_leg=spec)  # on the wall clock: all lost
        leg.send(_sync(0.004))
        ctl.send(_eop(0.004))
        wall.pump(0.0)
        assert drain(ctl) == [] and drain(leg) == []


def test_before_each_sync_the_controller_gets_exactly_the_surviving_leg_frames_of_that_period(buses):
    """Every surviving leg frame is delayed one period (delay_s = one period, exact in binary):
    pushed at the last sync's time, it is due at the next sync's, so it goes out just before that
    sync, even with every period read in one pump (on the wall clock they would all still be held)."""
    ctl, ctl_node, leg, leg_node = buses
    period_s = 2.0 ** -9
    node = ManInTheMiddle(ctl_node, leg_node, from_leg=FaultSpec(drop=0.3, delay=1.0, delay_s=period_s), seed=7,
                          sim_time=True)
    sent: list[list[tuple]] = []
    for k in range(1, 31):
        frames = [_frame(0x009 + (j << 5), bytes([k, j])) for j in range(4)]
        sent.append(_keys(frames))
        for f in frames:
            leg.send(f)
        leg.send(_sync(k * period_s))
    node.pump(0.0)
    got = _keys(drain(ctl))
    periods: list[list[tuple]] = [[]]
    syncs = []
    for key in got:
        if key[0] == SIM_SYNC_ID:
            syncs.append(key)
            periods.append([])
        else:
            periods[-1].append(key)
    assert syncs == _keys(_sync(k * period_s) for k in range(1, 31)) and periods[-1] == []
    for k, (out, src) in enumerate(zip(periods[:-1], sent), start=1):
        assert out == [key for key in src if key in out], f"period {k}: not the period's frames in order"
    s = node.summary()
    assert 0 < s["from_leg"]["drop"] < 120
    assert sum(map(len, periods)) == 120 - s["from_leg"]["drop"] == s["from_leg"]["delay"]
    assert s["from_leg"]["in_flight"] == 0 and s["sim_clock"]["last_sync_s"] == 30 * period_s


def test_a_delay_runs_on_the_syncs_time_never_on_the_wall_clock(buses):
    ctl, ctl_node, leg, leg_node = buses
    spec = FaultSpec(delay=1.0, delay_s=0.005)
    node = ManInTheMiddle(ctl_node, leg_node, to_leg=spec, from_leg=spec, sim_time=True)
    a = _frame(0x009, b"\xaa")
    leg.send(a)  # before the first sync: pushed at 0.0, due at 0.005
    node.pump(100.0)
    node.pump(1e6)  # a million wall seconds later: still held
    assert drain(ctl) == [] and node.summary()["from_leg"]["in_flight"] == 1
    b = _frame(0x00C, b"\xbb")
    seen_ctl, seen_leg = [], []
    for t_s in (0.002, 0.004, 0.005, 0.006, 0.008):
        leg.send(_sync(t_s))
        node.pump(0.0)
        seen_ctl.append(_keys(drain(ctl)))
        seen_leg.append(_keys(drain(leg)))
        if t_s == 0.002:
            ctl.send(b)  # the controller's answer to the sync of 0.002: due at 0.007
            ctl.send(_eop(0.002))
            node.pump(0.0)
            seen_leg[-1] += _keys(drain(leg))
    assert seen_ctl == [_keys([_sync(0.002)]), _keys([_sync(0.004)]), _keys([a, _sync(0.005)]),
                        _keys([_sync(0.006)]), _keys([_sync(0.008)])]
    # the controller's frame goes to the leg when the clock passes 0.007: at the sync of 0.008
    assert seen_leg == [_keys([_eop(0.002)]), [], [], [], _keys([b])]
    s = node.summary()
    assert s["from_leg"]["delay"] == s["to_leg"]["delay"] == 1 and s["sim_clock"]["syncs"] == 5


def test_a_malformed_sync_is_forwarded_and_counted_but_never_the_clock(buses):
    ctl, ctl_node, leg, leg_node = buses
    node = ManInTheMiddle(ctl_node, leg_node, from_leg=FaultSpec(delay=1.0, delay_s=0.005), sim_time=True)
    a = _frame(0x009, b"\xaa")
    bad = [_ext(SIM_SYNC_ID, struct.pack("<d", 1.0)[:4]), _sync(math.nan),
           can.Message(arbitration_id=SIM_SYNC_ID, is_extended_id=True, is_remote_frame=True, dlc=8)]
    leg.send(a)
    for m in bad:
        leg.send(m)
    node.pump(0.0)
    assert _keys(drain(ctl)) == _keys(bad)  # untouched, and the held frame still held (the clock is 0.0)
    s = node.summary()
    assert s["sim_clock"] == {"syncs": 0, "malformed_syncs": 3, "stale_syncs": 0, "last_sync_s": 0.0}
    assert s["from_leg"]["sim_frames"] == 3 and s["from_leg"]["in_flight"] == 1
    leg.send(_sync(0.005))
    node.pump(0.0)
    assert _keys(drain(ctl)) == _keys([a, _sync(0.005)])
    # a stale sync (a plant re-sending an earlier one) passes too, and the clock does not run back
    b = _frame(0x009, b"\xbb")
    for m in (_sync(0.002), b, _sync(0.009)):
        leg.send(m)
    node.pump(0.0)
    assert _keys(drain(ctl)) == _keys([_sync(0.002), _sync(0.009)])  # b: pushed at 0.005, due 0.010
    assert node.summary()["sim_clock"] == {"syncs": 2, "malformed_syncs": 3, "stale_syncs": 1, "last_sync_s": 0.009}


def _traffic(periods: int) -> list[tuple[str, can.Message]]:
    """A run's frames in the order they reach the node: per period the leg's frames, the sync (now
    and then a malformed one too), the controller's frames, now and then its state, its
    end-of-period. ``"leg"``: sent by the leg, ``"ctl"``: by the controller."""
    seq: list[tuple[str, can.Message]] = []
    for k in range(1, periods + 1):
        t_s = k * 0.002
        seq += [("leg", _frame(0x009 + (j << 5), bytes([k & 0xFF, k >> 8, j, 1]))) for j in range(4)]
        if k % 9 == 0:
            seq.append(("leg", _ext(SIM_SYNC_ID, b"\x00\x01")))
        seq.append(("leg", _sync(t_s)))
        seq += [("ctl", _frame(0x00C + (j << 5), bytes([k & 0xFF, k >> 8, j, 2]))) for j in range(3)]
        if k % 5 == 0:
            seq.append(("ctl", _state(k % 6)))
        seq.append(("ctl", _eop(t_s)))
    return seq


def _cuts(seq, every: float, rng) -> list[int]:
    """Where the pumps split ``seq``: after each sync always (the controller answers a sync only
    after the node forwarded it, so its answer is read in a later pump on a real bus), elsewhere
    with probability ``every``; the end last."""
    cuts = [i + 1 for i, (side, m) in enumerate(seq)
            if (side == "leg" and m.arbitration_id == SIM_SYNC_ID and m.is_extended_id) or rng.random() < every]
    return cuts if cuts[-1] == len(seq) else cuts + [len(seq)]


@pytest.mark.parametrize("delay_s, reorder_max_s", [(0.005, 0.003), (0.0, 0.0)],
                         ids=["held-across-periods", "released-at-once"])
def test_the_same_frames_give_the_same_frames_out_however_the_pumps_split_them(buses, delay_s, reorder_max_s):
    """Also with zero delays: a frame delayed 0 s or held 0 s is due as soon as it is pushed, and
    must still come out at the same place in the stream whatever was read with it."""
    import random

    ctl, ctl_node, leg, leg_node = buses
    spec = FaultSpec(drop=0.3, delay=0.2, reorder=0.2, duplicate=0.05, corrupt=0.05, delay_s=delay_s,
                     reorder_max_s=reorder_max_s)
    seq = _traffic(80)

    def run(cuts: list[int], now) -> tuple[list, list, dict]:
        node = ManInTheMiddle(ctl_node, leg_node, to_leg=spec, from_leg=spec, seed=11, sim_time=True)
        to_ctl, to_leg, start = [], [], 0
        for i, end in enumerate(cuts):
            for side, m in seq[start:end]:
                (leg if side == "leg" else ctl).send(m)
            node.pump(now(i))
            to_ctl += _keys(drain(ctl))
            to_leg += _keys(drain(leg))
            start = end
        return to_ctl, to_leg, node.summary()

    rng = random.Random(1)
    splits = {
        "a pump per frame": (list(range(1, len(seq) + 1)), lambda i: 0.0),
        "a pump per sync": (_cuts(seq, 0.0, rng), lambda i: 1e-3 * i),
        "a pump at each sync and end-of-period": (
            [i + 1 for i, (_, m) in enumerate(seq) if m.is_extended_id and m.arbitration_id in (SIM_SYNC_ID,
                                                                                               END_OF_PERIOD_ID)],
            lambda i: 5.0),
        "random, fine": (_cuts(seq, 0.6, rng), lambda i: rng.uniform(0.0, 1e3)),
        "random, coarse": (_cuts(seq, 0.1, rng), lambda i: -i),
    }
    results = {name: run(cuts, now) for name, (cuts, now) in splits.items()}
    assert len({len(cuts) for cuts, _ in splits.values()}) == len(splits)  # five different splits
    first_ctl, first_leg, first_summary = results["a pump per frame"]
    for name, (to_ctl, to_leg, summary) in results.items():
        assert to_ctl == first_ctl, f"{name}: other frames (or order) to the controller"
        assert to_leg == first_leg, f"{name}: other frames (or order) to the leg"
        assert summary == first_summary, name
    # the faults were there, and the protocol's frames all passed, in order, untouched
    for direction in ("to_leg", "from_leg"):
        assert all(first_summary[direction][k] > 0 for k in ("drop", "delay", "reorder", "duplicate", "corrupt"))
    sent_ctl = [_key(m) for side, m in seq if side == "leg" and m.is_extended_id]
    sent_leg = [_key(m) for side, m in seq if side == "ctl" and m.is_extended_id]
    assert [k for k in first_ctl if k[1]] == sent_ctl and [k for k in first_leg if k[1]] == sent_leg
    assert first_summary["sim_clock"]["malformed_syncs"] == 8 and first_summary["sim_clock"]["syncs"] == 80


@pytest.mark.parametrize("at_s, started_s", [(0.003, 0.004), (0.004, 0.004), (0.0041, 0.006)])
def test_a_silence_starts_at_the_first_sync_at_or_past_its_simulated_time(buses, at_s, started_s):
    ctl, ctl_node, leg, leg_node = buses
    node = ManInTheMiddle(ctl_node, leg_node, silence_node=0, sim_time=True, silence_at_sim_s=at_s)
    out = {}
    for k in range(1, 5):
        t_s = k * 0.002
        leg.send(_frame(0x009, bytes([k])))  # the hip (node 0)
        leg.send(_frame(0x029, bytes([k])))  # the knee (node 1)
        leg.send(_sync(t_s))
        node.pump(50.0 + k)
        out[t_s] = [m.arbitration_id for m in drain(ctl)]
    for t_s, ids in out.items():
        # a period's frames are judged by the sync before them: silenced after the silence's sync
        assert ids == ([0x029, SIM_SYNC_ID] if t_s > started_s else [0x009, 0x029, SIM_SYNC_ID]), t_s
    s = node.summary()["silence"]
    assert s["started_sim_s"] == started_s and s["at_sim_s"] == at_s
    assert s["started_mono"] == 50.0 + round(started_s / 0.002)  # the pump that read that sync
    assert node.summary()["from_leg"]["silenced"] == round((0.008 - started_s) / 0.002)


def test_a_silence_asked_for_in_simulated_time_starts_at_the_next_sync(buses):
    ctl, ctl_node, leg, leg_node = buses
    node = ManInTheMiddle(ctl_node, leg_node, silence_node=1, sim_time=True)
    leg.send(_sync(0.002))
    node.pump(0.0)
    node.silence_at_next_sync()  # SIGUSR1 in this mode
    leg.send(_frame(0x029))
    leg.send(_sync(0.004))
    leg.send(_frame(0x029))
    node.pump(0.0)
    assert [m.arbitration_id for m in drain(ctl)] == [SIM_SYNC_ID, 0x029, SIM_SYNC_ID]
    assert node.summary()["silence"]["started_sim_s"] == 0.004 and node.summary()["from_leg"]["silenced"] == 1
    with pytest.raises(RuntimeError):
        ManInTheMiddle(ctl_node, leg_node, silence_node=1).silence_at_next_sync()


def test_a_silence_on_the_other_clock_is_refused_before_anything_opens():
    from hil.faults.mitm import run_mitm

    with pytest.raises(ValueError, match="silence_after_s"):
        run_mitm("can9", "can8", clock="sim", silence_after_s=1.0)  # a channel opened first would fail otherwise
    with pytest.raises(ValueError, match="silence_at_sim_s"):
        run_mitm("can9", "can8", silence_at_sim_s=1.0)
    with pytest.raises(ValueError, match="clock"):
        run_mitm("can9", "can8", clock="lunar")
    with pytest.raises(ValueError, match="silence_at_sim_s"):
        ManInTheMiddle(can.Bus(interface="virtual", channel="x"), can.Bus(interface="virtual", channel="y"),
                       silence_at_sim_s=1.0)


@pytest.mark.parametrize("argv, option", [(("--clock", "sim", "--silence-after-s", "1"), "--silence-after-s"),
                                          (("--silence-at-sim-s", "1"), "--silence-at-sim-s"),
                                          (("--clock", "wall", "--silence-at-sim-s", "0"), "--silence-at-sim-s")])
def test_the_cli_refuses_a_silence_on_the_other_clock_in_one_line(capsys, argv, option):
    from hil.cli import main

    code = main(["mitm", "--controller-channel", "can9", "--leg-channel", "can8", "--silence-node", "0", *argv])
    err = capsys.readouterr().err.strip()
    assert code == 2  # a usage error, before the channels (which do not exist: 4) are tried
    assert "\n" not in err and err.startswith("elegant-stepping mitm: error: ") and option in err


def test_run_mitm_in_simulated_time_forwards_by_the_rule_and_says_its_clock(tmp_path, monkeypatch):
    """The node's loop on virtual buses (``_open`` swapped; a socket that never has data stands in
    for poll()): the frames waiting at start go through by the simulated-time rule, the silence
    starts at its sync, and the counts file says the clock. The node stops on SIGTERM, raised once
    it has read the leg's side empty (``duration_s`` is only a backstop)."""
    import signal
    import socket

    import hil.faults.mitm as mitm

    ends: dict[str, tuple[can.BusABC, can.BusABC]] = {}
    spares = []

    class Polled:  # the node's end: a virtual bus with a socket for poll()
        def __init__(self, bus: can.BusABC, stop_when_empty: bool) -> None:
            self.bus, self.send, self.stop_when_empty = bus, bus.send, stop_when_empty
            pair = socket.socketpair()
            spares.extend(pair)
            self.socket = pair[0]

        def recv(self, timeout=None):
            msg = self.bus.recv(timeout)
            if msg is None and self.stop_when_empty:
                self.stop_when_empty = False
                signal.raise_signal(signal.SIGTERM)  # as the session stops it
            return msg

    def fake_open(channel: str):
        ends[channel] = _pair()
        if channel == "leg":  # what the leg sent before the node's first wake-up
            for k in (1, 2):
                ends["leg"][0].send(_frame(0x009, bytes([k])))
                ends["leg"][0].send(_sync(k * 0.002))
        return ends[channel][1], Polled(ends[channel][1], channel == "leg")

    monkeypatch.setattr(mitm, "_open", fake_open)
    saved = {s: signal.getsignal(s) for s in (signal.SIGTERM, signal.SIGINT, signal.SIGUSR1)}
    try:
        summary = mitm.run_mitm("ctl", "leg", from_leg=FaultSpec(delay=1.0, delay_s=0.002), silence_node=0,
                                clock="sim", silence_at_sim_s=0.002, duration_s=60.0,
                                json_path=tmp_path / "mitm.json")
        got = _keys(drain(ends["ctl"][0]))
    finally:
        for s, handler in saved.items():
            signal.signal(s, handler)
        for b in (*ends.get("ctl", ()), *ends.get("leg", ())):
            b.shutdown()
        for sock in spares:
            sock.close()
    # hip frame 1 (delayed to 0.002) before the first sync; the silence starts at it: frame 2 silenced
    assert got == _keys([_frame(0x009, bytes([1])), _sync(0.002), _sync(0.004)])
    assert summary["stopped_by"] == "SIGTERM" and summary["clock"] == "sim"
    assert summary["silence"]["started_sim_s"] == 0.002 and summary["from_leg"]["silenced"] == 1
    assert summary["from_leg"]["sim_frames"] == 2 and summary["sim_clock"]["syncs"] == 2
    assert mitm.read_counts(tmp_path / "mitm.json")["clock"] == "sim"
