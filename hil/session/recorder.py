"""The HIL session's bus recorder: every frame on the channel to a log file, with counts and latency.

:class:`BusRecorder` writes with python-can's writer for the path's suffix (BLF or candump),
counts frames each way (what the controller sends, by the bus contract's senders, and what the
leg sends), measures command-to-feedback latency (each Set_Input_Pos to the next
Get_Encoder_Estimates from the same axis, kernel receive timestamps) and, if asked, keeps every
Set_Input_Pos target for the command audit (:mod:`hil.faults.audit`).

Beside the recording, when it stops, it writes the log's metadata
(:func:`hil.analysis.buslog.metadata_path`: ``bus.blf.json`` beside ``bus.blf``), stamped
``bus-log`` version :data:`hil.analysis.buslog.METADATA_VERSION` (:func:`controller.errors.stamp`):
the channel, the frames written each way, the recorder's error. Its readers
(:func:`hil.analysis.buslog.read_metadata`: ``replay``, ``decode``, the bus load) refuse an
unknown version in one line, read a metadata file without a stamp as version 0, and compare the
frame count with the frames they read, which finds a log cut short at a frame boundary.
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
SET_INPUT_POS = split_arbitration_id(_CONTRACT.odrive_id(0, "Set_Input_Pos"))[1]
GET_ENCODER_ESTIMATES = split_arbitration_id(_CONTRACT.odrive_id(0, "Get_Encoder_Estimates"))[1]
_F32 = struct.Struct("<f")  # Set_Input_Pos's Input_Pos [rev]

def sent_by_controller(msg: can.Message) -> bool:
    """True for a frame only the controller sends: a command of the contract's master messages
    (or a remote request) to a node other than the sensor board."""
    node, cmd = split_arbitration_id(msg.arbitration_id)
    return node != SENSOR_BOARD_NODE_ID and (cmd in CONTROLLER_CMDS or msg.is_remote_frame)


class BusRecorder(threading.Thread):
    """Records every frame on the channel with python-can's writer for ``path``'s suffix, counts
    frames each way and measures command-to-feedback latency. Drains a non-blocking socket every
    10 ms (one system call per frame). With ``audit_commands``, it also keeps every Set_Input_Pos
    target [rev] per node in ``commanded`` (to count targets outside the joint limits later)."""

    def __init__(self, channel: str, path: Path, audit_commands: bool = False) -> None:
        super().__init__(name="bus-recorder", daemon=True)
        from controller.daemon.fastbus import lean
        from controller.daemon.openbus import open_bus

        self.raw = open_bus({"interface": "socketcan", "channel": channel})
        sock = getattr(self.raw, "socket", None)  # None: not SocketCAN (a test's virtual bus)
        for opt in (getattr(socket, "SO_RCVBUFFORCE", None), socket.SO_RCVBUF):
            if opt is None or sock is None:
                continue
            try:  # room for a second of traffic between drains
                sock.setsockopt(socket.SOL_SOCKET, opt, 4 << 20)
                break
            except OSError:
                continue
        self.bus = lean(self.raw)
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
        self.raw.shutdown()
        write_json_atomic(metadata_path(self.path), {
            **stamp(METADATA_KIND, METADATA_VERSION), "log": self.path.name, "channel": self.channel,
            "frames": self.frames, "controller_to_leg": self.to_leg, "leg_to_controller": self.from_leg,
            "error": self.error}, indent=1)

    def summary(self) -> dict[str, Any]:
        lat = sorted(self.latency_s)
        q = (lambda p: lat[min(len(lat) - 1, int(math.ceil(p * len(lat))) - 1)] * 1e6) if lat else (lambda p: None)
        return {
            "file": str(self.path),
            "frames": self.frames,
            "controller_to_leg": self.to_leg,
            "leg_to_controller": self.from_leg,
            "command_to_feedback_us": {"median": q(0.5), "p99": q(0.99), "n": len(lat)},
            "error": self.error,
        }
