"""Fault injection: the per-frame fault model, the faulty bus, and the safe-state bounds in lockstep."""

from __future__ import annotations

import json
import math

import can
import numpy as np
import pytest

from controller.supervisor import Phase
from hil.faults.matrix import FaultCase, default_cases, run_case, table
from hil.faults.model import FaultInjector, FaultSpec, FaultyBus
from hil.lockstep.harness import Lockstep
from protocol import data_frame

WATCHDOG_S = 0.1  # the simulated drivers' watchdog timeout (DriverConfig default)
HEARTBEAT_S = 0.1  # their heartbeat period


def frames(n: int) -> list[can.Message]:
    return [data_frame(0x009, bytes([i & 0xFF, 1, 2, 3, 4, 5, 6, 7])) for i in range(n)]


def run(spec: FaultSpec, msgs, seed: int = 0, dt_s: float = 0.001, tail_s: float = 0.1):
    inj = FaultInjector(spec, np.random.default_rng(seed))
    out = []
    t = 0.0
    for m in msgs:
        inj.push(m, t)
        out += inj.pop_ready(t)
        t += dt_s
    end = t + tail_s
    while t <= end:
        out += inj.pop_ready(t)
        t += dt_s
    return inj, out


def test_spec_validates_and_parses():
    assert FaultSpec.parse("drop=0.05, delay_s=0.004") == FaultSpec(drop=0.05, delay_s=0.004)
    assert not FaultSpec.parse("").active
    for bad in ("drop=1.5", "drop=-0.1", "drop=nan", "jitter=0.1", "drop", "drop=x"):
        with pytest.raises(ValueError):
            FaultSpec.parse(bad)


def test_no_fault_passes_every_frame_in_order_at_once():
    msgs = frames(500)
    inj = FaultInjector(FaultSpec(), np.random.default_rng(0))
    for i, m in enumerate(msgs):
        inj.push(m, i * 1e-3)
        assert inj.pop_ready(i * 1e-3) == [m]


@pytest.mark.parametrize("kind", ["drop", "delay", "duplicate", "reorder", "corrupt"])
def test_each_fault_at_its_rate_and_seeded(kind):
    spec = FaultSpec(**{kind: 0.1})
    inj, out = run(spec, frames(5000))
    assert 350 <= inj.counts[kind] <= 650  # 10 % of 5000, well inside 4 sigma
    _, again = run(spec, frames(5000))
    assert [bytes(m.data) for m in out] == [bytes(m.data) for m in again]
    _, other = run(spec, frames(5000), seed=1)
    assert [bytes(m.data) for m in out] != [bytes(m.data) for m in other]
    expected = 5000 - inj.counts["drop"] + inj.counts["duplicate"]
    assert len(out) == expected


def test_delay_holds_a_frame_for_delay_s_and_lets_others_overtake():
    inj = FaultInjector(FaultSpec(delay=1.0, delay_s=0.005), np.random.default_rng(0))
    m = frames(1)[0]
    inj.push(m, 0.0)
    assert inj.pop_ready(0.0049) == []
    assert inj.pop_ready(0.005) == [m]


def test_reorder_swaps_a_frame_with_the_next_one():
    spec = FaultSpec(reorder=0.3)
    inj, out = run(spec, frames(200))
    order = [m.data[0] for m in out]
    assert sorted(order) == list(range(200))
    swaps = sum(1 for a, b in zip(order, order[1:]) if b < a)
    assert swaps == inj.counts["reorder"] > 0


def test_corrupt_changes_a_copy_not_the_original():
    msgs = frames(2000)
    originals = [bytes(m.data) for m in msgs]
    inj, out = run(FaultSpec(corrupt=1.0), msgs)
    assert [bytes(m.data) for m in msgs] == originals
    changed = [(o, bytes(m.data)) for o, m in zip(originals, out)]
    assert all(o != d for o, d in changed)
    replaced = [(o, d) for o, d in changed if len(d) == len(o)]
    assert all(sum(a != b for a, b in zip(o, d)) == 1 for o, d in replaced)
    assert 0.1 < 1 - len(replaced) / len(changed) < 0.3  # about one in five cut short
    assert all(m.dlc == len(m.data) for m in out)


def test_faulty_bus_silences_a_node_and_counts():
    a = can.Bus(interface="virtual", channel="test-faults-silence")
    b = can.Bus(interface="virtual", channel="test-faults-silence")
    try:
        fb = FaultyBus(b, clock=lambda: 0.0, seed=0)
        fb.silence([16])
        a.send(data_frame(16 << 5 | 8, bytes(8)))
        a.send(data_frame(0 << 5 | 9, bytes(8)))
        got = fb.recv(timeout=0.0)
        assert got.arbitration_id == 9 and fb.recv(timeout=0.0) is None
        assert fb.counts()["silenced_frames"] == 1
    finally:
        a.shutdown()
        b.shutdown()


# -- the safety chain in lockstep --------------------------------------------------------------
def walking() -> Lockstep:
    ls = Lockstep()
    while ls.loop.phase is not Phase.WALK:
        assert ls.t_s < 10.0, ls.loop.supervisor.fault_cause
        ls.step()
    for _ in range(1000):
        ls.step()
    return ls


def time_to_idle(ls: Lockstep, limit_s: float = 3.0) -> float:
    t0 = ls.t_s
    while not ls.axes_idle():
        assert ls.t_s - t0 < limit_s, "the axes never went IDLE"
        ls.step()
    return ls.t_s - t0


def test_kill_9_leaves_every_axis_idle_within_the_watchdog_timeout():
    with walking() as ls:
        ls.kill_controller()
        assert time_to_idle(ls) <= WATCHDOG_S + 2 * ls.leg.dt_s
        assert all(int(a.errors) & 0x1000000 for a in ls.leg.axes.values())  # WATCHDOG_TIMER_EXPIRED


def test_a_silent_node_stops_the_leg_after_the_configured_periods():
    for node in (0, 1, 16):
        with walking() as ls:
            cfg = ls.loop.config
            ls.silence([node])
            t0 = ls.t_s
            dt = time_to_idle(ls)
            assert ls.loop.phase is Phase.FAULT and "silent" in ls.loop.supervisor.fault_cause
            # the last frame came at most one of the node's frame periods (5 ms) before the silence
            assert cfg.heartbeat_timeout_s - 0.006 <= ls.loop.supervisor.fault_t_s - t0 <= cfg.heartbeat_timeout_s + 0.01
            assert dt <= cfg.heartbeat_timeout_s + 0.01  # the controller's IDLE, not the watchdog
            # learning is paused: no gate or reflex reaches the premotor in FAULT
            steps, weights = len(ls.loop.stats.steps), ls.loop.premotor.weights.copy()
            ls.loop.premotor.weights[:] = weights
            for _ in range(1500):
                ls.step()
            assert len(ls.loop.stats.steps) == steps and (ls.loop.premotor.weights == weights).all()
            assert ls.axes_idle()


def test_five_percent_frame_loss_is_not_mistaken_for_silence():
    with walking() as ls:
        ls.inject_faults(FaultSpec(drop=0.05), FaultSpec(drop=0.05), seed=3)
        for _ in range(15000):  # 15 s
            ls.step()
        assert ls.loop.phase is Phase.WALK, ls.loop.supervisor.fault_cause
        assert ls.faulty.counts()["from_leg"]["drop"] > 700  # of about 19,500 frames from the leg


def test_a_short_bus_off_is_ridden_through_and_a_long_one_stops_safely():
    with walking() as ls:
        ls.bus_off(0.03)
        for _ in range(2000):
            ls.step()
        assert ls.loop.phase is Phase.WALK and ls.loop.io.bus_events["bus_reopens"] == 1
        assert not ls.axes_idle()
    with walking() as ls:
        ls.bus_off(0.5)
        assert time_to_idle(ls) <= WATCHDOG_S + 2 * ls.leg.dt_s  # the drivers' watchdogs
        for _ in range(1000):
            ls.step()
        io = ls.loop.io
        assert ls.loop.phase is Phase.FAULT and io.bus_events["bus_reopen_failures"] >= 1
        assert io.bus_events["bus_reopens"] == 1 and io.dropped["bus_off"] == 1  # back, after backoff
        assert ls.axes_idle()


# -- the matrix --------------------------------------------------------------------------------
def test_cases_are_checked():
    with pytest.raises(ValueError):
        FaultCase("drop")
    with pytest.raises(ValueError):
        FaultCase("silence")
    with pytest.raises(ValueError):
        FaultCase("silence", node="elbow")
    with pytest.raises(ValueError):
        FaultCase("gremlins")
    names = [c.name for c in default_cases((0,), range(10))]
    assert len(names) == len(set(names)) and sum(n.startswith("drop_0.05") for n in names) == 10


def test_matrix_rows_have_the_issue_fields_and_are_deterministic(tmp_path):
    kill = run_case(FaultCase("kill"), 1, tmp_path)
    assert kill["safe_state_ms"] <= (WATCHDOG_S + 0.002) * 1e3
    assert kill["heartbeat_idle_ms"] <= (WATCHDOG_S + HEARTBEAT_S) * 1e3
    assert kill["commands_outside_limits"] == 0 and kill["data_lost"] is False and kill["weights_saved"]
    a = run_case(FaultCase("drop", 0.05, seed=4), 2, tmp_path / "a")
    b = run_case(FaultCase("drop", 0.05, seed=4), 2, tmp_path / "b")
    for row in (a, b):
        for key in ("fault", "rate", "safe_state_ms", "commands_outside_limits", "data_lost", "success_last_50"):
            assert key in row
    ta = json.loads((tmp_path / "a" / "drop_0.05_seed4" / "trials.json").read_text())
    tb = json.loads((tmp_path / "b" / "drop_0.05_seed4" / "trials.json").read_text())
    assert ta == tb and len(ta) == 2
    assert a["faults_applied"] == b["faults_applied"] and a["faults_applied"]["from_leg"]["drop"] > 0
    assert a["commands_outside_limits"] == 0 and a["data_lost"] is False
    text = table([kill, a])
    assert "| kill |" in text and "| drop | 0.05 |" in text and not math.isnan(kill["safe_state_ms"])


def test_the_faults_command_writes_rows_and_a_table(tmp_path):
    from hil.cli import main

    out, js = tmp_path / "m", tmp_path / "faults.json"
    assert main(["faults", "--only", "kill,kill_during_save", "--kills", "20", "--out", str(out), "--json", str(js),
                 "--quiet"]) == 0
    rows = json.loads(js.read_text())
    assert [r["fault"] for r in rows] == ["kill", "kill_during_save"]
    kill, save = rows
    assert kill["safe_state_ms"] <= (WATCHDOG_S + 0.002) * 1e3 and kill["commands_outside_limits"] == 0
    assert save["killsave"]["kills"] == 20 and save["killsave"]["corrupt_loads"] == 0 and save["data_lost"] is False
    report = (out / "report.md").read_text()
    assert "| kill |" in report and "| kill_during_save |" in report
