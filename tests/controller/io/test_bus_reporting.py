"""BusIO's reporting and its edges: every log line an operator reads (its wording, its times and
cause, at most ``warn_limit`` of a kind), every counter counted once per event, the receive path
never waiting on the bus, and the Set_Input_Pos guard reading the DBC's Input_Pos whatever its
layout. Many of these were found by mutation testing (docs/mutation.md)."""

from __future__ import annotations

import logging
import math

import can
import cantools
import pytest

from controller.config import default_axes
from controller.io.axis import AxisLink
from controller.io.bus import BusIO, ReopenPolicy
from controller.io.sensors import SensorLink
from protocol import AxisState, BusContract, data_frame
from protocol.contract import DBC_PATH
from tests.controller.io.test_bus import RANGE, Factory, encoder, frames_add_up, heartbeat, make_io
from tests.fakes import FakeBus

contract = BusContract.load()
LOG = "controller.io.bus"
BUS_OFF = can.Message(arbitration_id=0x040, is_error_frame=True, dlc=8, data=b"\0" * 8)
ERROR_FRAME = can.Message(arbitration_id=0x004, is_error_frame=True, dlc=8, data=b"\0" * 8)


def lines(caplog, level=logging.WARNING) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.name == LOG and r.levelno == level]


# --------------------------------------------------------------------------- the log, with a reopen factory
def test_an_outage_is_logged_once_down_once_failing_and_once_reopened_with_times_and_cause(caplog):
    caplog.set_level(logging.DEBUG, logger=LOG)
    factory = Factory(failing=2)
    io, bus, _, _ = make_io(reopen=factory)
    bus.recv_error = can.CanOperationError("Network is down")
    io.drain(10.0)
    for t in (10.05, 10.1, 10.15, 10.3, 10.35):  # attempts at 10.05 (fails), 10.15 (fails), 10.35
        io.drain(t)
    assert io.bus_up and factory.calls == 3
    assert lines(caplog) == [
        "CAN bus down at t=10.000 s (receive error: Network is down): closing it, reopening in 0.050 s "
        "(backoff up to 2.0 s); frames to send are dropped meanwhile",
        "reopening the CAN bus failed at t=10.050 s (no such device); retrying, backing off to 2.0 s",
        "CAN bus reopened at t=10.350 s after 0.350 s down (3 attempt(s))",
    ]


def test_the_causes_of_going_down_are_named(caplog):
    caplog.set_level(logging.WARNING, logger=LOG)
    io, bus, (hip, _), _ = make_io(reopen=Factory())
    bus.send_error = can.CanOperationError("No buffer space available")
    assert not io.send(hip.state_frame(AxisState.IDLE), 2.0)
    io.drain(2.05)
    io.bus.push(BUS_OFF)
    io.drain(3.5)
    down = [t for t in lines(caplog) if t.startswith("CAN bus down")]
    assert down[0].startswith("CAN bus down at t=2.000 s (send error on Set_Axis_State: No buffer space available)")
    assert down[1].startswith("CAN bus down at t=3.500 s (bus-off error frame, class 0x40)")


def test_a_factory_returning_none_is_a_failed_attempt_and_a_bus_that_fails_to_close_is_logged(caplog):
    caplog.set_level(logging.DEBUG, logger=LOG)

    class Unclosable(FakeBus):
        def shutdown(self):
            raise OSError(19, "No such device")

    opened = []

    def factory():
        opened.append(None if not opened else FakeBus())
        return opened[-1]

    io = BusIO(Unclosable(), contract, [AxisLink(a, contract) for a in default_axes()], SensorLink(16),
               reopen=factory)
    io.bus.recv_error = can.CanOperationError("gone")
    io.drain(0.0)
    assert lines(caplog, logging.DEBUG) == ["closing the failed bus raised OSError(19, 'No such device')"]
    io.drain(0.05)  # the factory returns None: a failure, tried again later
    assert not io.bus_up and io.bus_events["bus_reopen_failures"] == 1
    assert "reopening the CAN bus failed at t=0.050 s (the reopen factory returned None)" in lines(caplog)[1]
    io.drain(0.2)
    assert io.bus_up and io.bus is opened[-1]


def test_a_send_error_before_any_drain_takes_the_bus_down_and_the_first_drain_reopens_it():
    factory = Factory()
    io, bus, (hip, _), _ = make_io(reopen=factory)
    bus.send_error = can.CanOperationError("tx")
    assert not io.send(hip.state_frame(AxisState.IDLE))  # no time known yet
    assert not io.bus_up and io.dropped["tx_error"] == 1
    io.drain(0.05)
    assert io.bus_up and factory.calls == 1


def test_while_the_bus_is_down_drain_reads_nothing_and_returns_zero():
    factory = Factory(failing=100)
    io, bus, _, _ = make_io(reopen=factory)
    bus.recv_error = can.CanOperationError("down")
    io.drain(0.0)
    bus.recv_error = None
    bus.push(encoder(0, 0.1))
    assert io.drain(0.01) == 0 and io.drain(0.05) == 0 and io.drain(0.2) == 0
    assert len(bus.incoming) == 1 and io.received == 0 and factory.calls == 2


def test_a_reopened_bus_is_read_in_the_same_drain():
    factory = Factory()
    io, bus, _, _ = make_io(reopen=factory)
    bus.recv_error = can.CanOperationError("down")
    io.drain(0.0)
    factory.failing = 0

    def opened_with_a_frame():
        new = Factory.__call__(factory)
        new.push(encoder(0, 0.1))
        return new

    io.reopen = opened_with_a_frame
    assert io.drain(0.05) == 1 and io.rx["Get_Encoder_Estimates"] == 1


# --------------------------------------------------------------------------- the log, without a factory
def test_without_a_factory_each_error_is_warned_at_most_warn_limit_times_naming_it(caplog):
    caplog.set_level(logging.WARNING, logger=LOG)
    io, bus, (hip, _), _ = make_io()
    assert io.warn_limit == 3
    bus.recv_error = can.CanOperationError("boom")
    for k in range(5):
        io.drain(k * 0.01)
    bus.recv_error = None
    bus.send_error = can.CanOperationError("tx")
    for _ in range(2):
        io.send(hip.state_frame(AxisState.IDLE))
    bus.send_error = None
    bus.push(BUS_OFF, BUS_OFF, ERROR_FRAME, ERROR_FRAME)
    io.drain(1.0)
    assert io.dropped == {"bus_error": 5, "tx_error": 2, "bus_off": 2, "error_frames": 2}
    assert lines(caplog) == [
        "bus receive error: boom",
        "bus receive error: boom",
        "bus receive error: boom (no more bus_error warnings: see BusIO.dropped)",
        "bus send error on Set_Axis_State: tx",
        "bus send error on Set_Axis_State: tx",
        "bus-off error frame (class 0x40)",
        "bus-off error frame (class 0x40)",
        "error frame (class 0x4) dropped",
        "error frame (class 0x4) dropped",
    ]


def test_a_warn_limit_of_one_adds_the_no_more_note_to_the_first(caplog):
    caplog.set_level(logging.WARNING, logger=LOG)
    io, bus, _, _ = make_io(warn_limit=1)
    bus.push(ERROR_FRAME, ERROR_FRAME)
    io.drain(0.0)
    assert lines(caplog) == ["error frame (class 0x4) dropped (no more error_frames warnings: see BusIO.dropped)"]


def test_frame_warnings_name_the_message_its_length_and_bytes(caplog):
    caplog.set_level(logging.DEBUG, logger=LOG)
    io, bus, (hip, knee), _ = make_io()
    bus.push(data_frame(0x208, RANGE.pack(1.0, 1, 0) + b"\x07"),  # DLC 5, the DBC says 4
             encoder(0, math.nan),
             hip.pos_frame(0.1), hip.pos_frame(0.2),  # another master: warned once only
             can.Message(arbitration_id=0x7F0, data=b"\0" * 8, is_extended_id=False))
    io.drain(0.0)
    assert not io.send(data_frame(knee.pos_id, contract.codec("Set_Input_Pos").pack(50.0, 0.0, 0.0)))
    nan_hex = encoder(0, math.nan).data.hex()
    assert lines(caplog) == [
        "SB_Range frame with DLC 5 (5 bytes), 4 expected: dropped",
        f"invalid Get_Encoder_Estimates frame dropped: {nan_hex}",
        f"frame {hip.pos_id:#x} (Set_Input_Pos) on the bus is one only a master sends to our node: another master "
        "is on the bus (no more unexpected_sender warnings: see BusIO.dropped)",
        "refused to send Set_Input_Pos " + contract.codec("Set_Input_Pos").pack(50.0, 0.0, 0.0).hex()
        + ": position outside the joint limits or malformed",
    ]
    assert lines(caplog, logging.DEBUG) == ["frame 0x7f0 not ours, dropped"]


def test_frames_not_ours_are_logged_at_debug_level_warn_limit_times_then_only_counted(caplog):
    caplog.set_level(logging.DEBUG, logger=LOG)
    io, bus, _, _ = make_io()
    for k in range(6):
        bus.push(can.Message(arbitration_id=0x700 + k, data=b"\0" * 8, is_extended_id=False))
    io.drain(0.0)
    assert io.dropped["unknown"] == 6
    assert lines(caplog, logging.DEBUG) == ["frame 0x700 not ours, dropped", "frame 0x701 not ours, dropped",
                                            "frame 0x702 not ours, dropped"]
    assert lines(caplog) == []


def test_a_handler_that_raises_is_counted_logged_with_its_traceback_and_the_drain_goes_on(caplog):
    caplog.set_level(logging.WARNING, logger=LOG)
    io, bus, (hip, _), _ = make_io()

    def broken(values, now_s):
        raise RuntimeError("a bug in a handler")

    io.listen(hip.heartbeat_id, contract.codec("Heartbeat"), broken)
    bus.push(heartbeat(0), heartbeat(0), encoder(0, 0.5))
    assert io.drain(0.0) == 1  # the encoder frame after them is still read
    assert io.dropped["handler_error"] == 2 and io.rx == {"Get_Encoder_Estimates": 1} and frames_add_up(io)
    records = [r for r in caplog.records if r.name == LOG]
    assert [r.getMessage() for r in records] == [f"handler of Heartbeat raised on {heartbeat(0).data.hex()}"] * 2
    assert all(r.exc_info and r.exc_info[0] is RuntimeError for r in records)


@pytest.mark.parametrize("exc", [ValueError, TypeError, OverflowError])
def test_a_handler_refusing_values_by_raising_counts_the_frame_invalid(exc):
    io, bus, (hip, _), _ = make_io()

    def refusing(values, now_s):
        raise exc("no")

    io.listen(hip.heartbeat_id, contract.codec("Heartbeat"), refusing)
    bus.push(heartbeat(0), heartbeat(0))
    assert io.drain(0.0) == 0 and io.dropped == {"invalid": 2} and not io.rx


# --------------------------------------------------------------------------- counting and waiting
def test_drain_never_waits_on_the_bus():
    class Recording(FakeBus):
        def __init__(self):
            super().__init__()
            self.timeouts = []

        def recv(self, timeout=None):
            self.timeouts.append(timeout)
            return super().recv(timeout)

    bus = Recording()
    io, _, _, _ = make_io(bus)
    bus.push(encoder(0, 0.1), encoder(1, -0.1))
    io.drain(0.0)
    io.drain(0.01)
    assert bus.timeouts == [0.0, 0.0, 0.0, 0.0]


def test_a_frame_whose_payload_length_is_not_its_dlc_is_malformed():
    io, bus, _, _ = make_io()
    good = encoder(0, 0.1)
    bus.push(can.Message(arbitration_id=good.arbitration_id, dlc=8, data=bytes(good.data)[:4], is_extended_id=False,
                         check=False),
             can.Message(arbitration_id=good.arbitration_id, dlc=4, data=bytes(good.data), is_extended_id=False,
                         check=False))
    assert io.drain(0.0) == 0 and io.dropped == {"malformed": 2}


def test_every_health_reading_is_listened_to_on_each_axis():
    io, bus, (hip, knee), _ = make_io()
    temp, iq = contract.codec("Get_Temperature"), contract.codec("Get_Iq")
    for node in (0, 1):
        bus.push(data_frame(contract.odrive_id(node, "Get_Temperature"), temp.pack(40.0 + node, 50.0)),
                 data_frame(contract.odrive_id(node, "Get_Iq"), iq.pack(1.0, 2.0 + node)))
    assert io.drain(0.5) == 4 and io.rx == {"Get_Temperature": 2, "Get_Iq": 2}
    assert (hip.fet_temp_c, knee.fet_temp_c, hip.iq_a, knee.iq_a) == (40.0, 41.0, 2.0, 3.0)


def test_frames_sent_are_counted_by_name_and_others_as_other():
    io, bus, (hip, knee), _ = make_io()
    assert io.send(hip.state_frame(AxisState.IDLE)) and io.send(knee.pos_frame(-1.0))
    assert io.send(data_frame(0x208, RANGE.pack(1.0, 1, 0)))  # not a frame we command: sent, as "other"
    assert io.send(can.Message(arbitration_id=0x7F0, data=b"", is_extended_id=False))
    assert io.tx == {"Set_Axis_State": 1, "Set_Input_Pos": 1, "other": 2}


# --------------------------------------------------------------------------- ReopenPolicy
@pytest.mark.parametrize("name", ["first_delay_s", "max_delay_s", "stable_s"])
@pytest.mark.parametrize("bad", [-0.001, math.nan, math.inf, -math.inf, "1"])
def test_reopen_policy_times_must_be_finite_and_not_negative(name, bad):
    with pytest.raises(ValueError, match=rf"^ReopenPolicy\.{name} must be finite and >= 0 s, got "):
        ReopenPolicy(**{name: bad})


def test_reopen_policy_limits_are_inclusive_and_checked_against_each_other():
    ReopenPolicy(first_delay_s=0.0, max_delay_s=0.0, stable_s=0.0, factor=1.0)  # every bound itself is fine
    ReopenPolicy(first_delay_s=0.5, max_delay_s=0.5)
    with pytest.raises(ValueError, match="^ReopenPolicy.max_delay_s must not be below first_delay_s$"):
        ReopenPolicy(first_delay_s=0.5, max_delay_s=0.4)
    for bad in (0.999, math.nan, math.inf):
        with pytest.raises(ValueError, match=r"^ReopenPolicy\.factor must be finite and >= 1, got "):
            ReopenPolicy(factor=bad)
    ReopenPolicy(factor=1.5)


def test_a_policy_factor_of_one_retries_at_a_constant_pace():
    factory = Factory(failing=3)
    io, bus, _, _ = make_io(reopen=factory, policy=ReopenPolicy(first_delay_s=0.125, max_delay_s=1.0, factor=1.0))
    bus.recv_error = can.CanOperationError("down")
    io.drain(0.0)
    calls = []
    for k in range(1, 60):
        t = k / 64  # exact in binary: the pace is not blurred by rounding
        before = factory.calls
        io.drain(t)
        if factory.calls != before:
            calls.append(t)
    assert calls == [0.125, 0.25, 0.375, 0.5]


def test_an_outage_exactly_stable_s_after_a_reopen_starts_the_backoff_again():
    factory = Factory()
    io, bus, _, _ = make_io(reopen=factory, policy=ReopenPolicy(first_delay_s=0.05, stable_s=1.0))
    bus.recv_error = can.CanOperationError("down")
    io.drain(0.0)
    io.drain(0.05)  # reopened at 0.05
    factory.opened[-1].recv_error = can.CanOperationError("down again")
    io.drain(1.05)  # up exactly stable_s: the wait is first_delay_s again
    io.drain(1.099)
    assert factory.calls == 1
    io.drain(1.1)
    assert factory.calls == 2


# --------------------------------------------------------------------------- the guard, for other DBC layouts
_SET_INPUT_POS = ''' SG_ Input_Pos : 0|32@1+ (1,0) [0|0] "rev" ODrive
 SG_ Vel_FF : 32|16@1- (0.001,0) [-32.768|32.767] "rev/s" ODrive
 SG_ Torque_FF : 48|16@1- (0.001,0) [-32.768|32.767] "Nm" ODrive
'''
_FLOAT = "SIG_VALTYPE_ 12 Input_Pos : 1;\n"
LAYOUTS = {
    # name: (Set_Input_Pos's signals, Input_Pos is a float32, extra value types)
    "as shipped": (_SET_INPUT_POS, _FLOAT, ""),
    "scaled float": (' SG_ Input_Pos : 0|32@1+ (2,0) [0|0] "rev" ODrive\n', _FLOAT, ""),
    "offset float": (' SG_ Input_Pos : 0|32@1+ (1,1) [0|0] "rev" ODrive\n', _FLOAT, ""),
    "int32": (' SG_ Input_Pos : 0|32@1- (1,0) [0|0] "rev" ODrive\n', "", ""),
    "scaled int32": (' SG_ Input_Pos : 0|32@1- (0.001,0) [0|0] "rev" ODrive\n', "", ""),
    "double": (' SG_ Input_Pos : 0|64@1- (1,0) [0|0] "rev" ODrive\n', "SIG_VALTYPE_ 12 Input_Pos : 2;\n", ""),
    "after another float": (' SG_ Spare : 0|32@1+ (1,0) [0|0] "" ODrive\n'
                            ' SG_ Input_Pos : 32|32@1+ (1,0) [0|0] "rev" ODrive\n', _FLOAT,
                            "SIG_VALTYPE_ 12 Spare : 1;\n"),
    "big endian": (' SG_ Input_Pos : 0|32@0+ (1,0) [0|0] "rev" ODrive\n', _FLOAT, ""),
    "bit 1": (' SG_ Input_Pos : 1|32@1+ (1,0) [0|0] "rev" ODrive\n', _FLOAT, ""),
}
SB_COMMAND = 'BO_ 527 SB_Config: 1 Controller\n SG_ Mode : 0|8@1+ (1,0) [0|255] "" SensorBoard\n\n'


def contract_with(layout: str) -> BusContract:
    """The project's DBC with Set_Input_Pos laid out as ``layout`` and a command to the sensor board."""
    signals, value_type, extra = LAYOUTS[layout]
    text = open(DBC_PATH, encoding="utf-8").read()
    assert _SET_INPUT_POS in text and _FLOAT in text
    text = text.replace(_SET_INPUT_POS, signals).replace(_FLOAT, value_type + extra)
    text = text.replace("BO_ 513 SB_Heartbeat", SB_COMMAND + "BO_ 513 SB_Heartbeat")
    return BusContract(cantools.database.load_string(text, strict=True))


@pytest.mark.parametrize("layout", list(LAYOUTS))
def test_the_guard_reads_input_pos_whatever_the_dbc_layout(layout):
    c = contract_with(layout)
    codec = c.codec("Set_Input_Pos")
    axes = [AxisLink(a, c) for a in default_axes()]
    io = BusIO(FakeBus(), c, axes, SensorLink(16))
    hip = axes[0]
    lo, hi = hip.pos_bounds_rev  # about -0.716 and 1.194 rev

    def frame(rev):
        values = [0.0] * len(codec.signal_names)
        values[codec.signal_names.index("Input_Pos")] = rev
        if "Spare" in codec.signal_names:
            values[codec.signal_names.index("Spare")] = 0.5  # inside the limits: must not be read as Input_Pos
        return data_frame(hip.pos_id, codec.pack(*values))

    inside = [0, 1] if layout == "int32" else [lo * 0.5, hi * 0.5, 0.5]
    outside = [2, -1, 100] if layout == "int32" else [hi + 0.01, lo - 0.01, 5.0, -5.0]
    for rev in inside:
        assert io.send(frame(rev)), (layout, rev)
    for rev in outside:
        assert not io.send(frame(rev)), (layout, rev)
    assert io.tx["Set_Input_Pos"] == len(inside) and io.dropped["refused_outside_limits"] == len(outside)


def test_a_command_to_the_sensor_board_from_someone_else_is_another_master():
    c = contract_with("as shipped")
    io = BusIO(FakeBus(), c, [AxisLink(a, c) for a in default_axes()], SensorLink(16))
    io.bus.push(can.Message(arbitration_id=527, data=b"\x01", is_extended_id=False))
    assert io.drain(0.0) == 0 and io.dropped == {"unexpected_sender": 1} and io.foreign == {527: 1}
    assert io.send(can.Message(arbitration_id=527, data=b"\x01", is_extended_id=False))
    assert io.tx == {"SB_Config": 1}


# --------------------------------------------------------------------------- each reason's own limit
def _reach(io, bus, hip, knee, reason):
    """One event of ``reason``."""
    if reason == "bus_off":
        bus.push(BUS_OFF)
        io.drain(0.0)
    elif reason == "malformed":
        bus.push(data_frame(0x208, RANGE.pack(1.0, 1, 0) + b"\x00"))
        io.drain(0.0)
    elif reason == "invalid":
        bus.push(encoder(0, math.nan))
        io.drain(0.0)
    elif reason == "handler_error":
        bus.push(heartbeat(0))
        io.drain(0.0)
    elif reason == "refused_outside_limits":
        io.send(data_frame(knee.pos_id, contract.codec("Set_Input_Pos").pack(50.0, 0.0, 0.0)))
    elif reason == "tx_error":
        bus.send_error = can.CanOperationError("tx")
        io.send(hip.state_frame(AxisState.IDLE))
        bus.send_error = None


@pytest.mark.parametrize("reason", ["bus_off", "malformed", "invalid", "handler_error", "refused_outside_limits",
                                    "tx_error"])
def test_each_reason_has_its_own_warning_limit_and_says_so_by_name(reason, caplog):
    caplog.set_level(logging.WARNING, logger=LOG)
    io, bus, (hip, knee), _ = make_io()

    def broken(values, now_s):
        raise RuntimeError("bug")

    io.listen(hip.heartbeat_id, contract.codec("Heartbeat"), broken)
    for _ in range(5):
        _reach(io, bus, hip, knee, reason)
    _reach(io, bus, hip, knee, "bus_off" if reason != "bus_off" else "malformed")  # another reason: its own count
    texts = lines(caplog)
    assert len(texts) == 4 and io.dropped[reason] == 5
    assert texts[2].endswith(f" (no more {reason} warnings: see BusIO.dropped)")
    assert not texts[0].endswith("BusIO.dropped)") and not texts[3].endswith("BusIO.dropped)")


def test_expected_errors_are_warned_without_a_traceback(caplog):
    caplog.set_level(logging.WARNING, logger=LOG)
    io, bus, (hip, _), _ = make_io()
    bus.recv_error = can.CanOperationError("boom")
    io.drain(0.0)
    bus.recv_error = None
    bus.send_error = can.CanOperationError("tx")
    io.send(hip.state_frame(AxisState.IDLE))
    records = [r for r in caplog.records if r.name == LOG]
    assert len(records) == 2 and not any(r.exc_info for r in records)


def test_down_is_false_every_outage_is_counted_and_sends_while_down_are_each_dropped():
    factory = Factory(failing=1)
    io, bus, (hip, _), _ = make_io(reopen=factory)
    for k in range(3):
        io.bus.recv_error = can.CanOperationError("down")
        io.drain(10.0 * k)
        assert io.bus_up is False
        assert not io.send(hip.state_frame(AxisState.IDLE)) and not io.send(hip.state_frame(AxisState.IDLE))
        io.drain(10.0 * k + 0.05)
        io.drain(10.0 * k + 0.2)
        assert io.bus_up is True
    assert io.bus_events == {"bus_down": 3, "bus_reopens": 3, "bus_reopen_failures": 1}
    assert io.dropped["tx_while_down"] == 6 and io.dropped["bus_error"] == 3


def test_a_send_with_its_time_paces_the_reopening_itself():
    factory = Factory()
    io, bus, (hip, _), _ = make_io(reopen=factory)
    bus.recv_error = can.CanOperationError("down")
    io.drain(1.0)
    assert not io.send(hip.state_frame(AxisState.IDLE), 1.04)  # not yet due
    assert factory.calls == 0
    assert io.send(hip.state_frame(AxisState.IDLE), 1.05)  # due: reopened by the send, and sent
    assert factory.calls == 1 and io.bus_up and len(factory.opened[0].sent) == 1
