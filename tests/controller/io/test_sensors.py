"""The sensor board as the controller sees it: the contact switches' latch (a switch that closes
and opens between two ticks is still heard once)."""

from __future__ import annotations

from controller.io.sensors import SensorLink
from protocol import SENSOR_BOARD_NODE_ID


def test_a_switch_closed_and_opened_between_two_takes_reads_closed_once():
    s = SensorLink(SENSOR_BOARD_NODE_ID)
    assert s.take_contacts() == (False, False)
    assert s.on_contacts((0, 1, 0), 0.001) and s.on_contacts((0, 0, 1), 0.002)
    assert (s.foot, s.shin) == (False, False)  # the last frame says open ...
    assert s.take_contacts() == (False, True)  # ... but the shin closed since the last take
    assert s.take_contacts() == (False, False)  # heard once: the latch restarted from "open"


def test_a_switch_still_closed_reads_closed_at_every_take():
    s = SensorLink(SENSOR_BOARD_NODE_ID)
    assert s.on_contacts((1, 0, 0), 0.001)
    assert s.take_contacts() == (True, False)
    assert s.take_contacts() == (True, False)
    assert s.on_contacts((0, 0, 1), 0.002)
    assert s.take_contacts() == (False, False)


def test_a_rejected_frame_latches_nothing():
    s = SensorLink(SENSOR_BOARD_NODE_ID)
    assert s.on_contacts((0, 0, 5), 0.001)
    assert not s.on_contacts((1, 1, 5), 0.002)  # a duplicate sequence number: dropped whole
    assert not s.on_contacts((2, 1, 6), 0.003)  # a switch that is neither 0 nor 1: dropped whole
    assert s.take_contacts() == (False, False)
