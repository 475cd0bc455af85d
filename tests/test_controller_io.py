"""The controller's side of the bus: validation, counting, limits, timing honesty."""

from __future__ import annotations

import math
import uuid

import can
import pytest

from controller.config import AxisConfig, ControllerConfig
from controller.loop import ControlLoop
from controller.supervisor import Phase
from protocol import AxisState, BusContract, data_frame

contract = BusContract.load()


@pytest.fixture
def buses():
    channel = f"test-{uuid.uuid4().hex}"
    ours = can.Bus(interface="virtual", channel=channel)
    theirs = can.Bus(interface="virtual", channel=channel)
    yield ours, theirs
    ours.shutdown()
    theirs.shutdown()


def heartbeat(node: int, state: AxisState = AxisState.IDLE, error: int = 0):
    data = contract.codec("Heartbeat").encode(Axis_Error=error, Axis_State=int(state), Procedure_Result=0,
                                              Trajectory_Done_Flag=0)
    return data_frame(contract.odrive_id(node, "Heartbeat"), data)


def encoder(node: int, pos_rev: float, vel_rev_s: float = 0.0):
    return data_frame(contract.odrive_id(node, "Get_Encoder_Estimates"),
                      contract.codec("Get_Encoder_Estimates").pack(pos_rev, vel_rev_s))


def test_malformed_unknown_and_nan_frames_are_counted_and_dropped(buses):
    ours, theirs = buses
    loop = ControlLoop(ControllerConfig(), ours)
    bad = [
        can.Message(arbitration_id=0x7F0, data=b"\x00" * 8, is_extended_id=False),  # unknown id
        can.Message(arbitration_id=0x09, data=b"\x00" * 4, is_extended_id=False),  # short encoder frame
        can.Message(arbitration_id=0x09, is_remote_frame=True, dlc=8, is_extended_id=False),  # RTR
        can.Message(arbitration_id=0x09, data=b"\x00" * 8, is_extended_id=True),  # extended id
        encoder(0, math.nan),  # NaN reading
        can.Message(arbitration_id=0x01, data=b"\x00\x00\x00\x00\x05\x00\x00\x00", is_extended_id=False),
    ]
    for msg in bad:
        theirs.send(msg)
    theirs.send(encoder(0, 1.5))
    loop.tick(0.0)
    assert loop.io.dropped["unknown"] == 3
    assert loop.io.dropped["malformed"] == 1
    assert loop.io.dropped["invalid"] == 2  # NaN and axis state 5 (not an ODrive state)
    assert loop.io.rx["Get_Encoder_Estimates"] == 1
    assert loop.hip.pos_rad == pytest.approx(1.5 * 2 * math.pi / 6.0)


def test_no_target_outside_the_limits_is_ever_encoded():
    axis_cfg = AxisConfig("knee", node_id=1, min_rad=-2.0, max_rad=0.0, direction=-1)
    from controller.axis import AxisLink

    link = AxisLink(axis_cfg, contract)
    link.pos_rad = -1.0
    for q in (-5.0, 3.0, math.nan, math.inf, -math.inf, -1.0):
        frame = link.pos_frame(q)
        sent = axis_cfg.rev_to_rad(contract.codec("Set_Input_Pos").unpack(frame.data)[0])
        assert axis_cfg.min_rad - 1e-6 <= sent <= axis_cfg.max_rad + 1e-6
    assert link.clamped_targets == 5


def test_joint_units_round_trip_through_gear_direction_and_offset():
    cfg = AxisConfig("hip", node_id=0, min_rad=-1, max_rad=1, gear_ratio=9.0, direction=-1, zero_offset_rev=0.3)
    for q in (-0.7, 0.0, 0.4):
        assert cfg.rev_to_rad(cfg.rad_to_rev(q)) == pytest.approx(q)
    assert cfg.rad_to_rev(2 * math.pi) == pytest.approx(0.3 - 9.0)


def test_late_ticks_are_counted_and_never_double_step_the_cpg(buses):
    ours, _ = buses
    loop = ControlLoop(ControllerConfig(), ours)
    period = loop.config.period_s
    loop.tick(0.0)
    loop.tick(period)
    loop.tick(period + 10 * period)  # one tick arrives ten periods late
    loop.tick(12 * period)
    assert loop.stats.ticks == 4
    assert loop.stats.late_ticks == 1
    assert loop.stats.max_period_s == pytest.approx(10 * period)


def test_silent_bus_fails_bring_up_with_a_clear_cause(buses):
    ours, _ = buses
    cfg = ControllerConfig(bringup_timeout_s=0.2)
    loop = ControlLoop(cfg, ours)
    t = 0.0
    while t < 0.5:
        loop.tick(t)
        t += cfg.period_s
    assert loop.phase is Phase.FAULT
    assert "no heartbeat" in loop.supervisor.fault_cause
    assert loop.io.tx["Set_Input_Pos"] == 0


@pytest.mark.parametrize(
    "bad",
    [
        dict(rate_hz=0.0),
        dict(rate_hz=math.nan),
        dict(axes=(AxisConfig("hip", 0, -1, 1), AxisConfig("hip", 1, -1, 1))),
        dict(axes=(AxisConfig("hip", 0, -1, 1), AxisConfig("knee", 0, -1, 1))),
    ],
)
def test_bad_configuration_is_refused_with_the_field_named(bad):
    with pytest.raises(ValueError):
        ControllerConfig(**bad)
    with pytest.raises(ValueError, match="node_id 16"):
        AxisConfig("hip", 16, -1, 1)
