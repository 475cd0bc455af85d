"""Load the DBC and turn it into codecs addressed by node id.

ODrive's messages are defined in the DBC for node 0 (frame id = cmd id); a driver at node N
uses ``N << 5 | cmd_id``. The sensor board's messages carry their full ids (node 16). The ODrive
messages match ODrive's own generated DBC for firmware 0.6.10 (``protocol/reference/``, read only
by the tests, never at run time) message for message, signal for signal.

Short frames: a receiver accepts a payload shorter than the DBC's length only for the messages of
:data:`SHORT_FRAMES` (ODrive's own examples send them short), down to the length given there; the
missing bytes read as zero. :attr:`MessageCodec.min_length` (or
:meth:`BusContract.min_payload_length`) is that shortest length, and :meth:`MessageCodec.unpack`
accepts exactly what it allows.

SDO: RxSdo and TxSdo carry an endpoint's value in bytes 4..7, whose type depends on the endpoint.
The DBC keeps ODrive's raw ``Value`` (uint32); :func:`sdo_value_bits` and :func:`sdo_bits_value`
convert a float32 endpoint's value to and from it.

Simulated time (``hil --clock sim``): ``ES_Sim_Sync``, ``ES_End_Of_Period`` and
``ES_Controller_State`` are the only messages on 29-bit extended ids (:data:`SIM_TIME_IDS`); they belong to
no node, so they are in :attr:`BusContract.extended` (by frame id), never in ``odrive`` or
``sensor_board``, and :meth:`BusContract.route` (11-bit ids only) never returns them. Their
``Sim_Time`` is a float64 (the plant's clock bit for bit), packed with ``struct``'s ``d``.

:class:`MessageCodec` packs and unpacks payloads. Where every signal of a message is
byte-aligned, little-endian and 8/16/32 bits wide (or a float64), the layout is compiled once into a
``struct.Struct`` for the hot path (its cost against cantools: docs/benchmarks.md); otherwise
(and for a float signal with a scale or offset) cantools does the work. Both paths come from the same DBC signal definitions and are tested
against each other.
"""

from __future__ import annotations

import functools
import math
import struct
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from types import MappingProxyType
from typing import Callable, Final, Mapping

import cantools

SENSOR_BOARD_NODE_ID: Final = 16
MASTER_NODE = "Controller"  # the DBC's name for the bus master: the messages only it sends
NODE_ID_BITS = 6
CMD_ID_MASK: Final = 0x1F
MAX_NODE_ID = 0x3F
MAX_STANDARD_ID = 0x7FF
SIM_SYNC_ID = 0x1FFFFF00
"""29-bit id of ``ES_Sim_Sync`` (the plant's simulated time, once per control period)."""
END_OF_PERIOD_ID = 0x1FFFFF01
"""29-bit id of ``ES_End_Of_Period`` (the controller has ticked for a sync)."""
CONTROLLER_STATE_ID = 0x1FFFFF02
"""29-bit id of ``ES_Controller_State`` (the controller's phase, sent before an end-of-period when it changed)."""
SIM_TIME_IDS = frozenset({SIM_SYNC_ID, END_OF_PERIOD_ID, CONTROLLER_STATE_ID})
"""The simulated-time protocol's ids: no node, fault or controller ``BusIO`` ever handles them."""
PHASE_CODES: tuple[str, ...] = ("wait_nodes", "inactive", "arming", "ramp", "walk", "fault")
"""``ES_Controller_State.Phase``: the code of each phase (:class:`controller.supervisor.Phase` values), in DBC order."""
DBC_PATH = Path(str(resources.files("protocol").joinpath("elegant_stepping.dbc")))

SHORT_FRAMES: Mapping[str, int] = MappingProxyType({
    # ODrive's CANSimple example (can_simple.py, docs' CAN guide) sends struct.pack('<I', state).
    "Set_Axis_State": 4,
    # ODrive's endpoint-access example sends a read as struct.pack('<BHB', opcode, endpoint, 0)
    # and a write of a 1- or 2-byte endpoint as 5 or 6 bytes.
    "RxSdo": 4,
    # The reference's own comment: an RTR or an empty payload asks for the serial number.
    "Address": 0,
    # Earlier CANSimple versions define these without a payload (no Identify, no Action): empty
    # means Identify 0 and Action 0 (reboot).
    "Clear_Errors": 0,
    "Reboot": 0,
})
"""Messages a receiver accepts shorter than the DBC's length: name -> shortest payload [bytes].
Every other message must carry at least its DBC length. Missing bytes read as zero."""

_F32 = struct.Struct("<f")
_U32 = struct.Struct("<I")


def sdo_value_bits(value: object) -> int:
    """RxSdo/TxSdo ``Value`` (the raw uint32 of bytes 4..7) carrying ``value`` as a float32.
    Raises ``ValueError`` for a value outside float32's range (NaN and infinities pass) and for
    anything not a number (typed ``object``, so that compiled it raises that, not a ``TypeError``)."""
    try:
        return _U32.unpack(_F32.pack(value))[0]
    except (OverflowError, struct.error) as exc:
        raise ValueError(f"{value!r} does not fit a float32 SDO value") from exc


def sdo_bits_value(bits: int) -> float:
    """The float32 a RxSdo/TxSdo ``Value`` (raw uint32) carries. Raises ``ValueError`` outside 0..2**32-1."""
    if not 0 <= bits <= 0xFFFFFFFF:
        raise ValueError(f"SDO value bits must be a uint32, got {bits!r}")
    return _F32.unpack(_U32.pack(bits))[0]


def arbitration_id(node_id: int, cmd_id: int) -> int:
    """CANSimple arbitration id: ``node_id << 5 | cmd_id``."""
    if not 0 <= node_id <= MAX_NODE_ID:
        raise ValueError(f"node id must be 0..63, got {node_id}")
    if not 0 <= cmd_id <= CMD_ID_MASK:
        raise ValueError(f"cmd id must be 0..31, got {cmd_id}")
    return (node_id << 5) | cmd_id


def split_arbitration_id(arb_id: int) -> tuple[int, int]:
    """(node_id, cmd_id) of a CANSimple arbitration id."""
    return arb_id >> 5, arb_id & CMD_ID_MASK


_STRUCT_CODES = {(8, False): "B", (8, True): "b", (16, False): "H", (16, True): "h", (32, False): "I", (32, True): "i"}


class MessageCodec:
    """Encode and decode one message's payload in physical units.

    ``pack(*values)`` and ``unpack(data)`` take and return values in the DBC's signal order;
    ``encode(**signals)`` and ``decode(data)`` use names. Integers outside a signal's raw range
    raise ``ValueError``; so do NaN or infinite values for integer signals.
    """

    def __init__(self, message: cantools.database.Message) -> None:
        self.message = message
        self.name: str = message.name
        self.frame_id: int = message.frame_id
        self.cmd_id: int = message.frame_id & CMD_ID_MASK
        self.dlc: int = message.length
        # Shortest payload a receiver accepts (SHORT_FRAMES; the DLC for every other message).
        self.min_length: int = min(SHORT_FRAMES.get(message.name, message.length), message.length)
        signals = sorted(message.signals, key=lambda s: s.start)
        self.signal_names: tuple[str, ...] = tuple(s.name for s in signals)
        self._scales = tuple((float(s.scale), float(s.offset), bool(s.is_float)) for s in signals)
        self._struct = self._compile(signals, message.length)
        self.compiled = self._struct is not None
        self._int_limits = tuple(self._raw_limits(s) for s in signals)
        # Fast path: no signal is scaled, so physical values are raw values and struct checks
        # integer ranges itself (struct.error -> ValueError below).
        self._identity = all(scale == 1.0 and offset == 0.0 for scale, offset, _ in self._scales)
        self._float_only = all(is_float for _, _, is_float in self._scales)
        self._int_fields = tuple(
            (i, scale, offset, *limits)  # type: ignore[misc]  # not None: integer fields only
            for i, ((scale, offset, is_float), limits) in enumerate(zip(self._scales, self._int_limits))
            if not is_float
        )
        # Hot-path helpers: the signal count and, for unpack, (index, scale, offset) of every
        # integer signal (converted to physical units; float signals pass through as decoded).
        self._n_signals = len(signals)
        self._int_scaling: tuple[tuple[int, float, float], ...] = tuple(
            (i, scale, offset) for i, scale, offset, _lo, _hi in self._int_fields)
        self._pack_raw = self._struct.pack if self._struct is not None else None
        self._unpack_raw = self._struct.unpack_from if self._struct is not None else None
        # pack's integer signals: (index, scale, offset, lo, hi, exact). ``exact`` (scale 1, offset
        # 0): an int value is its own raw value (the general (v - 0.0) / 1.0, rounded, gives back the
        # same int for every int a signal of at most 32 bits holds), so it skips the float round trip.
        self._pack_int_fields = tuple(
            (i, scale, offset, lo, hi, scale == 1.0 and offset == 0.0)
            for i, scale, offset, lo, hi in self._int_fields
        )
        self.pack_floats = self._pack_raw if self._float_only else None
        """Hot path: for a compiled message whose signals are all floats, the struct's own ``pack``:
        the bytes :meth:`pack` gives for the right number of values, without its count check (a
        wrong count raises ``struct.error``); None for any other message."""

    @staticmethod
    def _raw_limits(sig) -> tuple[int, int] | None:
        if sig.is_float:
            return None
        if sig.is_signed:
            return -(1 << (sig.length - 1)), (1 << (sig.length - 1)) - 1
        return 0, (1 << sig.length) - 1

    @staticmethod
    def _compile(signals, length: int) -> struct.Struct | None:
        fmt = "<"
        pos = 0
        for s in signals:
            if s.byte_order != "little_endian" or s.start % 8 or s.start < pos:
                return None
            if s.is_float:
                code = {32: "f", 64: "d"}.get(s.length)
            else:
                code = _STRUCT_CODES.get((s.length, s.is_signed))
            if code is None or (s.is_float and (s.scale != 1 or s.offset != 0)):
                return None  # (a scaled float is left to cantools: the struct path scales integers only)
            if s.start > pos:
                fmt += f"{(s.start - pos) // 8}x"
            fmt += code
            pos = s.start + s.length
        if pos > length * 8:
            return None
        if pos < length * 8:
            fmt += f"{(length * 8 - pos) // 8}x"
        return struct.Struct(fmt)

    def pack(self, *values: float) -> bytes:
        if len(values) != self._n_signals:
            raise ValueError(f"{self.name} takes {self._n_signals} signals, got {len(values)}")
        pack_raw = self._pack_raw
        if pack_raw is None:
            return self.encode(**dict(zip(self.signal_names, values)))
        if self._float_only:
            return pack_raw(*values)
        raw = list(values)
        isfinite = math.isfinite
        for i, scale, offset, lo, hi, exact in self._pack_int_fields:
            value = values[i]
            r: int
            if exact and type(value) is int:
                r = value  # hot path: an int for an unscaled signal (see _pack_int_fields)
            else:
                scaled = (value - offset) / scale  # (its own name: r holds an int, also compiled)
                if not isfinite(scaled):
                    raise ValueError(f"{self.name}: non-finite value {value!r} for an integer signal")
                r = round(scaled)
            if r < lo or r > hi:
                raise ValueError(f"{self.name}: value {value!r} outside the signal's raw range {(lo, hi)}")
            raw[i] = r
        return pack_raw(*raw)

    def exact_reader(self) -> Callable[[bytes | bytearray], tuple]:
        """What reads a payload of exactly :attr:`dlc` bytes, for a receiver that has checked the
        length: the struct's own ``unpack_from`` where :meth:`unpack` would return that read
        unchanged (every signal unscaled: Get_Encoder_Estimates, 1,000 frames a second), else
        :meth:`unpack` itself. The same tuple of the same types either way."""
        unpack_raw = self._unpack_raw
        return unpack_raw if self._identity and unpack_raw is not None else self.unpack

    def accepts_length(self, length: int) -> bool:
        """True if a received payload of ``length`` bytes is acceptable (:data:`SHORT_FRAMES`)."""
        return length >= self.min_length

    def unpack(self, data: bytes | bytearray) -> tuple[float, ...]:
        """Physical values in signal order. Raises ``ValueError`` on a payload shorter than
        :attr:`min_length`; a shorter payload it accepts (:data:`SHORT_FRAMES`) reads as if
        zero-padded to the DLC."""
        if len(data) < self.dlc:
            if len(data) < self.min_length:
                expected = f"DLC {self.dlc}" if self.min_length == self.dlc else f"at least {self.min_length}"
                raise ValueError(f"{self.name}: payload of {len(data)} bytes, {expected} expected")
            data = bytes(data) + bytes(self.dlc - len(data))
        unpack_raw = self._unpack_raw
        if unpack_raw is None:
            decoded = self.message.decode(bytes(data[: self.dlc]), decode_choices=False, scaling=True)
            return tuple(decoded[n] for n in self.signal_names)  # type: ignore[call-overload,misc]  # a dict
        raw = unpack_raw(data)
        if self._identity:
            return raw
        # Convert only the integer signals in place (cheaper than a generator over every signal).
        values = list(raw)
        for i, scale, offset in self._int_scaling:
            raw_i: int = values[i]  # (declared: compiled, the scaling is C arithmetic, the same floats)
            values[i] = raw_i * scale + offset
        return tuple(values)

    def encode(self, **signals: float) -> bytes:
        if self._struct is not None:
            missing = set(self.signal_names) - signals.keys()
            if missing:
                raise ValueError(f"{self.name}: missing signals {sorted(missing)}")
            return self.pack(*(signals[n] for n in self.signal_names))
        try:
            return bytes(self.message.encode(signals, scaling=True, strict=True))
        except cantools.database.errors.EncodeError as exc:  # the same ValueError as the struct path's
            raise ValueError(f"{self.name}: {exc}") from None

    def decode(self, data: bytes | bytearray) -> dict[str, float]:
        return dict(zip(self.signal_names, self.unpack(data)))


@dataclass(frozen=True)
class Route:
    """What an arbitration id means: which node sent or receives it and which message it is."""

    node_id: int
    codec: MessageCodec


class BusContract:
    """The DBC as codecs. ``BusContract.load()`` is cached: one parse per process."""

    def __init__(self, db: cantools.database.Database) -> None:
        self.db = db
        self.odrive: dict[int, MessageCodec] = {}
        self.sensor_board: dict[int, MessageCodec] = {}
        self.extended: dict[int, MessageCodec] = {}  # 29-bit frame id -> codec (simulated time only)
        self.by_name: dict[str, MessageCodec] = {}
        # What only the master sends (commands and Get_* requests' ids as data frames): hearing
        # one of these from someone else means another master is on the bus. Address is sent by
        # both (the ODrive answers with it), so it is not one of them.
        self.master_messages: frozenset[str] = frozenset(
            m.name for m in db.messages if set(m.senders) == {MASTER_NODE})
        for message in db.messages:
            codec = MessageCodec(message)
            self.by_name[message.name] = codec
            if message.is_extended_frame:
                self.extended[message.frame_id] = codec
                continue
            node_id = message.frame_id >> 5
            if node_id == 0:
                self.odrive[codec.cmd_id] = codec
            elif node_id == SENSOR_BOARD_NODE_ID:
                self.sensor_board[codec.cmd_id] = codec
            else:
                raise ValueError(f"DBC message {message.name} at {message.frame_id:#x} belongs to no known node")

    @property
    def odrive_master_cmds(self) -> frozenset[int]:
        """The CANSimple command ids (low 5 bits) of the messages only the master sends."""
        return frozenset(c.cmd_id for c in self.odrive.values() if c.name in self.master_messages)

    @classmethod
    @functools.lru_cache(maxsize=4)
    def load(cls, path: str | None = None) -> "BusContract":
        return cls(cantools.database.load_file(str(path or DBC_PATH)))  # type: ignore[arg-type]  # a .dbc

    def codec(self, name: str) -> MessageCodec:
        try:
            return self.by_name[name]
        except KeyError:
            raise KeyError(f"no message named {name!r} in the DBC") from None

    def route(self, arb_id: int) -> Route | None:
        """The node and codec of an 11-bit arbitration id, or None for an id outside the
        contract (every id above 0x7FF: the extended ids are in :attr:`extended`)."""
        if not 0 <= arb_id <= MAX_STANDARD_ID:
            return None
        node_id, cmd_id = split_arbitration_id(arb_id)
        table = self.sensor_board if node_id == SENSOR_BOARD_NODE_ID else self.odrive
        codec = table.get(cmd_id)
        return None if codec is None else Route(node_id, codec)

    def min_payload_length(self, name: str) -> int:
        """The shortest payload of ``name`` a receiver accepts: its DLC, or less for the
        messages of :data:`SHORT_FRAMES`."""
        return self.codec(name).min_length

    def odrive_id(self, node_id: int, name: str) -> int:
        return arbitration_id(node_id, self.codec(name).cmd_id)

    def cycle_time_s(self, name: str) -> float | None:
        ms = self.codec(name).message.cycle_time
        return None if not ms else ms / 1000.0
