"""The controller's side of the bus: receive, validate, dispatch; send and count.

Every received frame is looked up by arbitration id in a table built once from the DBC and the
configured nodes. A frame is dropped and counted when its id is not one we listen to
(``unknown``), it is a remote request or an extended/error frame (``unknown``), its DLC is
short (``malformed``), or its values fail validation (``invalid``: NaN, out-of-range enums or
profile distances, stale sequence numbers). Nothing a frame contains can raise out of :meth:`BusIO.drain`.
"""

from __future__ import annotations

import logging
from collections import Counter
from typing import Callable

import can

from controller.axis import AxisLink
from controller.sensors import SensorLink
from protocol import BusContract, arbitration_id

log = logging.getLogger(__name__)

Handler = Callable[[tuple, float], bool]


class BusIO:
    def __init__(self, bus: can.BusABC, contract: BusContract, axes: list[AxisLink], sensors: SensorLink) -> None:
        self.bus = bus
        self.rx: Counter[str] = Counter()
        self.tx: Counter[str] = Counter()
        self.dropped: Counter[str] = Counter()
        self._names = {}
        self._table: dict[int, tuple[Handler, Callable, int, str]] = {}
        for axis in axes:
            self._listen(axis.heartbeat_id, contract.codec("Heartbeat"), axis.on_heartbeat)
            self._listen(axis.encoder_id, contract.codec("Get_Encoder_Estimates"), axis.on_encoder)
            for name in ("Set_Input_Pos", "Set_Axis_State", "Set_Controller_Mode", "Clear_Errors", "Estop"):
                self._names[contract.odrive_id(axis.config.node_id, name)] = name
        sb = sensors.node_id
        for name, handler in (("SB_Range", sensors.on_range), ("SB_Profile", sensors.on_profile),
                              ("SB_Contacts", sensors.on_contacts), ("SB_Heartbeat", sensors.on_heartbeat)):
            codec = contract.codec(name)
            self._listen(arbitration_id(sb, codec.cmd_id), codec, handler)

    def _listen(self, arb_id: int, codec, handler: Handler) -> None:
        self._table[arb_id] = (handler, codec.unpack, codec.dlc, codec.name)

    def drain(self, now_s: float) -> int:
        """Read every frame waiting on the bus; returns how many were accepted."""
        accepted = 0
        recv = self.bus.recv
        table = self._table
        while True:
            try:
                msg = recv(timeout=0.0)
            except can.CanError as exc:
                self.dropped["bus_error"] += 1
                log.warning("bus receive error: %s", exc)
                break
            if msg is None:
                break
            entry = table.get(msg.arbitration_id)
            if entry is None or msg.is_remote_frame or msg.is_extended_id or msg.is_error_frame:
                self.dropped["unknown"] += 1
                continue
            handler, unpack, dlc, name = entry
            if msg.dlc < dlc or len(msg.data) < dlc:
                self.dropped["malformed"] += 1
                continue
            try:
                ok = handler(unpack(msg.data), now_s)
            except (ValueError, TypeError, OverflowError):
                ok = False
            if ok:
                self.rx[name] += 1
                accepted += 1
            else:
                self.dropped["invalid"] += 1
        return accepted

    def send(self, msg: can.Message) -> bool:
        name = self._names.get(msg.arbitration_id, "other")
        try:
            self.bus.send(msg)
        except can.CanError as exc:
            self.dropped["tx_error"] += 1
            log.warning("bus send error on %s: %s", name, exc)
            return False
        self.tx[name] += 1
        return True
