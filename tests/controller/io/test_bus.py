"""The controller's side of the bus: validation, counting, bus errors and reopening, limits, timing honesty."""

from __future__ import annotations

import logging
import math
import struct
import uuid

import can
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from controller.io.axis import AxisConfig, AxisLink, FeedbackLimits, float32_target_bounds_rev
from controller.io.bus import RX_DROP_REASONS, BusIO, ReopenPolicy
from controller.config import ControllerConfig, default_axes
from controller.loop import ControlLoop
from controller.io.sensors import SensorLink
from controller.supervisor import Phase
from protocol import AxisState, BusContract, data_frame
from tests.fakes import FakeBus

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
        can.Message(arbitration_id=0x01, data=b"\x00\x00\x00\x00\x0f\x00\x00\x00", is_extended_id=False),
    ]
    for msg in bad:
        theirs.send(msg)
    theirs.send(encoder(0, 1.5))
    loop.tick(0.0)
    assert loop.io.dropped["unknown"] == 3
    assert loop.io.dropped["malformed"] == 1
    assert loop.io.dropped["invalid"] == 2  # NaN and axis state 15 (not an ODrive state)
    assert loop.io.rx["Get_Encoder_Estimates"] == 1
    assert loop.hip.pos_rad == pytest.approx(1.5 * 2 * math.pi / 6.0)


def test_no_target_outside_the_limits_is_ever_encoded():
    axis_cfg = AxisConfig("knee", node_id=1, min_rad=-2.0, max_rad=0.0, direction=-1)
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


# --------------------------------------------------------------------------- validation
RANGE = contract.codec("SB_Range")
CONTACTS = contract.codec("SB_Contacts")
POS = contract.codec("Set_Input_Pos")


def make_io(bus=None, **kw):
    bus = bus if bus is not None else FakeBus()
    axes = [AxisLink(a, contract) for a in default_axes()]
    sensors = SensorLink(16)
    return BusIO(bus, contract, axes, sensors, **kw), bus, axes, sensors


def frames_add_up(io):
    return io.received == sum(io.rx.values()) + sum(io.dropped[r] for r in RX_DROP_REASONS)


def test_every_received_frame_is_accepted_or_dropped_under_one_named_reason():
    io, bus, (hip, knee), sensors = make_io()
    cases = [
        ("malformed", data_frame(0x208, RANGE.pack(1.0, 1, 0) + b"\x00")),  # DLC 5, DBC says 4
        ("malformed", data_frame(0x20A, CONTACTS.pack(0, 0, 0)[:2])),  # DLC 2, DBC says 3
        ("unexpected_sender", hip.pos_frame(0.1)),  # another master commands our hip
        ("unexpected_sender", data_frame(contract.odrive_id(1, "Set_Limits"), b"\x00" * 8)),
        ("unexpected_sender", knee.estop_frame()),
        ("unknown", data_frame(contract.odrive_id(5, "Heartbeat"), b"\x00" * 8)),  # not our node
        ("unknown", can.Message(arbitration_id=hip.pos_id, is_remote_frame=True, dlc=8, is_extended_id=False)),
        ("invalid", encoder(0, 0.5, 150.0)),  # faster than any motor of the rig
        ("invalid", encoder(0, 0.5, math.inf)),
        ("invalid", encoder(0, 1e30, 0.0)),  # a corrupted exponent: no joint is there
        ("invalid", encoder(1, 5.0, 0.0)),  # knee 5 rev = -5.2 rad: 3 rad outside its range
        ("invalid", heartbeat(0, state=15)),  # 15 is no ODrive axis state
        ("invalid", data_frame(0x208, RANGE.pack(10.0, 1, 0))),  # 10 m: beyond the sensor's 3 m
        ("invalid", data_frame(0x208, RANGE.pack(1.0, 2, 1))),  # Range_Valid 2
        ("invalid", data_frame(0x20A, CONTACTS.pack(2, 0, 0))),  # a contact bit 2
        ("error_frames", can.Message(arbitration_id=0x004, is_error_frame=True, dlc=8, data=b"\x00" * 8)),
        ("bus_off", can.Message(arbitration_id=0x040, is_error_frame=True, dlc=8, data=b"\x00" * 8)),
    ]
    for expected, msg in cases:
        before = dict(io.dropped)
        bus.push(msg)
        assert io.drain(1.0) == 0, expected
        changed = {k: v - before.get(k, 0) for k, v in io.dropped.items() if v != before.get(k, 0)}
        assert changed == {expected: 1}, (expected, msg)
    # the good ones after all that
    bus.push(encoder(0, 0.5, 1.0), heartbeat(1, AxisState.CLOSED_LOOP_CONTROL),
             data_frame(0x208, RANGE.pack(1.5, 1, 2)), data_frame(0x208, RANGE.pack(0.0, 0, 3)),
             data_frame(0x20A, CONTACTS.pack(1, 0, 1)))
    assert io.drain(1.0) == 5
    assert frames_add_up(io)
    assert hip.pos_rad == pytest.approx(0.5 * 2 * math.pi / 6.0)
    assert sensors.range_valid is False and sensors.range_seq == 3  # a dropout is a sample too
    # a duplicate range sequence number is invalid, and a bad frame does not move the counter
    bus.push(data_frame(0x208, RANGE.pack(1.5, 1, 3)))
    io.drain(1.0)
    assert io.dropped["invalid"] == 9 and sensors.range_seq == 3
    assert sensors.range_invalid == 2 and sensors.contacts_invalid == 1 and sensors.range_out_of_sequence == 1


@pytest.mark.parametrize("name", ["Heartbeat", "Get_Encoder_Estimates", "SB_Range", "SB_Contacts", "SB_Heartbeat"])
def test_a_can_fd_frame_on_one_of_our_ids_is_dropped_as_unknown_and_changes_nothing(name):
    """Our bus is classic CAN: an FD frame (even one whose bytes would decode to a valid reading)
    is not one of our frames, whatever its id."""
    io, bus, (hip, _), sensors = make_io()
    codec = contract.codec(name)
    arb = contract.odrive_id(0, name) if codec.frame_id < 0x20 else codec.frame_id
    payload = {"Heartbeat": (0, int(AxisState.CLOSED_LOOP_CONTROL), 0, 0), "Get_Encoder_Estimates": (0.5, 0.0),
               "SB_Range": (1.0, 1, 0), "SB_Contacts": (1, 0, 0), "SB_Heartbeat": (0, 1, 1, 0.0)}[name]
    good = data_frame(arb, codec.pack(*payload))
    fd = can.Message(arbitration_id=arb, data=bytes(good.data), dlc=good.dlc, is_extended_id=False, is_fd=True,
                     check=False)
    before = (hip.state, hip.heartbeat_t_s, hip.encoder_t_s, sensors.range_t_s, sensors.contacts_t_s,
              sensors.heartbeat_t_s)
    bus.push(fd)
    assert io.drain(1.0) == 0
    assert io.dropped == {"unknown": 1} and not io.rx and frames_add_up(io)
    assert (hip.state, hip.heartbeat_t_s, hip.encoder_t_s, sensors.range_t_s, sensors.contacts_t_s,
            sensors.heartbeat_t_s) == before
    bus.push(good)  # the same bytes as a classic frame are accepted
    assert io.drain(1.1) == 1 and io.rx == {name: 1}


def test_a_bad_heartbeat_changes_nothing():
    io, bus, (hip, _), _ = make_io()
    bus.push(heartbeat(0, AxisState.CLOSED_LOOP_CONTROL))
    io.drain(0.0)
    bus.push(heartbeat(0, state=15, error=0x800))
    io.drain(0.1)
    assert hip.state is AxisState.CLOSED_LOOP_CONTROL and hip.error == 0 and hip.heartbeat_t_s == 0.0


def test_feedback_limits_are_configurable_and_validated():
    cfg = default_axes()[0]
    link = AxisLink(cfg, contract, FeedbackLimits(max_vel_rev_s=200.0, pos_slack_rad=10.0))
    assert link.on_encoder((0.0, 150.0), 0.0) and link.on_encoder((5.0, 0.0), 1.0)
    for bad in (0.0, -1.0, math.nan, math.inf):
        with pytest.raises(ValueError):
            FeedbackLimits(max_vel_rev_s=bad)


def test_warnings_are_limited_per_reason(caplog):
    io, bus, (hip, _), _ = make_io()
    caplog.set_level(logging.WARNING, logger="controller.io.bus")
    for i in range(200):
        bus.push(encoder(0, math.nan), encoder(1, 0.5, 0.0), hip.pos_frame(0.0))
        bus.push(data_frame(0x208, RANGE.pack(1.0, 1, 0) + b"\x00"))
        io.drain(i * 0.002)
    assert io.dropped["invalid"] == 200 and io.dropped["unexpected_sender"] == 200 and io.dropped["malformed"] == 200
    texts = [r.getMessage() for r in caplog.records]
    assert sum("invalid Get_Encoder_Estimates" in t for t in texts) == io.warn_limit
    assert sum("another master" in t for t in texts) == 1
    assert sum("DLC 5" in t for t in texts) == io.warn_limit
    assert len(texts) <= 3 * io.warn_limit


# --------------------------------------------------------------------------- bus errors, bus-off, reopen
class Factory:
    """Opens FakeBus after FakeBus; fails while ``failing`` > 0 (counting down)."""

    def __init__(self, failing: int = 0) -> None:
        self.failing = failing
        self.opened: list[FakeBus] = []
        self.calls = 0

    def __call__(self) -> FakeBus:
        self.calls += 1
        if self.failing > 0:
            self.failing -= 1
            raise can.CanInitializationError("no such device")
        bus = FakeBus()
        self.opened.append(bus)
        return bus


def test_receive_error_reopens_the_bus_with_exponential_backoff(caplog):
    caplog.set_level(logging.WARNING, logger="controller.io.bus")
    factory = Factory(failing=7)
    io, bus, (hip, _), _ = make_io(reopen=factory)
    bus.recv_error = can.CanOperationError("Error receiving: Network is down")
    assert io.drain(10.0) == 0
    assert not io.bus_up and bus.closed and io.dropped["bus_error"] == 1
    assert io.bus_events["bus_down"] == 1
    assert not io.send(hip.state_frame(AxisState.IDLE))  # nothing goes out while down
    assert io.dropped["tx_while_down"] == 1 and bus.sent == []
    # attempts at 0.05 s, then 0.1, 0.2, 0.4, 0.8, 1.6, 2.0 (capped), 2.0 s apart, paced by now_s
    t, attempts = 10.0, []
    while not io.bus_up:
        t = round(t + 0.01, 6)
        calls = factory.calls
        io.drain(t)
        if factory.calls != calls:
            attempts.append(t)
        assert t < 30.0
    gaps = [round(b - a, 6) for a, b in zip([10.0, *attempts], attempts)]
    assert gaps == [0.05, 0.1, 0.2, 0.4, 0.8, 1.6, 2.0, 2.0]
    assert io.bus_events["bus_reopen_failures"] == 7 and io.bus_events["bus_reopens"] == 1
    assert io.bus is factory.opened[0]
    # once per transition: down, first failed attempt, reopened
    texts = [r.getMessage() for r in caplog.records]
    assert len(texts) == 3, texts
    assert "down" in texts[0] and "failed" in texts[1] and "reopened" in texts[2]
    # the new bus works
    io.bus.push(encoder(0, 0.25))
    assert io.drain(t + 0.002) == 1
    assert io.send(hip.state_frame(AxisState.IDLE), t + 0.002) and len(io.bus.sent) == 1


def test_backoff_keeps_growing_when_a_reopened_bus_fails_at_once_and_resets_when_it_held():
    factory = Factory()
    io, bus, (hip, _), _ = make_io(reopen=factory, policy=ReopenPolicy(first_delay_s=0.05, max_delay_s=2.0,
                                                                        stable_s=1.0))
    bus.send_error = can.CanOperationError("Failed to transmit: No buffer space available")
    assert not io.send(hip.state_frame(AxisState.IDLE), 5.0)
    assert io.dropped["tx_error"] == 1 and not io.bus_up
    io.drain(5.05)
    assert io.bus_up and factory.calls == 1
    factory.opened[-1].recv_error = can.CanOperationError("again")
    io.drain(5.06)  # failed 10 ms after the reopen: the next wait is 0.1 s, not 0.05
    io.drain(5.15)
    assert factory.calls == 1
    io.drain(5.16)
    assert factory.calls == 2 and io.bus_up
    io.drain(7.0)  # up for more than 1 s: a new outage starts at 0.05 s again
    factory.opened[-1].push(can.Message(arbitration_id=0x040, is_error_frame=True, dlc=8, data=b"\0" * 8))
    io.drain(7.5)
    assert not io.bus_up and io.dropped["bus_off"] == 1
    io.drain(7.549)
    assert factory.calls == 2
    io.drain(7.55)
    assert factory.calls == 3 and io.bus_up and io.bus_events["bus_reopens"] == 3


def test_bus_off_error_frame_takes_the_bus_down_other_error_frames_do_not():
    factory = Factory()
    io, bus, _, _ = make_io(reopen=factory)
    bus.push(can.Message(arbitration_id=0x004 | 0x080, is_error_frame=True, dlc=8, data=b"\0" * 8),
             encoder(0, 0.1))
    assert io.drain(0.0) == 1 and io.bus_up and io.dropped["error_frames"] == 1
    bus.push(can.Message(arbitration_id=0x040, is_error_frame=True, dlc=8, data=b"\0" * 8), encoder(0, 0.2))
    assert io.drain(0.002) == 0 and not io.bus_up and bus.closed  # the frame behind it is gone with the bus
    assert frames_add_up(io)


def test_without_a_factory_errors_are_counted_and_the_same_bus_is_used_again():
    io, bus, (hip, _), _ = make_io()
    bus.recv_error = can.CanOperationError("boom")
    assert io.drain(0.0) == 0 and io.dropped["bus_error"] == 1 and io.bus_up
    bus.recv_error = None
    bus.push(can.Message(arbitration_id=0x040, is_error_frame=True, dlc=8, data=b"\0" * 8), encoder(0, 0.1))
    assert io.drain(0.002) == 1 and io.bus_up and io.dropped["bus_off"] == 1
    bus.send_error = can.CanOperationError("tx")
    assert not io.send(hip.state_frame(AxisState.IDLE)) and io.dropped["tx_error"] == 1
    bus.send_error = None
    assert io.send(hip.state_frame(AxisState.IDLE)) and io.bus is bus and not bus.closed


def test_a_factory_can_be_set_after_construction():
    factory = Factory()
    io, bus, _, _ = make_io()
    io.reopen = factory
    bus.recv_error = can.CanOperationError("boom")
    io.drain(0.0)
    io.drain(0.05)
    assert io.bus is factory.opened[0]


# --------------------------------------------------------------------------- joint limits
def raw_pos_frame(link, pos_rev, length=8):
    return data_frame(link.pos_id, POS.pack(pos_rev, 0.0, 0.0)[:length])


def test_send_refuses_a_raw_set_input_pos_outside_the_limits():
    io, bus, (hip, knee), _ = make_io()
    lo, hi = knee.pos_bounds_rev
    for rev in (hi + 1e-3, lo - 1e-3, math.nan, math.inf, 100.0):
        assert not io.send(raw_pos_frame(knee, rev))
    assert not io.send(raw_pos_frame(knee, 1.0, length=4))
    assert io.dropped["refused_outside_limits"] == 6 and bus.sent == []
    for rev in (lo, hi, 0.5 * (lo + hi)):
        assert io.send(raw_pos_frame(knee, rev))
    assert io.tx["Set_Input_Pos"] == 3


def decoded_rad(cfg, frame):
    return cfg.rev_to_rad(POS.unpack(frame.data)[0])


targets = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True, allow_subnormal=True),
    st.floats(-5.0, 5.0),
    st.sampled_from([-0.75, 1.25, -2.15, 0.0, -0.0, 5e-324, -5e-324, 1e308, -1e308, math.nan]),
)


@settings(max_examples=400, deadline=None, derandomize=True)
@given(axis_index=st.sampled_from([0, 1]), measured=targets,
       commands=st.lists(st.tuples(targets, targets), min_size=1, max_size=10))
def test_no_float_ever_becomes_a_target_outside_the_limits(axis_index, measured, commands):
    """Any float in (NaN, inf, huge, subnormal), for the hip (direction +1) and the knee (-1):
    the Set_Input_Pos on the wire decodes to a finite angle in [min_rad, max_rad], and BusIO's
    guard lets it through."""
    io, bus, axes, _ = make_io()
    link = axes[axis_index]
    cfg = link.config
    link.pos_rad = measured
    for q, qd in commands:
        frame = link.pos_frame(q, qd)
        assert len(frame.data) == POS.dlc
        q_sent = decoded_rad(cfg, frame)
        assert math.isfinite(q_sent) and cfg.min_rad <= q_sent <= cfg.max_rad
        _, vel_ff, torque_ff = POS.unpack(frame.data)
        assert abs(vel_ff) <= 32.0 + 1e-9 and torque_ff == 0.0
        assert io.send(frame)
    assert io.dropped["refused_outside_limits"] == 0 and len(bus.sent) == len(commands)


@settings(max_examples=300, deadline=None, derandomize=True)
@given(lo=st.floats(-6.0, 6.0), width=st.floats(0.01, 6.0), gear=st.floats(0.1, 1000.0),
       direction=st.sampled_from([1, -1]), offset=st.floats(-100.0, 100.0), q=targets)
def test_float32_target_bounds_hold_for_any_reasonable_axis(lo, width, gear, direction, offset, q):
    cfg = AxisConfig("hip", 0, min_rad=lo, max_rad=min(lo + width, 6.2), gear_ratio=gear, direction=direction,
                     zero_offset_rev=offset)  # joint limits inside the configuration's [-2 pi, 2 pi] rad
    b_lo, b_hi = float32_target_bounds_rev(cfg)
    assert struct.unpack("<f", struct.pack("<f", b_lo))[0] == b_lo
    assert cfg.min_rad <= cfg.rev_to_rad(b_lo) <= cfg.max_rad and cfg.min_rad <= cfg.rev_to_rad(b_hi) <= cfg.max_rad
    link = AxisLink(cfg, contract)
    q_sent = decoded_rad(cfg, link.pos_frame(q))
    assert cfg.min_rad <= q_sent <= cfg.max_rad


def test_an_encoder_jump_no_joint_makes_is_dropped():
    link = AxisLink(default_axes()[0], contract)
    assert link.on_encoder((1.0, 0.0), 0.0)
    q = link.pos_rad
    # 0.3 rev motor = 0.31 rad joint in 2 ms: 157 rad/s, far beyond any joint of the rig
    assert not link.on_encoder((1.3, 0.0), 0.002) and link.pos_rad == q and link.encoder_t_s == 0.0
    assert link.on_encoder((1.02, 0.0), 0.002)  # 0.021 rad in 2 ms: a fast swing
    assert link.on_encoder((1.3, 0.0), 0.1)  # 0.29 rad in 98 ms: fine


def test_a_heartbeat_with_unknown_bits_is_dropped_and_one_with_an_error_in_closed_loop_applied():
    io, bus, (hip, _), _ = make_io()
    bus.push(heartbeat(0, AxisState.CLOSED_LOOP_CONTROL))
    io.drain(0.0)
    bus.push(heartbeat(0, AxisState.IDLE, error=0x80000000))  # no such Axis_Error bit in 0.6
    io.drain(0.1)
    assert hip.closed_loop and hip.heartbeat_t_s == 0.0 and io.dropped["invalid"] == 1
    bus.push(heartbeat(0, AxisState.CLOSED_LOOP_CONTROL, error=0x1000000))  # acted on at once (issue 14)
    io.drain(0.15)
    assert not hip.closed_loop and hip.error == 0x1000000 and hip.heartbeat_t_s == 0.15
    assert io.dropped["invalid"] == 1
    bus.push(heartbeat(0, AxisState.IDLE, error=0x1000000))  # a real watchdog trip
    io.drain(0.2)
    assert not hip.closed_loop and hip.error == 0x1000000 and hip.state is AxisState.IDLE


def test_a_corrupted_sequence_number_costs_one_frame_and_a_restart_is_followed():
    s = SensorLink(16)
    for seq in range(10):
        assert s.on_range((1.0, 1, seq), seq * 0.02)
    assert not s.on_range((1.0, 1, 110), 0.2)  # a counter corrupted far ahead: not believed
    assert all(s.on_range((1.0, 1, seq), seq * 0.02) for seq in range(10, 40))  # the genuine stream goes on
    assert s.range_seq == 39 and s.range_lost == 0
    assert not s.on_range((1.0, 1, 0), 1.0)  # the board restarted: the first frame is a jump
    assert s.on_range((1.0, 1, 1), 1.02) and s.range_seq == 1  # the second confirms it
    assert s.on_range((1.0, 1, 3), 1.06) and s.range_lost == 1  # an ordinary gap


def test_frames_from_another_master_are_counted_per_id_and_bus_voltage_is_read():
    io, bus, (hip, knee), _ = make_io()
    voltage = contract.codec("Get_Bus_Voltage_Current")
    vid = contract.odrive_id(0, "Get_Bus_Voltage_Current")
    bus.push(hip.pos_frame(0.1), knee.estop_frame(), knee.estop_frame(), data_frame(vid, voltage.pack(24.5, 1.0)))
    assert io.drain(0.5) == 1
    assert io.foreign == {hip.pos_id: 1, knee.estop_id: 2} and io.dropped["unexpected_sender"] == 3
    assert hip.bus_voltage_v == pytest.approx(24.5) and knee.bus_voltage_v is None
    for bad in (math.nan, -1.0, 1000.0):
        bus.push(data_frame(vid, voltage.pack(bad, 0.0)))
        io.drain(0.6)
    assert hip.bus_voltage_v == pytest.approx(24.5) and io.dropped["invalid"] == 3
    assert frames_add_up(io)


def test_the_counters_are_counters_whose_assignment_is_dicts_own():
    """BusIO's counters (Tally) count as collections.Counter does; only ``del`` differs (dict's:
    a missing key raises), which is what keeps ``c[k] += 1`` on dict's C slot."""
    from collections import Counter

    from controller.io.bus import Tally

    io, bus, (hip, _knee), _ = make_io()
    for counts in (io.rx, io.tx, io.dropped, io.bus_events, io.foreign):
        assert type(counts) is Tally and isinstance(counts, Counter)
    t = Tally()
    t["a"] += 1
    t["a"] += 2
    assert t["a"] == 3 and t["missing"] == 0 and "missing" not in t and t == Counter(a=3)
    del t["a"]
    assert t == {}
    with pytest.raises(KeyError):
        del t["a"]
    assert Tally.__delitem__ is dict.__delitem__
