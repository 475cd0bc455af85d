"""NodeHost over python-can's virtual bus: routing, replies, cyclic publishing, failures, overhead."""

from __future__ import annotations

import uuid

import can
import numpy as np
import pytest

from firmware_sim.motor import MotorJoint, Transmission
from firmware_sim.node_host import NodeHost
from firmware_sim.odrive_axis import DriverConfig, SimOdriveAxis
from firmware_sim.sensor_board import SensorBoard, SensorBoardConfig
from protocol.contract import BusContract, arbitration_id
from protocol.odrive import AxisState, Cmd
from tests.fakes import FakeJointPlant, FakeSensorSource, drain

C = BusContract.load()
DT = 0.001


@pytest.fixture
def buses():
    channel = f"node-host-{uuid.uuid4().hex}"
    fw = can.Bus(interface="virtual", channel=channel)
    ctl = can.Bus(interface="virtual", channel=channel)
    yield fw, ctl
    fw.shutdown()
    ctl.shutdown()


def rig(fw_bus, **axis_cfg):
    plant = FakeJointPlant({"hip": 0.0, "knee": 0.2})
    axes = [
        SimOdriveAxis(DriverConfig(node_id=1, **axis_cfg), MotorJoint(plant, "hip", Transmission())),
        SimOdriveAxis(DriverConfig(node_id=2, **axis_cfg), MotorJoint(plant, "knee", Transmission(direction=-1))),
    ]
    board = SensorBoard(SensorBoardConfig(), FakeSensorSource(), np.random.default_rng(0))
    return NodeHost(fw_bus, [*axes, board]), axes, board, plant


def send(bus, node, name, *values):
    codec = C.codec(name)
    bus.send(can.Message(arbitration_id=arbitration_id(node, codec.cmd_id), data=codec.pack(*values), is_extended_id=False))


def send_rtr(bus, arb_id, dlc):
    bus.send(can.Message(arbitration_id=arb_id, is_remote_frame=True, dlc=dlc, is_extended_id=False))


def test_rtr_request_is_answered_over_the_bus(buses):
    fw, ctl = buses
    host, axes, _, plant = rig(fw)
    send_rtr(ctl, arbitration_id(2, Cmd.GET_ENCODER_ESTIMATES), 8)
    send_rtr(ctl, C.codec("SB_Contacts").frame_id, 3)
    assert host.poll(0.0) == 2
    replies = drain(ctl)
    assert [m.arbitration_id for m in replies] == [arbitration_id(2, Cmd.GET_ENCODER_ESTIMATES), 0x20A]
    pos, vel = C.codec("Get_Encoder_Estimates").unpack(replies[0].data)
    assert pos == pytest.approx(Transmission(direction=-1).joint_to_motor_rev(0.2), rel=1e-6)
    assert host.stats["rx"] == 2 and host.stats["tx"] == 2


def test_frames_routed_by_node_id(buses):
    fw, ctl = buses
    host, (a1, a2), board, _ = rig(fw)
    send(ctl, 2, "Set_Axis_State", AxisState.CLOSED_LOOP_CONTROL)
    host.poll(0.0)
    assert a2.state is AxisState.CLOSED_LOOP_CONTROL
    assert a1.state is AxisState.IDLE
    assert a2.stats["rx"]["Set_Axis_State"] == 1 and a1.stats["rx"]["Set_Axis_State"] == 0
    assert drain(ctl) == []  # commands get no reply


def test_foreign_extended_and_error_frames_counted(buses):
    fw, ctl = buses
    host, axes, board, _ = rig(fw)
    send(ctl, 5, "Set_Axis_State", AxisState.CLOSED_LOOP_CONTROL)  # no node 5 here
    send_rtr(ctl, arbitration_id(7, Cmd.HEARTBEAT), 8)
    ctl.send(can.Message(arbitration_id=(1 << 5) | Cmd.ESTOP, data=b"", is_extended_id=True))
    ctl.send(can.Message(is_error_frame=True))
    assert host.poll(0.0) == 4
    assert host.stats["foreign"] == 2
    assert host.stats["unknown"] == 2
    assert all(a.state is AxisState.IDLE and not a.errors for a in axes)
    assert drain(ctl) == []


def test_publish_rates_over_one_second(buses):
    fw, ctl = buses
    host, axes, board, _ = rig(fw)
    for i in range(1000):
        host.publish(i * DT)
    counts: dict[int, int] = {}
    for msg in drain(ctl):
        counts[msg.arbitration_id] = counts.get(msg.arbitration_id, 0) + 1
    for node in (1, 2):
        assert 9 <= counts[arbitration_id(node, Cmd.HEARTBEAT)] <= 11
        assert 499 <= counts[arbitration_id(node, Cmd.GET_ENCODER_ESTIMATES)] <= 501
    assert 49 <= counts[0x208] <= 51
    assert 199 <= counts[0x20A] <= 201
    assert 9 <= counts[0x201] <= 11
    assert host.stats["tx"] == sum(counts.values())


def test_closed_loop_over_the_bus_reaches_target(buses):
    fw, ctl = buses
    host, (a1, a2), _, plant = rig(fw, watchdog_timeout_s=0.1)
    send(ctl, 1, "Set_Axis_State", AxisState.CLOSED_LOOP_CONTROL)
    last_encoder = None
    for i in range(2000):
        t = i * DT
        if i % 10 == 0:  # 100 Hz commands keep the watchdog fed
            send(ctl, 1, "Set_Input_Pos", 0.75, 0.0, 0.0)
        host.step(t, DT)
        plant.step(DT)
        for msg in drain(ctl):
            if msg.arbitration_id == arbitration_id(1, Cmd.GET_ENCODER_ESTIMATES):
                last_encoder = C.codec("Get_Encoder_Estimates").unpack(msg.data)
    assert a1.state is AxisState.CLOSED_LOOP_CONTROL and not a1.errors
    assert last_encoder[0] == pytest.approx(0.75, abs=2e-3)
    assert a2.state is AxisState.IDLE


def test_watchdog_expires_over_the_bus_when_commands_stop(buses):
    fw, ctl = buses
    host, (a1, _), _, plant = rig(fw, watchdog_timeout_s=0.1)
    send(ctl, 1, "Set_Axis_State", AxisState.CLOSED_LOOP_CONTROL)
    heartbeats = []
    for i in range(300):
        host.step(i * DT, DT)
        plant.step(DT)
        heartbeats += [
            C.codec("Heartbeat").decode(m.data) for m in drain(ctl) if m.arbitration_id == arbitration_id(1, Cmd.HEARTBEAT)
        ]
    assert heartbeats[0]["Axis_State"] == AxisState.CLOSED_LOOP_CONTROL
    assert heartbeats[-1]["Axis_State"] == AxisState.IDLE
    assert heartbeats[-1]["Axis_Error"] & 0x1000000  # WATCHDOG_TIMER_EXPIRED


class FailingBus(can.BusABC):
    """A bus whose sends always fail and which never receives."""

    def __init__(self, inbox=()):
        super().__init__(channel="failing")
        self.inbox = list(inbox)

    def send(self, msg, timeout=None):
        raise can.CanOperationError("tx buffer full")

    def _recv_internal(self, timeout):
        return (self.inbox.pop(0) if self.inbox else None), True


def test_failing_send_is_counted_not_raised():
    rtr = can.Message(arbitration_id=arbitration_id(1, Cmd.HEARTBEAT), is_remote_frame=True, dlc=8, is_extended_id=False)
    bus = FailingBus([rtr])
    host, _, _, _ = rig(bus)
    assert host.poll(0.0) == 1
    sent = host.publish(0.0)
    assert sent == 2 + 2 + 4  # two axes x (heartbeat, encoder) + board (range, profile, contacts, heartbeat)
    assert host.stats["send_errors"] == 1 + sent
    assert host.stats["tx"] == 0
    bus.shutdown()


def test_duplicate_node_ids_rejected(buses):
    fw, _ = buses
    plant = FakeJointPlant()
    a = SimOdriveAxis(DriverConfig(node_id=1), MotorJoint(plant, "knee"))
    b = SimOdriveAxis(DriverConfig(node_id=1), MotorJoint(plant, "knee"))
    with pytest.raises(ValueError):
        NodeHost(fw, [a, b])


class RaisingNode:
    node_id = 9

    def handle(self, msg, now_s):
        raise RuntimeError("bug")

    def update(self, now_s, dt_s):
        pass

    def due(self, now_s):
        return []


def test_raising_node_is_counted_and_polling_continues(buses):
    fw, ctl = buses
    host = NodeHost(fw, [RaisingNode(), *rig(fw)[1]])
    send(ctl, 9, "Set_Axis_State", AxisState.IDLE)
    send(ctl, 1, "Set_Axis_State", AxisState.CLOSED_LOOP_CONTROL)
    assert host.poll(0.0) == 2
    assert host.stats["node_errors"] == 1
    assert host.nodes[1].state is AxisState.CLOSED_LOOP_CONTROL
