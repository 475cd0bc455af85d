"""The lockstep's in-process bus: python-can's semantics that matter in one thread, and the same
records as python-can's ``virtual`` bus."""

from __future__ import annotations

import functools
import json

import can
import pytest

from hil.experiments.learn import LearnConfig, LearningRun
from hil.lockstep.harness import Lockstep
from hil.lockstep.localbus import BUSES, LocalBus


def _frame(arb: int) -> can.Message:
    return can.Message(arbitration_id=arb, data=bytes([arb & 0xFF]), is_extended_id=False)


def test_every_other_bus_hears_each_frame_in_order_and_none_hears_its_own():
    a, b, c = LocalBus("t-order"), LocalBus("t-order"), LocalBus("t-order")
    other = LocalBus("t-elsewhere")
    try:
        for arb in (1, 2, 3):
            a.send(_frame(arb))
        b.send(_frame(9))
        assert [m.arbitration_id for m in iter(lambda: b.recv(0.0), None)] == [1, 2, 3]
        assert [m.arbitration_id for m in iter(lambda: c.recv(0.0), None)] == [1, 2, 3, 9]
        assert [m.arbitration_id for m in iter(lambda: a.recv(0.0), None)] == [9]
        assert other.recv(0.0) is None and a.recv(timeout=5.0) is None  # never waits: nothing can come
    finally:
        for bus in (a, b, c, other):
            bus.shutdown()


def test_a_shut_down_bus_leaves_its_channel_and_refuses_to_send():
    a, b = LocalBus("t-shut"), LocalBus("t-shut")
    b.shutdown()
    a.send(_frame(1))
    assert b.recv(0.0) is None
    with pytest.raises(can.CanOperationError):
        b.send(_frame(2))
    a.shutdown()
    assert set(BUSES) == {"local", "virtual"}


def test_the_local_and_the_virtual_bus_give_the_same_learning_records():
    records = {}
    for bus in BUSES:
        run = LearningRun(LearnConfig(trials=3, seed=4), harness=functools.partial(Lockstep, bus=bus))
        try:
            records[bus] = json.dumps(run.run())
            assert isinstance(run.ls.firmware_bus, LocalBus) is (bus == "local")
        finally:
            run.close()
    assert records["local"] == records["virtual"]
