"""Bring-up: find the nodes, read what they report, check each axis with a small move, leave all IDLE.

:func:`run_bringup` takes a python-can bus, the axes' configurations (node ids, gear ratio,
direction, zero offset, joint limits: :class:`controller.config.AxisConfig`), the sensor board's
node id, and a clock and a sleep (injectable: a test steps a simulated leg inside ``sleep``,
which makes the whole run deterministic). It returns a :class:`BringupReport`: a
:class:`~controller.bringup.checklist.Checklist` (one PASS/WARN/FAIL/SKIP line per item) and the values
read. The steps, in order:

a. **Nodes** (at most ``listen_s``, 1.5 s; at least ``listen_min_s``): a heartbeat from every
   configured axis and from the sensor board; nodes heard that are not configured (WARN, with
   what they sent); commands or requests from another master (FAIL: bring-up then sends no
   command at all); error frames (WARN). A bus on which nothing at all is heard fails at once
   with what was expected on which channel and what to check; nothing else is run.
b. **Per axis** (requests are RTR frames, ``request_attempts`` x ``request_timeout_s``):
   Get_Version (firmware must be 0.6.x: another minor version has another message set, FAIL;
   an unreleased build or a protocol version other than 2, WARN); Get_Error (active errors and
   disarm reason by name: FAIL when latched, unless ``clear_errors``: then Clear_Errors is sent
   and, if Get_Error then reads none, WARN); Get_Bus_Voltage_Current (in ``[bus_voltage_min_v,
   bus_voltage_max_v]``, 12-56 V); the heartbeat's state (IDLE expected). **Sensor board**: its
   SB_Heartbeat (running, no error) and readings heard (SB_Range, SB_Contacts; WARN if not).
c. **Per axis**, the joint angle from Get_Encoder_Estimates through the axis's conversion lies
   in ``[min_rad, max_rad]``. A reading outside that would lie inside with the other
   ``direction`` says so: a wrong direction shows here (the move check cannot see it, see
   :mod:`controller.bringup.move`).
d. **Per axis, one at a time**, only if its items above passed (else SKIP, with the reason) and
   ``move`` is set: :func:`controller.bringup.move.move_axis` (closed loop, move, move back, IDLE).
e. **End**: Set_Axis_State(IDLE) to every configured axis heard that is not IDLE (none if
   another master is on the bus), and the item ``all axes IDLE``.

Any exception on the way (a bus failure, Ctrl-C) still sends IDLE to an axis being moved.

May import: the standard library, python-can, ``protocol``, ``controller``.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from typing import Any, Sequence

import can

from controller.io.axis import AxisConfig, AxisLink
from controller.bringup.bus import BusError, BusWatch, Clock, Sleep
from controller.bringup.move import MoveConfig, error_names, move_axis
from controller.bringup.checklist import Checklist, Status
from protocol import AxisState, BusContract, SENSOR_BOARD_NODE_ID

log = logging.getLogger(__name__)

FIRMWARE_PROTOCOL_VERSION = 2
"""Get_Version.Protocol_Version of ODrive firmware 0.6."""

SENSOR_BOARD_RUNNING = 1
"""SB_Heartbeat.Board_State of a running sensor board."""


@dataclass(frozen=True)
class BringupConfig:
    """How bring-up listens, asks and judges.

    Attributes:
        listen_s: the longest wait for every node's heartbeat [s]; default 1.5.
        listen_min_s: the shortest listen, to hear unknown nodes and other masters [s]; 0.25.
        poll_s: sleep between drains of the bus while waiting [s]; default 0.002.
        request_timeout_s: wait for the reply to one Get_* request [s]; default 0.1.
        request_attempts: requests sent before giving up; default 3.
        firmware: the (major, minor) firmware version the protocol is written for; (0, 6).
        bus_voltage_min_v, bus_voltage_max_v: the plausible DC bus voltage [V]; 12.0, 56.0.
        state_timeout_s: wait for a fresh heartbeat (after Clear_Errors, at the end) [s]; 1.0.
        encoder_max_age_s: a cyclic encoder estimate older than this is asked for again (RTR) [s];
            default 0.1.
        move: the move check (:class:`controller.bringup.move.MoveConfig`).
    """

    listen_s: float = 1.5
    listen_min_s: float = 0.25
    poll_s: float = 0.002
    request_timeout_s: float = 0.1
    request_attempts: int = 3
    firmware: tuple[int, int] = (0, 6)
    bus_voltage_min_v: float = 12.0
    bus_voltage_max_v: float = 56.0
    state_timeout_s: float = 1.0
    encoder_max_age_s: float = 0.1
    move: MoveConfig = field(default_factory=MoveConfig)

    def __post_init__(self) -> None:
        for name, lo, hi in (("listen_s", 0.1, 30.0), ("listen_min_s", 0.0, 30.0), ("poll_s", 0.0001, 0.1),
                             ("request_timeout_s", 0.005, 5.0), ("bus_voltage_min_v", 0.0, 1000.0),
                             ("bus_voltage_max_v", 0.0, 1000.0), ("state_timeout_s", 0.2, 10.0),
                             ("encoder_max_age_s", 0.001, 10.0)):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and lo <= value <= hi):
                raise ValueError(f"BringupConfig.{name} must be in [{lo}, {hi}], got {value!r}")
        if self.listen_min_s > self.listen_s:
            raise ValueError("BringupConfig.listen_min_s must not exceed listen_s")
        if self.bus_voltage_min_v >= self.bus_voltage_max_v:
            raise ValueError("BringupConfig.bus_voltage_min_v must be below bus_voltage_max_v")
        if not (isinstance(self.request_attempts, int) and 1 <= self.request_attempts <= 20):
            raise ValueError(f"BringupConfig.request_attempts must be 1..20, got {self.request_attempts!r}")


@dataclass
class BringupReport:
    """What bring-up found: the checklist and the values read (per axis, per node)."""

    channel: str
    checklist: Checklist
    axes: dict[str, dict[str, Any]]
    sensor_board: dict[str, Any]
    bus: dict[str, Any]
    elapsed_s: float = 0.0

    @property
    def passed(self) -> bool:
        return self.checklist.passed

    def to_dict(self) -> dict[str, Any]:
        return {"channel": self.channel, **self.checklist.to_dict(), "axes": self.axes,
                "sensor_board": self.sensor_board, "bus": self.bus, "elapsed_s": round(self.elapsed_s, 4)}


def _node_list(names: Sequence[tuple[str, int]]) -> str:
    parts = [f"{n} (node {i})" for n, i in names]
    return parts[0] if len(parts) == 1 else ", ".join(parts[:-1]) + " and " + parts[-1]


def _messages(counter) -> str:
    return ", ".join(f"{name} x{n}" for name, n in counter.most_common(4))


class Bringup:
    """One bring-up run (see the module docstring); :meth:`run` returns the report."""

    def __init__(self, bus: can.BusABC, axes: Sequence[AxisConfig], *, sensor_node_id: int = SENSOR_BOARD_NODE_ID,
                 channel: str = "the bus", config: BringupConfig = BringupConfig(), move: bool = True,
                 clear_errors: bool = False, clock: Clock = time.monotonic, sleep: Sleep = time.sleep,
                 contract: BusContract | None = None) -> None:
        if not axes:
            raise ValueError("bring-up needs at least one axis")
        ids = [a.node_id for a in axes] + [sensor_node_id]
        if len(set(ids)) != len(ids):
            raise ValueError(f"node ids must differ (axes and sensor board), got {ids}")
        contract = contract if contract is not None else BusContract.load()
        self.axes = tuple(axes)
        self.links = {a.name: AxisLink(a, contract) for a in self.axes}
        self.sensor_node_id = sensor_node_id
        self.channel = channel
        self.cfg = config
        self.do_move = move
        self.clear_errors = clear_errors
        self.clock = clock
        self.w = BusWatch(bus, contract, [a.node_id for a in self.axes], sensor_node_id=sensor_node_id,
                          clock=clock, sleep=sleep, poll_s=config.poll_s)
        self.list = Checklist()
        self.info: dict[str, dict[str, Any]] = {a.name: {"node_id": a.node_id} for a in self.axes}
        self.board_info: dict[str, Any] = {"node_id": sensor_node_id}
        self.blocked: dict[str, list[str]] = {a.name: [] for a in self.axes}  # failed items that forbid a move
        self.other_master = False

    def _add(self, axis: str | None, name: str, status: Status, detail: str) -> None:
        self.list.add(name, status, detail)
        if axis is not None and status is Status.FAIL:
            self.blocked[axis].append(name.split(": ", 1)[-1])

    # -- a. nodes ------------------------------------------------------------------------
    def listen(self) -> bool:
        """Listen for heartbeats; False when nothing at all was heard (then nothing else runs)."""
        w, cfg = self.w, self.cfg
        t0 = self.clock()
        axis_nodes = [a.node_id for a in self.axes]

        def everyone() -> bool:
            return (self.clock() - t0 >= cfg.listen_min_s and all(n in w.heartbeats for n in axis_nodes)
                    and w.board is not None)

        w.wait(everyone, cfg.listen_s)
        listened = self.clock() - t0
        expected = _node_list([(a.name, a.node_id) for a in self.axes] + [("the sensor board", self.sensor_node_id)])
        if not w.first_s:
            what = (f"only {w.error_frames} error frames" if w.error_frames else "no frame at all")
            self._add(None, "bus: nodes heard", Status.FAIL,
                      f"{what} on {self.channel} in {listened:.1f} s; expected heartbeats from {expected}. Check the "
                      f"wiring (CAN_H, CAN_L, ground), the 120 ohm termination at both ends, the bitrate (every node "
                      f"and {self.channel} at the same rate), that the nodes are powered, and that {self.channel} is "
                      f"up (ip -details link show {self.channel})")
            return False
        unknown = w.unknown_nodes()
        hint = ("; heard unconfigured node(s) " + ", ".join(str(n) for n in unknown) + ": is node_id right?"
                if unknown else "")
        for a in self.axes:
            name = f"{a.name} (node {a.node_id}): heartbeat"
            if a.node_id in w.heartbeats:
                self._add(a.name, name, Status.PASS, f"heard {w.first_s[a.node_id] - t0:.2f} s after start, "
                                                     f"{w.node_frames[a.node_id]} frames")
            elif w.heard(a.node_id):
                self._add(a.name, name, Status.FAIL, f"frames ({_messages(w.node_messages[a.node_id])}) but no "
                                                     f"heartbeat in {listened:.1f} s: heartbeat message rate 0?")
            else:
                self._add(a.name, name, Status.FAIL, f"nothing from node {a.node_id} in {listened:.1f} s: check its "
                                                     f"node id, power and CAN wiring{hint}")
        board = f"sensor board (node {self.sensor_node_id}): heartbeat"
        if w.board is not None:
            self._add(None, board, Status.PASS, f"heard {w.first_s[self.sensor_node_id] - t0:.2f} s after start, "
                                                f"{w.node_frames[self.sensor_node_id]} frames")
        else:
            extra = (f"frames ({_messages(w.node_messages[self.sensor_node_id])}) but no SB_Heartbeat"
                     if w.heard(self.sensor_node_id) else f"nothing from node {self.sensor_node_id}")
            self._add(None, board, Status.FAIL, f"{extra} in {listened:.1f} s: check its power and wiring{hint}")
        if unknown:
            self._add(None, "bus: unknown nodes", Status.WARN, "; ".join(
                f"node {n}: {_messages(m)}" for n, m in unknown.items()) + " (not in the configuration)")
        else:
            self._add(None, "bus: unknown nodes", Status.PASS, "none")
        if w.foreign_commands:
            self.other_master = True
            self._add(None, "bus: no other master", Status.FAIL,
                      f"{_messages(w.foreign_commands)}: another master is commanding the axes; stop it (a "
                      f"controller daemon?) and run bring-up again. No command is sent meanwhile")
        else:
            self._add(None, "bus: no other master", Status.PASS, f"no command from another master in {listened:.2f} s")
        errors = "" if not w.error_frames else f", {w.error_frames} error frames (bitrate, termination?)"
        self._add(None, "bus: traffic", Status.WARN if w.error_frames else Status.PASS,
                  f"{w.frames} frames in {listened:.2f} s{errors}")
        return True

    # -- b. per-axis state ---------------------------------------------------------------
    def _request(self, a: AxisConfig, name: str) -> tuple | None:
        return self.w.request(a.node_id, name, timeout_s=self.cfg.request_timeout_s, attempts=self.cfg.request_attempts)

    def _no_reply(self, name: str) -> str:
        return (f"no reply to {name} (RTR) in {self.cfg.request_attempts} x {self.cfg.request_timeout_s:g} s: "
                "does the firmware answer remote requests?")

    def check_version(self, a: AxisConfig) -> None:
        item = f"{a.name}: firmware"
        v = self._request(a, "Get_Version")
        if v is None:
            self._add(a.name, item, Status.FAIL, self._no_reply("Get_Version"))
            return
        proto, hw_major, hw_minor, hw_variant, fw_major, fw_minor, fw_rev, unreleased = (int(x) for x in v)
        self.info[a.name].update(protocol_version=proto, hw_version=f"{hw_major}.{hw_minor}-{hw_variant}",
                                 fw_version=f"{fw_major}.{fw_minor}.{fw_rev}", fw_unreleased=bool(unreleased))
        detail = (f"firmware {fw_major}.{fw_minor}.{fw_rev}{' (unreleased)' if unreleased else ''}, hardware "
                  f"{hw_major}.{hw_minor}-{hw_variant}, protocol {proto}")
        want = ".".join(str(x) for x in self.cfg.firmware)
        if (fw_major, fw_minor) != tuple(self.cfg.firmware):
            self._add(a.name, item, Status.FAIL, f"{detail}: the bus contract is firmware {want}.x's message set; "
                                                 f"flash {want}.x")
        elif unreleased or proto != FIRMWARE_PROTOCOL_VERSION:
            self._add(a.name, item, Status.WARN, f"{detail}: expected a released {want}.x with protocol "
                                                 f"{FIRMWARE_PROTOCOL_VERSION}")
        else:
            self._add(a.name, item, Status.PASS, detail)

    def check_errors(self, a: AxisConfig) -> None:
        item = f"{a.name}: errors"
        v = self._request(a, "Get_Error")
        if v is None:
            self._add(a.name, item, Status.FAIL, self._no_reply("Get_Error"))
            return
        active, reason = int(v[0]), int(v[1])
        self.info[a.name].update(active_errors=active, disarm_reason=reason)
        found = f"active errors {error_names(active)}, disarm reason {error_names(reason)}"
        if not active and not reason:
            self._add(a.name, item, Status.PASS, "no active error, no disarm reason")
            return
        if not self.clear_errors or self.other_master:
            self._add(a.name, item, Status.FAIL, f"latched: {found}. Find the cause, then run bring-up with "
                                                 f"--clear-errors to clear them (Clear_Errors)")
            return
        self.w.drain()
        t_clear = self.clock()
        self.w.send(self.links[a.name].clear_errors_frame())
        v = self._request(a, "Get_Error")
        # a heartbeat sent after the clear, so the state check reads the cleared state
        self.w.wait(lambda: self.w.heartbeats.get(a.node_id) is not None
                    and self.w.heartbeats[a.node_id].t_s > t_clear, self.cfg.state_timeout_s)
        if v is None:
            self._add(a.name, item, Status.FAIL, f"was {found}; Clear_Errors sent, then {self._no_reply('Get_Error')}")
        elif int(v[0]) or int(v[1]):
            self._add(a.name, item, Status.FAIL, f"was {found}; still active errors {error_names(int(v[0]))}, "
                                                 f"disarm reason {error_names(int(v[1]))} after Clear_Errors")
        else:
            self.info[a.name]["cleared"] = True
            self._add(a.name, item, Status.WARN, f"was {found}; cleared (--clear-errors)")

    def check_voltage(self, a: AxisConfig) -> None:
        item = f"{a.name}: bus voltage"
        v = self._request(a, "Get_Bus_Voltage_Current")
        if v is None:
            self._add(a.name, item, Status.FAIL, self._no_reply("Get_Bus_Voltage_Current"))
            return
        volts, amps = float(v[0]), float(v[1])
        self.info[a.name].update(bus_voltage_v=round(volts, 3), bus_current_a=round(amps, 3))
        lo, hi = self.cfg.bus_voltage_min_v, self.cfg.bus_voltage_max_v
        detail = f"{volts:.1f} V, {amps:.2f} A"
        if lo <= volts <= hi:
            self._add(a.name, item, Status.PASS, f"{detail} (plausible: {lo:g}-{hi:g} V)")
        else:
            why = "supply off, too low or a blown fuse?" if not volts >= lo else "supply too high?"
            self._add(a.name, item, Status.FAIL, f"{detail}, outside {lo:g}-{hi:g} V: {why}")

    def check_state(self, a: AxisConfig) -> None:
        item = f"{a.name}: state"
        hb = self.w.heartbeats.get(a.node_id)
        if hb is None:
            self._add(a.name, item, Status.FAIL, "no heartbeat")
            return
        self.info[a.name].update(state=hb.state_name, heartbeat_error=hb.error, procedure_result=hb.procedure_result)
        detail = f"heartbeat {hb.state_name}, errors {error_names(hb.error)}, procedure result {hb.procedure_result}"
        if hb.state == AxisState.IDLE:
            self._add(a.name, item, Status.PASS, detail)
        elif hb.state == AxisState.CLOSED_LOOP_CONTROL:
            self._add(a.name, item, Status.FAIL, f"{detail}: already armed before bring-up (another controller?)")
        else:
            self._add(a.name, item, Status.FAIL, f"{detail}: IDLE expected (a calibration running?)")

    def check_board(self) -> None:
        b = self.w.board
        if b is None:
            return
        msgs = self.w.node_messages.get(self.sensor_node_id, {})
        self.board_info.update(state=b.state, error=b.error, fw_version=b.fw_version, uptime_s=b.uptime_s,
                               frames={k: v for k, v in msgs.items()})
        detail = f"state {b.state}, error {b.error:#x}, firmware {b.fw_version}, uptime {b.uptime_s:.1f} s"
        ok = b.state == SENSOR_BOARD_RUNNING and not b.error
        self._add(None, "sensor board: state", Status.PASS if ok else Status.FAIL,
                  detail if ok else f"{detail}: running (state {SENSOR_BOARD_RUNNING}) with no error expected")
        missing = [m for m in ("SB_Range", "SB_Contacts") if not msgs.get(m)]
        seen = ", ".join(f"{m} x{msgs.get(m, 0)}" for m in ("SB_Range", "SB_Profile", "SB_Contacts"))
        self._add(None, "sensor board: readings", Status.WARN if missing else Status.PASS,
                  f"{seen}" + (f": no {' or '.join(missing)} heard (sensor unplugged?)" if missing else ""))

    # -- c. position ---------------------------------------------------------------------
    def check_position(self, a: AxisConfig) -> None:
        item = f"{a.name}: position"
        w = self.w
        e = w.encoders.get(a.node_id)
        if e is None or self.clock() - e.t_s > self.cfg.encoder_max_age_s:
            v = self._request(a, "Get_Encoder_Estimates")
            e = w.encoders.get(a.node_id)
            if v is None or e is None:
                self._add(a.name, item, Status.FAIL, self._no_reply("Get_Encoder_Estimates"))
                return
        q = a.rev_to_rad(e.pos_rev)
        self.info[a.name].update(pos_rev=round(e.pos_rev, 6), pos_rad=round(q, 5))
        limits = f"[{a.min_rad:g}, {a.max_rad:g}] rad"
        detail = f"{q:+.3f} rad ({e.pos_rev:+.4f} rev at the motor)"
        if a.min_rad <= q <= a.max_rad:
            self._add(a.name, item, Status.PASS, f"{detail}, inside {limits}")
        elif a.min_rad <= -q <= a.max_rad:
            self._add(a.name, item, Status.FAIL, f"{detail}, outside {limits}; with direction {-a.direction:+d} it "
                                                 f"would read {-q:+.3f} rad, inside: is direction {a.direction:+d} "
                                                 "wrong?")
        else:
            self._add(a.name, item, Status.FAIL, f"{detail}, outside {limits}: check zero_offset_rev, gear_ratio and "
                                                 "direction, or bring the joint into its range by hand")

    # -- d. moves ------------------------------------------------------------------------
    def move(self, a: AxisConfig) -> None:
        why = None
        if self.other_master:
            why = "another master is on the bus"
        elif not self.do_move:
            why = "--no-move"
        elif self.blocked[a.name]:
            why = f"{', '.join(self.blocked[a.name])} failed"
        if why is not None:
            for suffix in ("closed loop", "move", "move back"):
                self.list.add(f"{a.name}: {suffix}", Status.SKIP, f"not moved: {why}")
            return
        self.info[a.name]["move"] = move_axis(self.w, self.links[a.name], self.cfg.move, self.list)

    # -- e. end --------------------------------------------------------------------------
    def end(self) -> None:
        w = self.w
        heard = [a for a in self.axes if a.node_id in w.heartbeats]
        if not heard:
            return
        if not self.other_master:
            for a in heard:
                if w.heartbeats[a.node_id].state != AxisState.IDLE:
                    w.send(self.links[a.name].state_frame(AxisState.IDLE))
        t0 = self.clock()

        def all_idle() -> bool:
            return all(w.heartbeats[a.node_id].state == AxisState.IDLE for a in heard)

        w.wait(all_idle, self.cfg.state_timeout_s if not all_idle() else 0.0)
        states = {a.name: w.heartbeats[a.node_id].state_name for a in heard}
        for a in heard:
            self.info[a.name]["state_at_end"] = states[a.name]
        detail = ", ".join(f"{n} {s}" for n, s in states.items())
        missing = [a.name for a in self.axes if a not in heard]
        if missing:
            detail += f"; not heard: {', '.join(missing)}"
        if all_idle():
            self.list.add("all axes IDLE", Status.PASS, detail)
        else:
            self.list.add("all axes IDLE", Status.FAIL,
                          f"{detail} {self.clock() - t0:.1f} s after Set_Axis_State(IDLE)")

    # -- the run -------------------------------------------------------------------------
    def run(self) -> BringupReport:
        t0 = self.clock()
        try:
            if self.listen():
                heard = [a for a in self.axes if a.node_id in self.w.heartbeats]
                for a in heard:
                    self.check_version(a)
                    self.check_errors(a)
                    self.check_voltage(a)
                    self.check_state(a)
                self.check_board()
                for a in heard:
                    self.check_position(a)
                for a in heard:
                    self.move(a)
                self.end()
        except BusError as exc:
            self.list.add("bus", Status.FAIL, f"the bus failed during bring-up: {exc}")
        elapsed = self.clock() - t0
        summary = self.list.summary()
        log.info("bring-up on %s: %s in %.2f s", self.channel, summary, elapsed)
        w = self.w
        bus = {"frames": w.frames, "error_frames": w.error_frames, "extended_frames": w.extended_frames,
               "nodes_heard": sorted(w.first_s),
               "unknown_nodes": {str(n): dict(m) for n, m in w.unknown_nodes().items()},
               "foreign_commands": dict(w.foreign_commands)}
        return BringupReport(self.channel, self.list, self.info, self.board_info, bus, elapsed)


def run_bringup(bus: can.BusABC, axes: Sequence[AxisConfig], **kwargs: Any) -> BringupReport:
    """Run bring-up on ``bus`` for ``axes``; keyword arguments as :class:`Bringup`'s."""
    return Bringup(bus, axes, **kwargs).run()
