"""The HIL session's bus recorder: every frame on the channel to a log file, with counts and latency.

:class:`BusRecorder` writes with python-can's writer for the path's suffix (BLF or candump),
counts frames each way (what the controller sends, by the bus contract's senders, and what the
leg sends), measures command-to-feedback latency (each Set_Input_Pos to the next
Get_Encoder_Estimates from the same axis, kernel receive timestamps) and, if asked, keeps every
Set_Input_Pos target for the command audit (:mod:`hil.faults.audit`).

Beside the recording, when it stops, it writes the log's metadata
(:func:`hil.analysis.buslog.metadata_path`: ``bus.blf.json`` beside ``bus.blf``), stamped
``bus-log`` version :data:`hil.analysis.buslog.METADATA_VERSION` (:func:`controller.errors.stamp`):
the channel, the frames written each way, the frames the kernel dropped before the recorder could
read them (``frames_lost``, below), the recorder's error. Its readers
(:func:`hil.analysis.buslog.read_metadata`: ``replay``, ``decode``, the bus load) refuse an
unknown version in one line, read a metadata file without a stamp as version 0, and compare the
frame count with the frames they read, which finds a log cut short at a frame boundary.

**Lost frames.** A frame that arrives while the socket's receive queue is full is dropped by the
kernel, and the log would hold a gap nobody sees. So, on SocketCAN, the recorder turns on the
kernel's drop counter (``SO_RXQ_OVFL``): each frame it then reads carries, as ancillary data
(``SOL_SOCKET``, ``SO_RXQ_OVFL``, a uint32), how many frames this socket has dropped so far. The
counter is cumulative, so the last (largest) value seen is the count; at stop, ``SO_MEMINFO``'s
drop count (the same kernel counter, which also sees drops after the last frame read) is taken
where the kernel gives it. python-can's SocketCAN ``recv`` does not hand out ancillary data (and
its reader asserts there is none beside the timestamp), so the recorder reads the socket itself
(:func:`read_frame`: one ``recvmsg``, the frame dissected by python-can's own
``dissect_can_frame`` into the same :class:`can.Message` python-can's reader makes, the kernel's
``SO_TIMESTAMPNS`` timestamp as before). On any other bus (a test's virtual bus), or where
python-can's internals are not as expected (:func:`controller.daemon.fastbus.internals_work`),
frames are read as before and ``frames_lost`` is None: unknown, not zero.
"""

from __future__ import annotations

import math
import socket
import struct
import threading
import time
from array import array
from pathlib import Path
from typing import Any

import can

from hil.analysis.buslog import METADATA_KIND, METADATA_VERSION, metadata_path
from protocol import SENSOR_BOARD_NODE_ID, BusContract, split_arbitration_id

_CONTRACT = BusContract.load()
CONTROLLER_CMDS = _CONTRACT.odrive_master_cmds  # the DBC's messages sent by the Controller
_CONTROLLER_EXTENDED = frozenset(i for i, c in _CONTRACT.extended.items() if c.message.senders == ["Controller"])
SET_INPUT_POS = split_arbitration_id(_CONTRACT.odrive_id(0, "Set_Input_Pos"))[1]
GET_ENCODER_ESTIMATES = split_arbitration_id(_CONTRACT.odrive_id(0, "Get_Encoder_Estimates"))[1]
_F32 = struct.Struct("<f")  # Set_Input_Pos's Input_Pos [rev]

SO_RXQ_OVFL = getattr(socket, "SO_RXQ_OVFL", 40)  # Linux's value; Python's socket module may lack the name
SO_TIMESTAMPNS = getattr(socket, "SO_TIMESTAMPNS", 35)  # what python-can's SocketCAN bus turns on
SO_MEMINFO = getattr(socket, "SO_MEMINFO", 55)
SO_RCVBUFFORCE = getattr(socket, "SO_RCVBUFFORCE", 33)  # Python's socket module lacks it: without the
# Linux value here the recorder only ever asked SO_RCVBUF, which the kernel silently caps at
# net.core.rmem_max (212992 by default: 425984 bytes, ~550 frames, ~0.1 s of a HIL session; seen
# inside User-Mode Linux by tests/vcan/test_recorder_vcan.py)
RCVBUF_BYTES = 4 << 20  # asked for: room for a second of traffic between drains
_SK_MEMINFO_DROPS = 8  # index of the drop count in SO_MEMINFO's uint32 array (Linux >= 4.6)
_U32 = struct.Struct("=I")
_TIMESPEC = struct.Struct("@ll")  # struct timespec: seconds, nanoseconds
_CANFD_MTU = 72  # the largest frame read (python-can reads this much: an FD frame stays whole)
try:  # python-can's own frame layout (used only where fastbus.internals_work() says it behaves)
    from can.interfaces.socketcan import constants as _c
    from can.interfaces.socketcan.socketcan import dissect_can_frame
except ImportError:  # python-can without SocketCAN support (not Linux): frames read as before, loss unknown
    _c = dissect_can_frame = None
_ANCILLARY_SIZE = socket.CMSG_SPACE(_TIMESPEC.size) + socket.CMSG_SPACE(_U32.size)


def parse_ancillary(ancdata: list[tuple[int, int, bytes]]) -> tuple[float | None, int]:
    """(kernel receive timestamp [s], frames dropped so far) from one ``recvmsg``'s ancillary data.

    The timestamp is ``SO_TIMESTAMPNS``'s (None if absent). The drop count is ``SO_RXQ_OVFL``'s
    uint32; the kernel attaches it only once the socket has dropped a frame, so with the counter
    turned on its absence means 0 (returned as 0; the caller knows whether it turned it on)."""
    timestamp_s: float | None = None
    dropped = 0
    for level, kind, data in ancdata:
        if level != socket.SOL_SOCKET:
            continue
        if kind == SO_TIMESTAMPNS and len(data) >= _TIMESPEC.size:
            seconds, nanoseconds = _TIMESPEC.unpack_from(data)
            timestamp_s = seconds + nanoseconds * 1e-9
        elif kind == SO_RXQ_OVFL and len(data) >= _U32.size:
            dropped = _U32.unpack_from(data)[0]
    return timestamp_s, dropped


def read_frame(sock: socket.socket) -> tuple[can.Message, int] | None:
    """One frame from the non-blocking SocketCAN socket ``sock`` and the socket's drop count so
    far (:func:`parse_ancillary`); None when no frame is waiting.

    The frame is the :class:`can.Message` python-can's reader (``capture_message``, no channel)
    makes of it: the same identifier, flags, length, data and kernel timestamp.

    Raises:
        can.CanOperationError: the socket failed, or the kernel gave no timestamp (python-can's
            bus always turns ``SO_TIMESTAMPNS`` on).
    """
    c = _c
    try:
        cf, ancdata, msg_flags, _addr = sock.recvmsg(_CANFD_MTU, _ANCILLARY_SIZE)
    except (BlockingIOError, InterruptedError):
        return None
    except OSError as error:
        raise can.CanOperationError(f"Error receiving: {error.strerror}", error.errno) from error
    timestamp_s, dropped = parse_ancillary(ancdata)
    if timestamp_s is None:
        raise can.CanOperationError("a received frame without its kernel timestamp (SO_TIMESTAMPNS)")
    can_id, can_dlc, flags, data = dissect_can_frame(cf)
    ext = bool(can_id & c.CAN_EFF_FLAG)
    msg = can.Message(
        timestamp=timestamp_s,
        channel=None,
        arbitration_id=can_id & (0x1FFFFFFF if ext else 0x7FF),
        is_extended_id=ext,
        is_remote_frame=bool(can_id & c.CAN_RTR_FLAG),
        is_error_frame=bool(can_id & c.CAN_ERR_FLAG),
        is_fd=len(cf) == c.CANFD_MTU,
        is_rx=not bool(msg_flags & socket.MSG_DONTROUTE),
        bitrate_switch=bool(flags & c.CANFD_BRS),
        error_state_indicator=bool(flags & c.CANFD_ESI),
        dlc=can_dlc,
        data=data,
    )
    return msg, dropped


def socket_drops(sock: socket.socket) -> int | None:
    """The kernel's count of frames dropped on ``sock`` (``SO_MEMINFO``), None where not given."""
    try:
        raw = sock.getsockopt(socket.SOL_SOCKET, SO_MEMINFO, 4 * (_SK_MEMINFO_DROPS + 1))
    except OSError:
        return None
    if len(raw) < 4 * (_SK_MEMINFO_DROPS + 1):
        return None
    return _U32.unpack_from(raw, 4 * _SK_MEMINFO_DROPS)[0]

def sent_by_controller(msg: can.Message) -> bool:
    """True for a frame only the controller sends: a command of the contract's master messages
    (or a remote request) to a node other than the sensor board; in simulated time also its
    ``ES_End_Of_Period`` and ``ES_Controller_State`` (the plant's ``ES_Sim_Sync`` is the leg's)."""
    if msg.is_extended_id:
        return msg.arbitration_id in _CONTROLLER_EXTENDED
    node, cmd = split_arbitration_id(msg.arbitration_id)
    return node != SENSOR_BOARD_NODE_ID and (cmd in CONTROLLER_CMDS or msg.is_remote_frame)


class BusRecorder(threading.Thread):
    """Records every frame on the channel with python-can's writer for ``path``'s suffix, counts
    frames each way and measures command-to-feedback latency. Drains a non-blocking socket every
    10 ms (one system call per frame). With ``audit_commands``, it also keeps every Set_Input_Pos
    target [rev] per node in ``commanded`` (to count targets outside the joint limits later).
    ``frames_lost``: the frames the kernel dropped on its socket so far (None: not counted, not
    SocketCAN). ``rcvbuf_bytes``: the receive buffer the kernel gave its socket (it asks
    :data:`RCVBUF_BYTES` with ``SO_RCVBUFFORCE``, else ``SO_RCVBUF``, capped at rmem_max)."""

    def __init__(self, channel: str, path: Path, audit_commands: bool = False) -> None:
        super().__init__(name="bus-recorder", daemon=True)
        from controller.daemon.fastbus import internals_work, lean
        from controller.daemon.openbus import open_bus

        self.raw = open_bus({"interface": "socketcan", "channel": channel})
        sock = getattr(self.raw, "socket", None)  # None: not SocketCAN (a test's virtual bus)
        self.rcvbuf_bytes: int | None = None  # the receive buffer the kernel gave (None: not SocketCAN)
        if sock is not None:
            for opt in (SO_RCVBUFFORCE, socket.SO_RCVBUF):  # FORCE: past rmem_max, needs CAP_NET_ADMIN
                try:
                    sock.setsockopt(socket.SOL_SOCKET, opt, RCVBUF_BYTES)
                    break
                except OSError:  # EPERM without the capability: SO_RCVBUF, capped at rmem_max
                    continue
            try:
                self.rcvbuf_bytes = sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)
            except OSError:
                pass
        self._sock: socket.socket | None = None  # read by read_frame, counting drops
        self.frames_lost: int | None = None
        if sock is not None and internals_work():
            try:
                sock.setsockopt(socket.SOL_SOCKET, SO_RXQ_OVFL, 1)
            except OSError:  # a kernel without the counter: read as before, the loss unknown
                pass
            else:
                sock.setblocking(False)
                self._sock, self.frames_lost = sock, 0
        self.bus = lean(self.raw) if self._sock is None else self.raw
        try:
            self.writer = can.Logger(str(path))
        except BaseException:
            self.raw.shutdown()
            raise
        self.path = path
        self.channel = channel
        self.stop_event = threading.Event()
        self.frames = 0
        self.to_leg = 0
        self.from_leg = 0
        self.by_id: dict[int, int] = {}
        self._pending: dict[int, float] = {}
        self.latency_s: list[float] = []
        self.commanded: dict[int, array] | None = {} if audit_commands else None
        self.error: str | None = None

    def _take(self, msg: can.Message) -> None:
        self.writer.on_message_received(msg)
        self.frames += 1
        arb = msg.arbitration_id
        self.by_id[arb] = self.by_id.get(arb, 0) + 1
        if msg.is_extended_id:  # simulated time's frames (sent_by_controller's rule, inlined)
            if arb in _CONTROLLER_EXTENDED:
                self.to_leg += 1
            else:
                self.from_leg += 1
            return
        node, cmd = split_arbitration_id(arb)
        if node != SENSOR_BOARD_NODE_ID and (cmd in CONTROLLER_CMDS or msg.is_remote_frame):
            self.to_leg += 1
            if cmd == SET_INPUT_POS:
                if node not in self._pending:
                    self._pending[node] = msg.timestamp
                if self.commanded is not None and len(msg.data) >= 4:
                    self.commanded.setdefault(node, array("f")).append(_F32.unpack_from(msg.data)[0])
        else:
            self.from_leg += 1
            if cmd == GET_ENCODER_ESTIMATES and node != SENSOR_BOARD_NODE_ID:
                t = self._pending.pop(node, None)
                if t is not None:
                    self.latency_s.append(msg.timestamp - t)

    def _drain(self) -> None:
        if self._sock is not None:
            sock, take = self._sock, self._take
            got = read_frame(sock)
            while got is not None:
                msg, dropped = got
                if dropped > self.frames_lost:  # cumulative: the largest is the count
                    self.frames_lost = dropped
                take(msg)
                got = read_frame(sock)
            return
        recv = self.bus.recv
        msg = recv(0)
        while msg is not None:
            self._take(msg)
            msg = recv(0)

    def run(self) -> None:
        try:
            while not self.stop_event.is_set():
                time.sleep(0.01)
                self._drain()
            self._drain()
        except Exception as exc:  # noqa: BLE001 - reported in the metrics
            self.error = repr(exc)

    def stop(self) -> None:
        """Stop recording, close the log, then write its metadata beside it."""
        from controller.atomic import write_json_atomic
        from controller.errors import stamp

        self.stop_event.set()
        self.join(timeout=10)
        self.writer.stop()
        if self._sock is not None:  # drops after the last frame read carry no ancillary data
            final = socket_drops(self._sock)
            if final is not None and final > self.frames_lost:
                self.frames_lost = final
        self.raw.shutdown()
        write_json_atomic(metadata_path(self.path), {
            **stamp(METADATA_KIND, METADATA_VERSION), "log": self.path.name, "channel": self.channel,
            "frames": self.frames, "controller_to_leg": self.to_leg, "leg_to_controller": self.from_leg,
            "frames_lost": self.frames_lost, "error": self.error}, indent=1)

    def summary(self) -> dict[str, Any]:
        lat = sorted(self.latency_s)
        q = (lambda p: lat[min(len(lat) - 1, int(math.ceil(p * len(lat))) - 1)] * 1e6) if lat else (lambda p: None)
        return {
            "file": str(self.path),
            "frames": self.frames,
            "controller_to_leg": self.to_leg,
            "leg_to_controller": self.from_leg,
            "command_to_feedback_us": {"median": q(0.5), "p99": q(0.99), "n": len(lat)},
            "frames_lost": self.frames_lost,
            "error": self.error,
        }
