"""What bring-up hears on the bus: nodes, heartbeats, encoder readings, replies to requests.

:class:`BusWatch` drains a python-can bus without blocking (``recv(0)``) and keeps, per node id,
when it was first and last heard and how many frames it sent; per axis node, its last heartbeat
(:class:`Heartbeat`) and its last encoder estimate (:class:`EncoderReading`, motor side); for
the sensor board, its last SB_Heartbeat; for every arbitration id, the last data frame and when
it came (the replies to Get_* requests). Frames whose node id is not one we expect are another
node's (``unknown_nodes``); data frames that only a master sends (the DBC's ``Controller``
messages, e.g. Set_Input_Pos) or remote requests to one of the nodes mean another master is on
the bus (``foreign_commands``): we never hear our own frames. Error frames are counted.

Time is the injected ``clock`` [s] at the moment a frame is drained (never the frame's own
timestamp: the virtual bus stamps wall-clock time, the simulated leg runs on its own); waiting
calls the injected ``sleep`` between drains, so a test can step a simulated leg inside it.

May import: the standard library, python-can, ``protocol``.
"""

from __future__ import annotations

import logging
import math
from collections import Counter
from dataclasses import dataclass
from typing import Callable, Iterable

import can

from controller import errors
from protocol import AxisState, BusContract, SENSOR_BOARD_NODE_ID, remote_frame, split_arbitration_id

log = logging.getLogger(__name__)

Clock = Callable[[], float]
Sleep = Callable[[float], None]

_MAX_DRAIN = 10_000  # frames read in one drain at most (a flooding bus cannot hold us forever)


@dataclass(frozen=True)
class Heartbeat:
    """An axis's last heartbeat: when it came [s, bring-up clock] and what it said."""

    t_s: float
    error: int
    state: int
    procedure_result: int

    @property
    def state_name(self) -> str:
        try:
            return AxisState(self.state).name
        except ValueError:
            return f"unknown state {self.state}"


@dataclass(frozen=True)
class EncoderReading:
    """An axis's last Get_Encoder_Estimates [s, rev, rev/s: motor side]."""

    t_s: float
    pos_rev: float
    vel_rev_s: float


@dataclass(frozen=True)
class BoardHeartbeat:
    """The sensor board's last SB_Heartbeat [s; uptime in s]."""

    t_s: float
    error: int
    state: int
    fw_version: int
    uptime_s: float


class BusError(errors.BusError, RuntimeError):
    """The bus failed while bring-up was using it (a send or receive raised). Bring-up reports it
    as a failed item; one that escaped would be exit 4 (:class:`controller.errors.BusError`)."""


class BusWatch:
    """Drain the bus and remember what each node said (see the module docstring).

    ``axis_nodes``: the node ids of the configured axes; ``sensor_node_id``: the sensor board's.
    ``poll_s``: the sleep between drains while waiting [s].
    """

    def __init__(self, bus: can.BusABC, contract: BusContract, axis_nodes: Iterable[int], *,
                 sensor_node_id: int = SENSOR_BOARD_NODE_ID, clock: Clock, sleep: Sleep,
                 poll_s: float = 0.002) -> None:
        self.bus = bus
        self.contract = contract
        self.axis_nodes = tuple(axis_nodes)
        self.sensor_node_id = sensor_node_id
        self.expected = frozenset((*self.axis_nodes, sensor_node_id))
        self.clock = clock
        self.sleep = sleep
        self.poll_s = poll_s
        self._hb = contract.codec("Heartbeat")
        self._enc = contract.codec("Get_Encoder_Estimates")
        self._sb_hb = contract.codec("SB_Heartbeat")
        self._master_cmds = contract.odrive_master_cmds
        self.frames = 0
        self.frames_taken = 0  # standard-id frames taken so far: orders replies after requests
        self.error_frames = 0
        self.extended_frames = 0
        self.first_s: dict[int, float] = {}
        self.last_s: dict[int, float] = {}
        self.node_frames: Counter[int] = Counter()
        self.node_messages: dict[int, Counter[str]] = {}
        self.heartbeats: dict[int, Heartbeat] = {}
        self.encoders: dict[int, EncoderReading] = {}
        self.board: BoardHeartbeat | None = None
        self.last_data: dict[int, tuple[int, bytes]] = {}  # arbitration id -> (receive number, payload)
        self.foreign_commands: Counter[str] = Counter()
        self.undecodable = 0

    # -- receiving -----------------------------------------------------------------------
    def drain(self) -> int:
        """Read every waiting frame; returns how many. Raises :class:`BusError` if the bus fails."""
        n = 0
        recv = self.bus.recv
        while n < _MAX_DRAIN:
            try:
                msg = recv(0)
            except (can.CanError, OSError) as exc:
                raise BusError(f"receive failed: {exc}") from exc
            if msg is None:
                break
            n += 1
            self._take(msg, self.clock())
        self.frames += n
        return n

    def _take(self, msg: can.Message, now_s: float) -> None:
        if msg.is_error_frame:
            self.error_frames += 1
            return
        if msg.is_extended_id:
            self.extended_frames += 1
            return
        self.frames_taken += 1
        node, cmd = split_arbitration_id(msg.arbitration_id)
        self.first_s.setdefault(node, now_s)
        self.last_s[node] = now_s
        self.node_frames[node] += 1
        route = self.contract.route(msg.arbitration_id)
        name = route.codec.name if route is not None else f"cmd {cmd:#04x}"
        self.node_messages.setdefault(node, Counter())[name] += 1
        if route is None:
            return
        codec = route.codec
        if node in self.expected and node != self.sensor_node_id and (
                msg.is_remote_frame or cmd in self._master_cmds or not msg.data):
            # A command, a remote request or a zero-length Get_* request to one of our axes: sent
            # by a master, and we never hear our own frames, so another master is on the bus.
            kind = "RTR " if msg.is_remote_frame else ("request " if not msg.data else "")
            self.foreign_commands[f"{kind}{codec.name} to node {node}"] += 1
            return
        if msg.is_remote_frame:
            return
        data = bytes(msg.data)
        self.last_data[msg.arbitration_id] = (self.frames_taken, data)
        try:
            if codec is self._hb and node != self.sensor_node_id:
                error, state, result, _done = codec.unpack(data)
                self.heartbeats[node] = Heartbeat(now_s, int(error), int(state), int(result))
            elif codec is self._enc and node != self.sensor_node_id:
                pos, vel = codec.unpack(data)
                if math.isfinite(pos) and math.isfinite(vel):
                    self.encoders[node] = EncoderReading(now_s, pos, vel)
            elif codec is self._sb_hb and node == self.sensor_node_id:
                error, state, fw, uptime = codec.unpack(data)
                self.board = BoardHeartbeat(now_s, int(error), int(state), int(fw), float(uptime))
        except ValueError:  # a payload shorter than the DBC's length
            self.undecodable += 1

    # -- waiting -------------------------------------------------------------------------
    def wait(self, done: Callable[[], bool], timeout_s: float) -> bool:
        """Drain and sleep until ``done()`` or ``timeout_s`` has passed; returns ``done()``."""
        t0 = self.clock()
        while True:
            self.drain()
            if done():
                return True
            if self.clock() - t0 >= timeout_s:
                return False
            self.sleep(self.poll_s)

    def pause(self, duration_s: float) -> None:
        """Drain and sleep for ``duration_s`` [s]."""
        self.wait(lambda: False, duration_s)

    # -- sending -------------------------------------------------------------------------
    def send(self, msg: can.Message) -> None:
        try:
            self.bus.send(msg)
        except (can.CanError, OSError) as exc:
            raise BusError(f"send of {msg.arbitration_id:#05x} failed: {exc}") from exc

    def request(self, node_id: int, name: str, *, timeout_s: float = 0.1, attempts: int = 3) -> tuple | None:
        """Send a Get_* request (RTR) and wait for the reply; its values in DBC signal order, or
        None when ``attempts`` requests of ``timeout_s`` each went unanswered."""
        codec = self.contract.codec(name)
        arb = self.contract.odrive_id(node_id, name)
        for _ in range(attempts):
            self.drain()  # whatever is waiting came before the request
            before = self.frames_taken
            self.send(remote_frame(arb, codec.dlc))
            if self.wait(lambda: self.last_data.get(arb, (-1, b""))[0] > before, timeout_s):
                try:
                    return codec.unpack(self.last_data[arb][1])
                except ValueError:
                    self.undecodable += 1
        return None

    # -- what was heard ------------------------------------------------------------------
    def heard(self, node_id: int) -> bool:
        return node_id in self.first_s

    def unknown_nodes(self) -> dict[int, Counter[str]]:
        """Nodes heard that are not configured: node id -> messages (name -> count)."""
        return {n: self.node_messages[n] for n in sorted(self.first_s) if n not in self.expected}
