"""The controller's side of simulated time: frames up to the sync, a tick per sync, the end of
period echoing the sync's time; sync and end-of-period frames never reach the controller."""

from __future__ import annotations

import itertools
import math
import struct

import can
import pytest

from controller.daemon.simclock import SimClockBus, SimSync, run_period
from controller.supervisor import Phase
from protocol.contract import CONTROLLER_STATE_ID, END_OF_PERIOD_ID, PHASE_CODES, SIM_SYNC_ID

_n = itertools.count()


@pytest.fixture
def buses():
    channel = f"simclock-{next(_n)}"
    plant = can.Bus(interface="virtual", channel=channel)
    clock = SimClockBus(can.Bus(interface="virtual", channel=channel))
    yield plant, clock
    clock.shutdown()
    plant.shutdown()


def frame(arb: int, data: bytes = bytes(8)) -> can.Message:
    return can.Message(arbitration_id=arb, data=data, is_extended_id=False)


def sync(t_s: float) -> can.Message:
    return can.Message(arbitration_id=SIM_SYNC_ID, data=struct.pack("<d", t_s), is_extended_id=True)


def drain(bus: can.BusABC) -> list[int]:
    out = []
    while (m := bus.recv(timeout=0.0)) is not None:
        out.append(m.arbitration_id)
    return out


def test_recv_stops_at_the_sync_and_the_next_period_waits_for_the_next_tick(buses):
    plant, clock = buses
    for arb in (0x009, 0x029):
        plant.send(frame(arb))
    plant.send(sync(0.002))
    plant.send(frame(0x208))  # the next period's
    assert drain(clock) == [0x009, 0x029]
    assert clock.recv(timeout=5.0) is None  # at the boundary: at once, whatever the timeout
    s = clock.wait_sync(0.0)
    assert s == SimSync(0, 0.002) and clock.current == s
    assert drain(clock) == []  # the frame after the sync is the next tick's
    clock.end_period(s)
    plant.send(sync(0.004))
    assert clock.wait_sync(0.0) == SimSync(1, 0.004)
    assert drain(clock) == [0x208]
    assert clock.stats["syncs"] == 2


def test_wait_sync_keeps_the_frames_before_it_for_the_tick(buses):
    plant, clock = buses
    for arb in (0x001, 0x009, 0x021, 0x209):
        plant.send(frame(arb))
    plant.send(sync(1.5))
    plant.send(frame(0x00A))
    assert clock.wait_sync(0.0) == SimSync(0, 1.5)
    assert drain(clock) == [0x001, 0x009, 0x021, 0x209]


def test_wait_sync_without_a_sync_times_out_and_keeps_what_it_read(buses):
    plant, clock = buses
    plant.send(frame(0x009))
    assert clock.wait_sync(0.0) is None
    assert clock.current is None
    assert drain(clock) == [0x009]


def test_end_of_period_echoes_the_sync_s_time_bit_for_bit(buses):
    plant, clock = buses
    t = 0.0
    for _ in range(7):
        t += 0.001  # the plant's accumulated clock, not 7 * 0.001
    plant.send(sync(t))
    s = clock.wait_sync(0.0)
    assert struct.pack("<d", s.t_s) == struct.pack("<d", t)
    clock.end_period(s)
    eop = plant.recv(timeout=0.0)
    assert eop.is_extended_id and eop.arbitration_id == END_OF_PERIOD_ID and eop.dlc == 8
    assert bytes(eop.data) == struct.pack("<d", t)
    assert plant.recv(timeout=0.0) is None and clock.stats["ends"] == 1


def test_the_periods_must_alternate(buses):
    plant, clock = buses
    plant.send(sync(0.002))
    plant.send(sync(0.004))
    s = clock.wait_sync(0.0)
    with pytest.raises(RuntimeError, match="end_period"):
        clock.wait_sync(0.0)
    with pytest.raises(ValueError):
        clock.end_period(SimSync(5, 0.002))
    clock.end_period(s)
    with pytest.raises(ValueError):
        clock.end_period(s)  # ended once only
    assert clock.wait_sync(0.0) == SimSync(1, 0.004)


def test_sync_and_end_of_period_frames_never_reach_the_controller(buses):
    plant, clock = buses
    other_extended = can.Message(arbitration_id=0x1234567, data=bytes(8), is_extended_id=True)
    plant.send(can.Message(arbitration_id=END_OF_PERIOD_ID, data=bytes(8), is_extended_id=True))  # another controller's
    plant.send(can.Message(arbitration_id=CONTROLLER_STATE_ID, data=bytes(1), is_extended_id=True))  # its state
    plant.send(can.Message(arbitration_id=SIM_SYNC_ID, data=bytes(4), is_extended_id=True))  # malformed
    plant.send(sync(math.nan))  # not a time
    plant.send(other_extended)
    plant.send(frame(0x009))
    plant.send(sync(0.1))
    got = []
    while (m := clock.recv(timeout=0.0)) is not None:
        got.append((m.arbitration_id, m.is_extended_id))
    assert got == [(0x1234567, True), (0x009, False)]  # other traffic passes, for BusIO to count
    assert clock.stats == {"syncs": 0, "ends": 0, "states": 0, "stale_syncs": 0, "foreign_end_of_period": 2,
                           "malformed_sync": 2}
    assert clock.wait_sync(0.0) == SimSync(0, 0.1)


def test_send_passes_the_controller_s_frames_through(buses):
    plant, clock = buses
    clock.send(frame(0x00C, b"\x01" * 8))
    m = plant.recv(timeout=0.0)
    assert (m.arbitration_id, bytes(m.data)) == (0x00C, b"\x01" * 8)


class _Loop:
    def __init__(self, bus: can.BusABC) -> None:
        self.bus = bus
        self.ticks: list[tuple[float, list[int]]] = []
        self.phase = Phase.WAIT_NODES

    def tick(self, now_s: float) -> None:
        self.ticks.append((now_s, drain(self.bus)))


def test_run_period_ticks_once_per_sync_with_its_time(buses):
    plant, clock = buses
    loop = _Loop(clock)
    assert run_period(loop, clock, 0.0) is None and loop.ticks == []
    plant.send(frame(0x009))
    plant.send(sync(0.002))
    plant.send(frame(0x029))
    plant.send(sync(0.004))
    assert run_period(loop, clock, 0.0) == SimSync(0, 0.002)
    assert run_period(loop, clock, 0.0) == SimSync(1, 0.004)
    assert loop.ticks == [(0.002, [0x009]), (0.004, [0x029])]
    sent = list(iter(lambda: plant.recv(timeout=0.0), None))
    ends = [struct.unpack("<d", m.data)[0] for m in sent if m.arbitration_id == END_OF_PERIOD_ID]
    assert ends == [0.002, 0.004]
    # the phase went with the first answer only (it did not change)
    states = [m for m in sent if m.arbitration_id == CONTROLLER_STATE_ID]
    assert [bytes(m.data) for m in states] == [bytes([PHASE_CODES.index("wait_nodes")])]
    assert sent[0] is not None and sent[0].arbitration_id == CONTROLLER_STATE_ID  # before its end of period


def test_the_opening_sync_is_answered_without_a_tick_and_its_repeats_are_stale(buses):
    plant, clock = buses
    loop = _Loop(clock)
    for _ in range(3):  # the plant repeats the opening sync until it is answered
        plant.send(sync(0.0))
    assert run_period(loop, clock, 0.0) == SimSync(0, 0.0)
    assert loop.ticks == []  # no time has passed: no tick
    plant.send(frame(0x009))
    plant.send(sync(0.002))
    assert run_period(loop, clock, 0.0) == SimSync(1, 0.002)
    assert loop.ticks == [(0.002, [0x009])]
    assert clock.stats["stale_syncs"] == 2  # the two repeats, dropped


def test_a_sync_for_a_time_already_lived_is_never_ticked_on(buses):
    plant, clock = buses
    loop = _Loop(clock)
    for t in (0.002, 0.004, 0.002, 0.004, 0.006):
        plant.send(sync(t))
    got = [run_period(loop, clock, 0.0) for _ in range(4)]
    assert [g.t_s if g else None for g in got] == [0.002, 0.004, 0.006, None]
    assert [t for t, _ in loop.ticks] == [0.002, 0.004, 0.006]
    assert clock.stats["stale_syncs"] == 2


def test_the_controller_state_goes_out_when_the_phase_changes(buses):
    plant, clock = buses
    loop = _Loop(clock)
    phases = [Phase.WAIT_NODES, Phase.WAIT_NODES, Phase.INACTIVE, Phase.WALK, Phase.WALK, Phase.FAULT]
    for i, phase in enumerate(phases, 1):
        loop.phase = phase
        plant.send(sync(i * 0.002))
        assert run_period(loop, clock, 0.0) is not None
    sent = list(iter(lambda: plant.recv(timeout=0.0), None))
    codes = [m.data[0] for m in sent if m.arbitration_id == CONTROLLER_STATE_ID]
    assert [PHASE_CODES[c] for c in codes] == ["wait_nodes", "inactive", "walk", "fault"]
    assert clock.stats["states"] == 4 and clock.stats["ends"] == 6
    # each state just before the end of period of its tick
    for i, m in enumerate(sent):
        if m.arbitration_id == CONTROLLER_STATE_ID:
            assert sent[i + 1].arbitration_id == END_OF_PERIOD_ID
