"""The bus recorder's metadata beside its log: stamped, read back, and the frame count it gives;
the kernel's count of the frames it lost (SO_RXQ_OVFL), parsed and carried into the metadata.

A real SocketCAN socket needs a kernel with CAN (tests/vcan). Here the kernel's drop counter is
exercised on a UDP socket on the loopback, whose datagrams carry the same 16-byte can_frames and
the same ancillary data (SO_TIMESTAMPNS, SO_RXQ_OVFL): the kernel code that counts and reports
drops is the socket layer's, shared by both families."""

from __future__ import annotations

import json
import socket
import struct
import uuid

import can
import pytest

import controller.daemon.openbus as openbus
from controller.errors import InputError
from hil.analysis.buslog import LogReading, frames_lost, metadata_path, read_metadata
from hil.session.recorder import SO_RXQ_OVFL, SO_TIMESTAMPNS, BusRecorder, parse_ancillary, read_frame, socket_drops

CAN_FRAME = struct.Struct("=IBBBB8s")  # struct can_frame: can_id (with its flags), len, pad, res, len8_dlc, data


@pytest.fixture
def virtual_channel(monkeypatch):
    """The recorder's SocketCAN bus replaced by a python-can virtual bus on a fresh channel."""
    channel = "rec-" + "".join(chr(ord("a") + int(c, 16)) for c in uuid.uuid4().hex[:8])  # no digits: BLF's channel
    monkeypatch.setattr(openbus, "open_bus", lambda kw: can.Bus(interface="virtual", channel=channel))
    return channel


@pytest.mark.parametrize("suffix", [".blf", ".log"])
def test_the_recorder_writes_stamped_metadata_counting_the_frames_it_wrote(virtual_channel, tmp_path, suffix):
    from protocol import BusContract

    c = BusContract.load()
    log = tmp_path / f"bus{suffix}"
    rec = BusRecorder("vcan0", log)
    sender = can.Bus(interface="virtual", channel=virtual_channel)
    rec.start()
    try:
        for i in range(25):
            sender.send(can.Message(arbitration_id=c.odrive_id(i % 2, "Set_Input_Pos"), data=bytes(8),
                                    is_extended_id=False))
            sender.send(can.Message(arbitration_id=c.odrive_id(i % 2, "Get_Encoder_Estimates"), data=bytes(8),
                                    is_extended_id=False))
    finally:
        sender.shutdown()
        rec.stop()  # drains what is left, closes the log, then writes the metadata
    meta = json.loads(metadata_path(log).read_text())
    assert list(meta)[:3] == ["format", "format_version", "project_version"]
    assert (meta["format"], meta["format_version"]) == ("bus-log", 1)
    assert (meta["frames"], meta["controller_to_leg"], meta["leg_to_controller"]) == (50, 25, 25)
    assert meta["log"] == log.name and meta["error"] is None
    assert meta["frames_lost"] is None and frames_lost(meta) is None  # a virtual bus: unknown, not 0
    assert read_metadata(log) == meta
    reading = LogReading(log, meta["frames"])
    assert sum(1 for _ in reading) == 50 and reading.damage is None


def test_metadata_of_an_unknown_version_or_kind_is_refused_in_one_line(tmp_path):
    log = tmp_path / "bus.blf"
    assert read_metadata(log) is None  # a log without metadata (from elsewhere): nothing to check
    meta = metadata_path(log)
    assert meta.name == "bus.blf.json"
    meta.write_text(json.dumps({"format": "bus-log", "format_version": 2, "project_version": "0.9", "frames": 1}))
    with pytest.raises(InputError, match=r"bus.blf.json: bus-log format version 2 \(written by elegant-stepping 0.9\)"):
        read_metadata(log)
    meta.write_text(json.dumps({"format": "metrics", "format_version": 1}))
    with pytest.raises(InputError, match="a 'metrics' file, not a bus-log file"):
        read_metadata(log)
    meta.write_text("{not json")
    with pytest.raises(InputError, match="not valid JSON"):
        read_metadata(log)
    meta.write_text(json.dumps({"format": "bus-log", "format_version": 1, "frames": "many"}))
    with pytest.raises(InputError, match="'frames' is 'many'"):
        read_metadata(log)
    for bad in (-1, "some", True, 1.5):
        meta.write_text(json.dumps({"format": "bus-log", "format_version": 1, "frames": 3, "frames_lost": bad}))
        with pytest.raises(InputError, match=r"bus.blf.json: 'frames_lost' is .*, not a count of frames"):
            read_metadata(log)


def test_metadata_without_a_stamp_is_read_as_version_0(tmp_path):
    log = tmp_path / "bus.log"
    metadata_path(log).write_text(json.dumps({"frames": 3, "channel": "vcan0"}))
    assert read_metadata(log) == {"frames": 3, "channel": "vcan0"}


def test_the_drop_count_and_timestamp_are_parsed_from_ancillary_data_built_by_hand():
    ts = struct.pack("@ll", 1700000000, 250_000_000)
    ovfl = struct.pack("=I", 7)
    assert SO_RXQ_OVFL == 40 and SO_TIMESTAMPNS == 35  # Linux's values
    assert parse_ancillary([(socket.SOL_SOCKET, 35, ts), (socket.SOL_SOCKET, 40, ovfl)]) == (1700000000.25, 7)
    assert parse_ancillary([(socket.SOL_SOCKET, 40, ovfl), (socket.SOL_SOCKET, 35, ts)]) == (1700000000.25, 7)
    # the kernel attaches the count only once the socket has dropped a frame: absent means none yet
    assert parse_ancillary([(socket.SOL_SOCKET, 35, ts)]) == (1700000000.25, 0)
    assert parse_ancillary([]) == (None, 0)
    # another level's message of the same type number, or a short one, is not the count
    assert parse_ancillary([(socket.IPPROTO_IP, 40, ovfl), (socket.SOL_SOCKET, 40, b"\x01")]) == (None, 0)
    assert parse_ancillary([(socket.SOL_SOCKET, 40, struct.pack("=I", 0xFFFFFFFF))])[1] == 0xFFFFFFFF


def _receiver(rcvbuf: int | None = None, count_drops: bool = True) -> socket.socket:
    """A UDP socket on the loopback set up as python-can sets up its SocketCAN socket (kernel
    timestamps), and as the recorder does (the drop counter), non-blocking."""
    r = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    r.bind(("127.0.0.1", 0))
    r.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
    if count_drops:
        r.setsockopt(socket.SOL_SOCKET, SO_RXQ_OVFL, 1)
    if rcvbuf is not None:
        r.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf)
    r.setblocking(False)
    return r


def _sender(to: socket.socket) -> socket.socket:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.connect(to.getsockname())
    return s


def _frame(can_id: int, data: bytes, flags: int = 0) -> bytes:
    return CAN_FRAME.pack(can_id | flags, len(data), 0, 0, 0, data.ljust(8, b"\0"))


def test_a_frame_read_with_the_drop_counter_is_the_message_python_can_makes_of_it():
    from can.interfaces.socketcan import constants as c
    from can.interfaces.socketcan.socketcan import capture_message

    ours, theirs = _receiver(), _receiver(count_drops=False)
    to_ours, to_theirs = _sender(ours), _sender(theirs)
    fd = struct.pack("=IBBBB64s", 0x123, 12, c.CANFD_BRS, 0, 0, bytes(range(12)))
    raws = [_frame(0x00C, struct.pack("<fhh", 0.25, 1, -1)), _frame(0x1ABCDEF0, b"\x01\x02\x03", c.CAN_EFF_FLAG),
            _frame(0x001, b"", c.CAN_RTR_FLAG), _frame(0x7FF, b"\xff"), fd]
    try:
        for raw in raws:
            to_ours.send(raw)
            to_theirs.send(raw)
        for raw in raws:
            got = read_frame(ours)
            assert got is not None
            msg, dropped = got
            theirs.settimeout(10.0)  # it is there already (loopback delivery is synchronous); never hang
            expected = capture_message(theirs)
            assert dropped == 0
            assert msg.equals(expected, timestamp_delta=None), (msg, expected)
            assert msg.channel is None and msg.timestamp > 0  # the kernel's timestamp, as python-can's
        assert read_frame(ours) is None  # none waiting: None, not an error
    finally:
        for sock in (ours, theirs, to_ours, to_theirs):
            sock.close()


def test_the_kernel_counts_the_frames_a_full_receive_queue_dropped_and_the_next_frame_carries_it():
    r = _receiver(rcvbuf=1)  # the kernel's smallest queue: a few frames
    s = _sender(r)
    try:
        sent = 300
        for i in range(sent):
            s.send(_frame(i, bytes(8)))
        got = []
        while (item := read_frame(r)) is not None:
            got.append(item)
        lost = sent - len(got)
        assert lost > 0
        assert [m.arbitration_id for m, _ in got] == list(range(len(got)))  # the first ones, in order
        assert all(dropped == 0 for _, dropped in got)  # queued before the queue overflowed
        assert socket_drops(r) == lost  # SO_MEMINFO: the same counter, read at any time
        s.send(_frame(0x7FF, b"\x01"))
        msg, dropped = read_frame(r)
        assert msg.arbitration_id == 0x7FF and dropped == lost  # SO_RXQ_OVFL: cumulative, on the next frame
    finally:
        r.close()
        s.close()


class _DatagramBus:
    """What the recorder takes of python-can's SocketCAN bus (its ``socket``, ``shutdown``), on a
    loopback UDP socket carrying can_frames."""

    def __init__(self) -> None:
        self.socket = _receiver()

    def shutdown(self) -> None:
        self.socket.close()


def test_the_recorder_writes_the_kernels_count_of_the_frames_it_lost(monkeypatch, tmp_path):
    bus = _DatagramBus()
    monkeypatch.setattr(openbus, "open_bus", lambda kw: bus)
    log = tmp_path / "bus.log"
    rec = BusRecorder("vcan0", log)
    assert bus.socket.getsockopt(socket.SOL_SOCKET, SO_RXQ_OVFL) == 1  # the recorder turned the counter on
    assert rec.frames_lost == 0
    bus.socket.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1)  # a queue that overflows (the recorder's is 4 MiB)
    sender = _sender(bus.socket)
    sent = 300
    try:
        for i in range(sent):  # before the recorder drains: the queue overflows, the rest is dropped
            sender.send(_frame(i, bytes(8)))
    finally:
        sender.close()
    rec.start()
    rec.stop()
    meta = read_metadata(log)
    assert meta["error"] is None and meta["frames"] > 0
    assert meta["frames_lost"] == sent - meta["frames"] > 0 and frames_lost(meta) == meta["frames_lost"]
    assert rec.summary()["frames_lost"] == meta["frames_lost"]
    assert [m.arbitration_id for m in LogReading(log, meta["frames"])] == list(range(meta["frames"]))


def test_the_recorder_counts_the_lost_frames_from_the_next_frame_where_the_kernel_has_no_meminfo(monkeypatch, tmp_path):
    """Without SO_MEMINFO (None), the count comes from SO_RXQ_OVFL alone: the first frame queued
    after the drops carries it. The test drains by hand, so the order is the test's, not a race."""
    import hil.session.recorder as recorder

    bus = _DatagramBus()
    monkeypatch.setattr(openbus, "open_bus", lambda kw: bus)
    monkeypatch.setattr(recorder, "socket_drops", lambda sock: None)
    log = tmp_path / "bus.log"
    rec = BusRecorder("vcan0", log)
    bus.socket.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1)
    sender = _sender(bus.socket)
    try:
        for i in range(300):
            sender.send(_frame(i, bytes(8)))
        rec._drain()
        read = rec.frames
        assert 0 < read < 300 and rec.frames_lost == 0  # the frames read were queued before the drops
        sender.send(_frame(0x7FF, b"\x01"))
        rec._drain()
        assert rec.frames == read + 1 and rec.frames_lost == 300 - read
    finally:
        sender.close()
    rec.start()
    rec.stop()
    assert read_metadata(log)["frames_lost"] == 300 - read


def test_the_simulated_time_frames_are_counted_on_the_side_that_sends_them():
    from hil.session.recorder import sent_by_controller
    from protocol.contract import CONTROLLER_STATE_ID, END_OF_PERIOD_ID, SIM_SYNC_ID

    def ext(arb: int) -> can.Message:
        return can.Message(arbitration_id=arb, is_extended_id=True, data=bytes(8))

    assert not sent_by_controller(ext(SIM_SYNC_ID))  # the plant's
    assert sent_by_controller(ext(END_OF_PERIOD_ID)) and sent_by_controller(ext(CONTROLLER_STATE_ID))
    assert not sent_by_controller(ext(0x1234567))  # an unknown extended frame is nobody's command
