"""The controller's side of the bus: receive, validate, dispatch; send, guard and count.

**Receiving.** Every received frame is looked up by arbitration id in a table built once from
the DBC and the configured nodes, and is either accepted (``rx[message name]``) or dropped and
counted under exactly one reason in ``dropped``:

- ``unknown``: an id we do not listen to (another node's traffic), or one of ours as a remote
  request, an extended-id or a CAN FD frame;
- ``malformed``: a data frame with one of our ids whose DLC (or payload length) is not exactly
  the DBC's length for that message;
- ``unexpected_sender``: a data frame with an id that only a master sends (the DBC's
  ``Controller`` messages: Set_Input_Pos, Set_Axis_State, Estop, ... to one of our nodes). We
  never hear our own frames, so another master is on the bus: logged once, with a warning, and
  counted per arbitration id in ``foreign`` (the loop makes it a latched FAULT,
  :meth:`controller.loop.ControlLoop.tick`);
- ``invalid``: the handler (:class:`~controller.io.axis.AxisLink`,
  :class:`~controller.io.sensors.SensorLink`) refused the values: NaN or infinite, out of range
  (an encoder reading faster or further than :class:`~controller.io.axis.FeedbackLimits` allow,
  a heartbeat state that is not an ODrive axis state, a range beyond the sensor's reach or a
  profile beam beyond the beams', a Range_Valid or contact bit other than 0/1), or a stale or
  duplicate sequence number;
- ``handler_error``: a handler raised something other than ValueError/TypeError/OverflowError
  (a bug: logged with its traceback, a few times);
- ``error_frames``: an error frame (SocketCAN delivers them with ``is_error_frame`` and the
  error class bits in the arbitration id) other than bus-off; ``bus_off``: a bus-off error
  frame (class ``CAN_ERR_BUSOFF``, 0x40).

``received`` counts the frames read, so ``received == sum(rx.values()) + sum(dropped[r] for r
in RX_DROP_REASONS)``. Nothing a frame contains can raise out of :meth:`BusIO.drain`. At most
``warn_limit`` warnings are logged per reason (``unknown`` only at debug level): no log flood
at 500 Hz; the counters keep the full story.

**Sending.** :meth:`BusIO.send` hands a frame to the bus and counts it in ``tx``, or drops it
and counts ``dropped["tx_error"]`` (the bus raised), ``dropped["tx_while_down"]`` (the bus is
closed, see below) or ``dropped["refused_outside_limits"]``: a Set_Input_Pos for one of our
axes whose position is not a finite value inside the axis's ``pos_bounds_rev`` (or whose
length is not the DBC's) is never put on the bus, whoever built it. Frames from
:meth:`AxisLink.pos_frame` always pass; the check costs about 0.13 us a frame (a dict
lookup every send does anyway, a float32 read and two comparisons).

**Bus errors and bus-off.** With a ``reopen`` factory (a callable that opens a fresh bus), a
``can.CanError`` (or ``OSError``) from ``recv`` or ``send``, or a bus-off error frame, takes the
bus down: the old bus is shut down and reopened with exponential backoff (``ReopenPolicy``:
first after 0.05 s, doubling to at most 2 s; the backoff starts again from 0.05 s once a bus has
stayed up for 1 s). Attempts are paced by the ``now_s`` given to :meth:`drain` (each tick) and
:meth:`send` (if given), never by sleeping in the control loop. While the bus is down,
:meth:`drain` returns 0 and every send is dropped (``tx_while_down``). ``bus_events`` counts
``bus_down``, ``bus_reopens`` and ``bus_reopen_failures``; each transition is logged once (down,
with its cause; the first failed attempt of an outage; reopened, with the outage's length).
Without a factory nothing is reopened: a receive error is counted (``bus_error``) and ends that
drain, a send error is counted (``tx_error``), and the same bus is used again next time.

Meanwhile the rest of the safety chain acts on its own: the drivers hear no command, so their
watchdogs (100 ms) disarm the axes (IDLE, WATCHDOG_TIMER_EXPIRED, latched until Clear_Errors);
the controller hears no node, so the supervisor's silence timeout puts it in FAULT (latched),
which sends every axis IDLE once the bus is back and never another position target. An outage
shorter than both (one reopening after 0.05 s) is ridden through without a stop. Reopening a
socket does not restart a CAN controller that went bus-off: on real hardware give the interface
``restart-ms`` (``ip link set can0 type can restart-ms 100``) so the kernel restarts it.
"""

from __future__ import annotations

import logging
import math
import struct
from collections import Counter
from dataclasses import dataclass
from typing import Any, Callable, Final

import can

from controller.io.axis import AxisLink
from controller.io.sensors import SensorLink
from protocol import BusContract, arbitration_id
from protocol.compiled import interpreted

log = logging.getLogger(__name__)

Handler = Callable[[tuple, float], bool]

CAN_ERR_BUSOFF: Final = 0x40
"""SocketCAN error class ``CAN_ERR_BUSOFF`` (linux/can/error.h), in an error frame's id."""

RX_DROP_REASONS = ("unknown", "malformed", "unexpected_sender", "invalid", "handler_error", "error_frames",
                   "bus_off")
"""``dropped`` reasons of received frames: each frame read is accepted or counted under one."""

TX_DROP_REASONS = ("tx_error", "tx_while_down", "refused_outside_limits")
"""``dropped`` reasons of frames handed to :meth:`BusIO.send` and not sent."""


@interpreted  # a Counter subclass: plain Python even when compiled (protocol.compiled)
class Tally(Counter):
    """The counters of :class:`BusIO` (``rx``, ``tx``, ``dropped``, ...): a ``collections.Counter``
    whose ``del`` is dict's own. Counter defines ``__delitem__`` in Python, and since deletion and
    assignment share one C slot, every ``c[k] += 1`` then takes Python-level dispatch (about 3x a
    dict's; twice a frame on the hot path). The one difference: deleting a key that is not there
    raises KeyError, as a dict does (nothing deletes from these)."""

    __delitem__ = dict.__delitem__



@interpreted  # a configuration: plain Python even when compiled (protocol.compiled)
@dataclass(frozen=True)
class ReopenPolicy:
    """How a failed bus is reopened (only with a ``reopen`` factory).

    Attributes:
        first_delay_s: wait before the first attempt after the bus went down [s]; default 0.05.
        max_delay_s: the longest wait between attempts [s]; default 2.0.
        factor: each failed attempt (or an outage right after a reopen) multiplies the wait by
            this; default 2.0.
        stable_s: a bus that stayed up this long starts the next outage at ``first_delay_s``
            again [s]; default 1.0 (a bus that fails again at once keeps backing off).
    """

    first_delay_s: float = 0.05
    max_delay_s: float = 2.0
    factor: float = 2.0
    stable_s: float = 1.0

    def __post_init__(self) -> None:
        for name in ("first_delay_s", "max_delay_s", "stable_s"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0.0):
                raise ValueError(f"ReopenPolicy.{name} must be finite and >= 0 s, got {value!r}")
        if self.max_delay_s < self.first_delay_s:
            raise ValueError("ReopenPolicy.max_delay_s must not be below first_delay_s")
        if not (math.isfinite(self.factor) and self.factor >= 1.0):
            raise ValueError(f"ReopenPolicy.factor must be finite and >= 1, got {self.factor!r}")


class BusIO:
    """Receive, validate and dispatch frames; send, guard and count them (see the module doc).

    ``reopen``: a factory that opens a fresh bus (None: never reopen); it may be set after
    construction (``io.reopen = factory``). ``bus_up``: False while the bus is down.
    """

    def __init__(self, bus: can.BusABC, contract: BusContract, axes: list[AxisLink], sensors: SensorLink, *,
                 reopen: Callable[[], can.BusABC] | None = None, policy: ReopenPolicy = ReopenPolicy(),
                 warn_limit: int = 3) -> None:
        self.bus = bus
        self.reopen = reopen
        self.policy = policy
        self.warn_limit = warn_limit
        self.rx: Counter[str] = Tally()
        self.tx: Counter[str] = Tally()
        self.dropped: Counter[str] = Tally()
        self.bus_events: Counter[str] = Tally()
        self.received = 0
        self.foreign: Counter[int] = Tally()  # frames from another master, by arbitration id
        self.bus_up = True
        self._warnings: Counter[str] = Tally()
        self._now_s = -math.inf
        self._delay_s = policy.first_delay_s
        self._retry_at_s = -math.inf
        self._down_since_s = -math.inf
        self._up_since_s = -math.inf
        self._attempts = 0
        self._table: dict[int, tuple[Handler, Callable, int, str]] = {}
        # Ids only a master sends, to our nodes: (name, lowest, highest Input_Pos [rev]); the
        # bounds only for Set_Input_Pos (None otherwise).
        self._tx_table: dict[int, tuple[str, float | None, float | None]] = {}
        for axis in axes:
            self.listen(axis.heartbeat_id, contract.codec("Heartbeat"), axis.on_heartbeat)
            self.listen(axis.encoder_id, contract.codec("Get_Encoder_Estimates"), axis.on_encoder)
            voltage = contract.codec("Get_Bus_Voltage_Current")
            self.listen(arbitration_id(axis.config.node_id, voltage.cmd_id), voltage, axis.on_bus_voltage)
            for name, handler in (("Get_Temperature", axis.on_temperature), ("Get_Iq", axis.on_iq)):  # health
                codec = contract.codec(name)
                self.listen(arbitration_id(axis.config.node_id, codec.cmd_id), codec, handler)
            for codec in contract.odrive.values():
                if codec.name in contract.master_messages:
                    self._tx_table[arbitration_id(axis.config.node_id, codec.cmd_id)] = (codec.name, None, None)
            lo, hi = axis.pos_bounds_rev
            self._tx_table[axis.pos_id] = ("Set_Input_Pos", lo, hi)
        sb = sensors.node_id
        for name, handler in (("SB_Range", sensors.on_range), ("SB_Profile", sensors.on_profile),
                              ("SB_Contacts", sensors.on_contacts), ("SB_Heartbeat", sensors.on_heartbeat)):
            codec = contract.codec(name)
            self.listen(arbitration_id(sb, codec.cmd_id), codec, handler)
        for codec in contract.sensor_board.values():
            if codec.name in contract.master_messages:
                self._tx_table[arbitration_id(sb, codec.cmd_id)] = (codec.name, None, None)
        self._pos_len, self._unpack_pos = self._input_pos_reader(contract)

    def listen(self, arb_id: int, codec, handler: Handler) -> None:
        """Hand every valid frame with ``arb_id`` (decoded by ``codec``) to ``handler``."""
        self._table[arb_id] = (handler, codec.exact_reader(), codec.dlc, codec.name)

    @staticmethod
    def _input_pos_reader(contract: BusContract) -> tuple[int, Callable[[bytes | bytearray], tuple]]:
        """(DBC length, reader of ``(Input_Pos [rev],)``) for Set_Input_Pos: a bare float32 read
        where the DBC puts Input_Pos at bit 0, little-endian, unscaled; the codec otherwise."""
        codec = contract.codec("Set_Input_Pos")
        sig = next(s for s in codec.message.signals if s.name == "Input_Pos")
        if (sig.is_float and sig.length == 32 and sig.start == 0 and sig.byte_order == "little_endian"
                and sig.scale == 1 and sig.offset == 0):
            return codec.dlc, struct.Struct("<f").unpack_from
        index = codec.signal_names.index("Input_Pos")
        return codec.dlc, lambda data: (codec.unpack(data)[index],)

    # ------------------------------------------------------------------ logging
    def _warn(self, reason: str, fmt: str, *args, limit: int | None = None, exc_info: bool = False) -> None:
        """A warning for ``reason``, at most ``limit`` (default ``warn_limit``) times."""
        n = self._warnings[reason] + 1
        self._warnings[reason] = n
        limit = self.warn_limit if limit is None else limit
        if n <= limit:
            if n == limit:
                fmt += " (no more %s warnings: see BusIO.dropped)"
                args = (*args, reason)
            log.warning(fmt, *args, exc_info=exc_info)

    # ------------------------------------------------------------------ bus up / down
    def _go_down(self, now_s: float, cause: str) -> None:
        """Shut the failed bus down and schedule the first reopening attempt."""
        if not self.bus_up:
            return
        p = self.policy
        self.bus_up = False
        self.bus_events["bus_down"] += 1
        if now_s - self._up_since_s >= p.stable_s:
            self._delay_s = p.first_delay_s
        else:  # it failed again soon after a reopen: keep backing off
            self._delay_s = min(p.max_delay_s, self._delay_s * p.factor)
        self._retry_at_s = now_s + self._delay_s
        self._down_since_s = now_s
        self._attempts = 0
        log.warning("CAN bus down at t=%.3f s (%s): closing it, reopening in %.3f s (backoff up to %.1f s); "
                    "frames to send are dropped meanwhile", now_s, cause, self._delay_s, p.max_delay_s)
        try:
            self.bus.shutdown()
        except Exception as exc:  # noqa: BLE001 - a broken bus may fail to close too
            log.debug("closing the failed bus raised %r", exc)

    def _try_reopen(self, now_s: float) -> bool:
        """One reopening attempt (when due); True if the bus is up again."""
        if now_s < self._retry_at_s or self.reopen is None:
            return False
        self._attempts += 1
        try:
            bus = self.reopen()
            if bus is None:
                raise can.CanInitializationError("the reopen factory returned None")
        except Exception as exc:  # noqa: BLE001 - whatever opening a bus raises, try again later
            p = self.policy
            self.bus_events["bus_reopen_failures"] += 1
            self._delay_s = min(p.max_delay_s, self._delay_s * p.factor)
            self._retry_at_s = now_s + self._delay_s
            if self._attempts == 1:
                log.warning("reopening the CAN bus failed at t=%.3f s (%s); retrying, backing off to %.1f s",
                            now_s, exc, p.max_delay_s)
            return False
        self.bus = bus
        self.bus_up = True
        self._up_since_s = now_s
        self.bus_events["bus_reopens"] += 1
        log.warning("CAN bus reopened at t=%.3f s after %.3f s down (%d attempt(s))", now_s,
                    now_s - self._down_since_s, self._attempts)
        return True

    # ------------------------------------------------------------------ receive
    def drain(self, now_s: float) -> int:
        """Read every frame waiting on the bus; returns how many were accepted."""
        self._now_s = now_s
        if not self.bus_up and not self._try_reopen(now_s):
            return 0
        accepted = 0
        n = 0
        recv = self.bus.recv
        table = self._table
        rx = self.rx
        dropped = self.dropped
        msg: Any  # read without mypyc's type checks: the controller must survive any frame (a numpy.bool flag too)
        while True:
            try:
                msg = recv(timeout=0.0)
            except (can.CanError, OSError) as exc:
                dropped["bus_error"] += 1
                if self.reopen is not None:
                    self._go_down(now_s, f"receive error: {exc}")
                else:
                    self._warn("bus_error", "bus receive error: %s", exc)
                break
            if msg is None:
                break
            n += 1
            arb = msg.arbitration_id
            if msg.is_error_frame:
                if arb & CAN_ERR_BUSOFF:
                    dropped["bus_off"] += 1
                    if self.reopen is not None:
                        self._go_down(now_s, f"bus-off error frame, class {arb:#x}")
                        break
                    self._warn("bus_off", "bus-off error frame (class %#x)", arb)
                else:
                    dropped["error_frames"] += 1
                    self._warn("error_frames", "error frame (class %#x) dropped", arb)
                continue
            entry = table.get(arb)
            if entry is None:
                own = self._tx_table.get(arb)
                if own is not None and not (msg.is_remote_frame or msg.is_extended_id):
                    dropped["unexpected_sender"] += 1
                    self.foreign[arb] += 1
                    self._warn("unexpected_sender", "frame %#x (%s) on the bus is one only a master sends to our "
                               "node: another master is on the bus", arb, own[0], limit=1)
                else:
                    dropped["unknown"] += 1
                    if self._warnings["unknown"] < self.warn_limit:
                        self._warnings["unknown"] += 1
                        log.debug("frame %#x not ours, dropped", arb)
                continue
            if msg.is_remote_frame or msg.is_extended_id or msg.is_fd:
                dropped["unknown"] += 1
                continue
            handler, unpack, dlc, name = entry
            data = msg.data
            if msg.dlc != dlc or len(data) != dlc:
                dropped["malformed"] += 1
                self._warn("malformed", "%s frame with DLC %d (%d bytes), %d expected: dropped", name, msg.dlc,
                           len(data), dlc)
                continue
            try:
                ok = handler(unpack(data), now_s)
            except (ValueError, TypeError, OverflowError):
                ok = False
            except Exception:  # noqa: BLE001 - nothing a frame contains may stop the loop
                dropped["handler_error"] += 1
                self._warn("handler_error", "handler of %s raised on %s", name, bytes(data).hex(), exc_info=True)
                continue
            if ok:
                rx[name] += 1
                accepted += 1
            else:
                dropped["invalid"] += 1
                self._warn("invalid", "invalid %s frame dropped: %s", name, bytes(data).hex())
        self.received += n
        return accepted

    # ------------------------------------------------------------------ send
    def send(self, msg: can.Message, now_s: float | None = None) -> bool:
        """Send one frame; False (and counted in ``dropped``) if it was not put on the bus.

        ``now_s``: the current time [s], to pace reopening attempts (default: the time of the
        last :meth:`drain`)."""
        entry = self._tx_table.get(msg.arbitration_id)
        if entry is None:
            name = "other"
        else:
            name, lo, hi = entry
            if lo is not None:
                data = msg.data
                if len(data) != self._pos_len or not lo <= self._unpack_pos(data)[0] <= hi:  # False for NaN too
                    self.dropped["refused_outside_limits"] += 1
                    self._warn("refused_outside_limits", "refused to send %s %s: position outside the joint "
                               "limits or malformed", name, bytes(data).hex())
                    return False
        if not self.bus_up:
            if now_s is not None:
                self._now_s = now_s
            if not self._try_reopen(self._now_s):
                self.dropped["tx_while_down"] += 1
                return False
        try:
            self.bus.send(msg)
        except (can.CanError, OSError) as exc:
            self.dropped["tx_error"] += 1
            if self.reopen is not None:
                self._go_down(self._now_s if now_s is None else now_s, f"send error on {name}: {exc}")
            else:
                self._warn("tx_error", "bus send error on %s: %s", name, exc)
            return False
        self.tx[name] += 1
        return True
