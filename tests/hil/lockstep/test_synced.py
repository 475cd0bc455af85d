"""Simulated time through the sync protocol, in one process: the same run as the in-process
lockstep, frame for frame (learning records, a walk's metrics, faults, a killed controller); and
the plant's half across processes (:class:`SimTimePlant`), with the controller in a thread on its
own end of the bus: the same run, the controller's phase heard, a dead controller declared gone."""

from __future__ import annotations

import json
import math
import struct
import threading
import uuid

import can
import pytest

import hil.experiments.learn as learn
import hil.experiments.walk as walk
from controller.supervisor import Phase
from hil.analysis.records import first_difference
from hil.faults.model import FaultSpec
from hil.lockstep.harness import Lockstep, LockstepConfig
from controller.daemon.simclock import SimClockBus, run_period
from hil.lockstep.synced import SimTimePlant, SyncedLockstep
from protocol.contract import CONTROLLER_STATE_ID, END_OF_PERIOD_ID, SIM_SYNC_ID


def _learn(harness: type) -> tuple[list[str], dict]:
    run = learn.LearningRun(learn.LearnConfig(trials=3, seed=0), harness=harness)
    try:
        trials = run.run()
        assert type(run.ls) is harness
        ls = run.ls
        facts = {"t_s": ls.t_s, "ticks": ls.loop.stats.ticks, "dropped": dict(ls.loop.io.dropped),
                 "host": dict(ls.leg.host.stats)}
        if isinstance(ls, SyncedLockstep):
            facts["plant_bus"] = dict(ls.plant_bus.stats)
            facts["sim_clock"] = dict(ls.sim_clock.stats)
            facts["plant_phase"] = ls.plant_bus.controller_phase
    finally:
        run.close()
    return [json.dumps(t, sort_keys=True) for t in trials], facts


def test_learning_through_the_sync_protocol_gives_the_in_process_records():
    plain, plain_facts = _learn(Lockstep)
    synced, facts = _learn(SyncedLockstep)
    assert len(plain) == 3
    assert synced == plain  # per trial, every field
    # the same clock and the same bus, seen from both ends
    for key in ("t_s", "ticks", "dropped", "host"):
        assert facts[key] == plain_facts[key], key
    assert facts["dropped"] == {}  # no sync or end-of-period frame reached the controller's BusIO
    assert facts["host"]["unknown"] == 0  # ... or the plant's nodes
    # every tick came from a sync and was answered
    n = facts["ticks"]
    assert n > 9000
    # one controller state per phase the run went through (wait_nodes ... walk), each heard by the plant
    states = facts["sim_clock"]["states"]
    assert 3 <= states <= 6
    assert facts["sim_clock"] == {"syncs": n, "ends": n, "states": states, "stale_syncs": 0,
                                  "foreign_end_of_period": 0, "malformed_sync": 0}
    assert facts["plant_bus"] == {"syncs": n, "ends": n, "alone": 0, "stale_ends": 0, "states": states, "hidden": 0,
                                  "silenced": 0}
    assert facts["plant_phase"] == "walk"


def test_a_walk_through_the_sync_protocol_gives_the_in_process_metrics(monkeypatch):
    metrics = {}
    for harness in (Lockstep, SyncedLockstep):
        monkeypatch.setattr(walk, "Lockstep", harness)
        m = walk.run_walk(4.0, seed=1)
        m.pop("wall_s")
        metrics[harness.__name__] = json.dumps(m, sort_keys=True)
    assert json.loads(metrics["Lockstep"])["steps"] > 0
    assert metrics["SyncedLockstep"] == metrics["Lockstep"]


def _run(ls: Lockstep, t_s: float) -> None:
    while ls.t_s < t_s:
        ls.step()


def test_the_sync_follows_the_period_s_frames_and_the_end_of_period_the_controller_s():
    with SyncedLockstep(LockstepConfig(seed=2)) as ls:
        tap = ls.observer()
        try:
            _run(ls, 1.0)
            frames = []
            while (m := tap.recv(timeout=0.0)) is not None:
                frames.append(m)
        finally:
            tap.shutdown()
    syncs = [i for i, m in enumerate(frames) if m.is_extended_id and m.arbitration_id == SIM_SYNC_ID]
    ends = [i for i, m in enumerate(frames) if m.is_extended_id and m.arbitration_id == END_OF_PERIOD_ID]
    assert len(syncs) == len(ends) == ls.loop.stats.ticks == 500
    times = [struct.unpack("<d", frames[i].data)[0] for i in syncs]
    assert times == sorted(times) and times[-1] == ls.t_s
    for s, e in zip(syncs, ends):
        assert s < e and frames[e].data == frames[s].data  # the end echoes the sync's time, bit for bit
        # between a sync and its end: only the controller's frames (to the ODrive nodes 0, 1 and
        # the sensor board 16), no plant frame
        # (and the controller's state, when its phase changed)
        between = [m for m in frames[s + 1:e] if not (m.is_extended_id and m.arbitration_id == CONTROLLER_STATE_ID)]
        assert all(not m.is_extended_id and m.arbitration_id >> 5 in (0, 1, 16) for m in between)
    assert any(e - s > 1 for s, e in zip(syncs, ends))  # the controller did send in its periods


def test_faults_wrap_the_sim_clock_and_give_the_in_process_run():
    results = []
    for harness in (Lockstep, SyncedLockstep):
        with harness(LockstepConfig(seed=4)) as ls:
            _run(ls, 1.5)
            faulty = ls.inject_faults(FaultSpec(drop=0.05, delay=0.05, reorder=0.02),
                                      FaultSpec(drop=0.05, duplicate=0.02), seed=9)
            _run(ls, 3.0)
            ls.silence([16])  # the sensor board goes silent: the controller must stop safely
            _run(ls, 4.0)
            results.append((faulty.counts(), dict(ls.loop.io.rx), dict(ls.loop.io.dropped), ls.loop.phase,
                            ls.loop.supervisor.fault_cause, ls.axes_idle()))
            if isinstance(ls, SyncedLockstep):
                assert ls.plant_bus.stats["alone"] == 0 and ls.sim_clock.stats["ends"] == ls.loop.stats.ticks
    assert results[0][0]["from_leg"] and results[0][0]["silenced_frames"] > 0
    assert results[0][3] is Phase.FAULT
    assert results[1] == results[0]


def test_a_killed_controller_leaves_the_plant_stepping_alone_on_simulated_time():
    idle_at = []
    for harness in (Lockstep, SyncedLockstep):
        with harness(LockstepConfig(seed=0)) as ls:
            while ls.loop.phase is not Phase.WALK:
                assert ls.t_s < 10.0
                ls.step()
            _run(ls, ls.t_s + 0.5)
            ticks = ls.loop.stats.ticks
            ls.kill_controller()
            killed_at = ls.t_s
            while not ls.axes_idle():
                assert ls.t_s < killed_at + 1.0, "the drivers' watchdogs never disarmed the axes"
                ls.step()
            idle_at.append(ls.t_s - killed_at)
            assert ls.loop.stats.ticks == ticks
            if isinstance(ls, SyncedLockstep):
                periods = int(round(idle_at[-1] * ls.config.controller.rate_hz))
                assert ls.plant_bus.stats["alone"] == pytest.approx(periods, abs=1) and periods > 10
                assert ls.sim_clock.stats["ends"] == ticks
    assert idle_at[1] == idle_at[0]  # the watchdogs acted on simulated time: the same instant


def test_the_plant_waits_for_the_end_of_its_own_period_and_keeps_the_frames_before_it():
    import can

    from hil.lockstep.synced import PlantSyncBus

    plant = PlantSyncBus(can.Bus(interface="virtual", channel="synced-plant-unit"))
    ctl = can.Bus(interface="virtual", channel="synced-plant-unit")
    try:
        def eop(t_s: float) -> can.Message:
            return can.Message(arbitration_id=END_OF_PERIOD_ID, data=struct.pack("<d", t_s), is_extended_id=True)

        plant.publish_sync(0.004)
        m = ctl.recv(timeout=0.0)
        assert m.is_extended_id and m.arbitration_id == SIM_SYNC_ID and bytes(m.data) == struct.pack("<d", 0.004)
        ctl.send(eop(0.002))  # a late answer to the previous sync
        ctl.send(can.Message(arbitration_id=0x00C, data=bytes(8), is_extended_id=False))
        ctl.send(eop(0.004))
        ctl.send(can.Message(arbitration_id=0x02C, data=bytes(8), is_extended_id=False))
        assert plant.wait_end_of_period(0.004, 0.0) is True
        assert plant.stats["stale_ends"] == 1 and plant.stats["ends"] == 1
        ctl.send(can.Message(arbitration_id=SIM_SYNC_ID, data=bytes(8), is_extended_id=True))  # another plant's
        ids = [m.arbitration_id for m in iter(lambda: plant.recv(timeout=0.0), None)]
        assert ids == [0x00C, 0x02C]  # in order, and no sync or end-of-period frame
        assert plant.stats["hidden"] == 1
        assert plant.wait_end_of_period(0.006, 0.0) is False and plant.stats["alone"] == 1
        with pytest.raises(ValueError):
            plant.publish_sync(math.inf)
    finally:
        plant.shutdown()
        plant.inner.shutdown()
        ctl.shutdown()


# -- the plant's half across processes (hil --clock sim): SimTimePlant, here with the controller in a thread
def _controller_thread(channel: str, config, stop: threading.Event, ticks: list):
    """The controller's side as the daemon runs it in simulated time: a ControlLoop on its own
    bus through a SimClockBus, one run_period after another until ``stop``."""
    from controller.loop import ControlLoop

    clock = SimClockBus(can.Bus(interface="virtual", channel=channel))
    loop = ControlLoop(config, clock)
    ticks.append(loop)

    def body():
        try:
            while not stop.is_set():
                run_period(loop, clock, 0.05)
        finally:
            clock.shutdown()

    t = threading.Thread(target=body, daemon=True)
    t.start()
    return t


def test_a_plant_and_a_controller_on_separate_ends_give_the_lockstep_run():
    cfg = LockstepConfig(seed=6)
    channel = f"simtime-{uuid.uuid4().hex}"
    plant_bus = can.Bus(interface="virtual", channel=channel)
    stop, holder = threading.Event(), []
    worker = _controller_thread(channel, cfg.controller, stop, holder)
    try:
        with SimTimePlant(cfg, bus=plant_bus, grace_s=5.0, open_timeout_s=10.0) as plant:
            while plant.t_s < 4.0:
                plant.step()
            phase_seen, gone = plant.loop.phase, plant.gone
            stats = dict(plant.plant_bus.stats)
        stop.set()
        worker.join(5.0)
    finally:
        stop.set()
        plant_bus.shutdown()
    remote = holder[0]
    with Lockstep(cfg) as ls:
        _run(ls, 4.0)
        want = [[s.onset_s, s.cell, s.burst_s] for s in ls.loop.stats.steps]
        want_ticks, want_phase = ls.loop.stats.ticks, ls.loop.phase
    # compared as records (NaN equal to NaN): == on tuples holding NaN holds only for the same float
    # object, which pure Python's step records happen to share and compiled ones do not
    got = [[s.onset_s, s.cell, s.burst_s] for s in remote.stats.steps]
    assert want and first_difference(got, want) is None, first_difference(got, want)
    assert remote.stats.ticks == want_ticks  # no tick at the opening sync
    assert phase_seen is want_phase is Phase.WALK  # the plant learned the phase from the state frames
    assert not gone and stats["alone"] == 0 and stats["ends"] == want_ticks + 1


def test_the_opening_sync_is_repeated_until_answered_and_a_silent_end_gives_up():
    from hil.lockstep.synced import PlantSyncBus

    channel = f"open-{uuid.uuid4().hex}"
    inner, other = can.Bus(interface="virtual", channel=channel), can.Bus(interface="virtual", channel=channel)
    try:
        bus = PlantSyncBus(inner)
        # nobody there: the sync is sent again every 10 ms until it gives up (0.5 s: even a process
        # starved for a while on a busy machine gets to send twice; 0.05 s once did not)
        assert bus.open_time(0.0, resend_s=0.01, timeout_s=0.5) is False
        sent = [m for m in iter(lambda: other.recv(timeout=0.0), None)]
        assert len(sent) >= 2 and all(m.arbitration_id == SIM_SYNC_ID and m.data == bytes(8) for m in sent)
        assert bus.stats["alone"] == 0  # waiting to open is not stepping alone
        other.send(can.Message(arbitration_id=END_OF_PERIOD_ID, is_extended_id=True, data=bytes(8)))
        assert bus.open_time(0.0, resend_s=0.5, timeout_s=5.0) is True
        # a silenced node's frames are never sent; the others' are
        bus.silenced_node = 1
        bus.send(can.Message(arbitration_id=(1 << 5) | 9, data=bytes(8), is_extended_id=False))
        bus.send(can.Message(arbitration_id=(0 << 5) | 9, data=bytes(8), is_extended_id=False))
        got = [m.arbitration_id for m in iter(lambda: other.recv(timeout=0.0), None) if not m.is_extended_id]
        assert got == [9] and bus.stats["silenced"] == 1
    finally:
        inner.shutdown()
        other.shutdown()


def test_a_plant_whose_controller_stops_answering_declares_it_gone_and_steps_on():
    cfg = LockstepConfig(seed=1)
    channel = f"gone-{uuid.uuid4().hex}"
    plant_bus = can.Bus(interface="virtual", channel=channel)
    stop, holder = threading.Event(), []
    worker = _controller_thread(channel, cfg.controller, stop, holder)
    try:
        with SimTimePlant(cfg, bus=plant_bus, grace_s=0.3, open_timeout_s=10.0) as plant:
            while plant.loop.phase is not Phase.WALK:
                assert plant.t_s < 10.0
                plant.step()
            stop.set()  # the controller dies (no goodbye frames)
            worker.join(5.0)
            t_dead = plant.t_s
            while plant.t_s < t_dead + 1.0:
                plant.step()
            assert plant.gone and plant.plant_bus.stats["alone"] > 100
            # the drivers' watchdogs acted on simulated time: every axis IDLE
            assert all(a.state.name == "IDLE" for a in plant.leg.axes.values())
    finally:
        stop.set()
        plant_bus.shutdown()
