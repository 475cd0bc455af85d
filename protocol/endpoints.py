"""ODrive endpoint ids for RxSdo / TxSdo (CANSimple 0x004 / 0x005): the ONE table both sides use.

**UNVERIFIED.** ODrive publishes the endpoint ids of each firmware build in its
``flat_endpoints.json``; we could not obtain that file for firmware 0.6.10, and the ids change
between builds. Every id below is therefore marked unverified (``Endpoint.verified`` is False for
all of them) and must be checked against ``flat_endpoints.json`` of the firmware actually flashed
before a real driver is written to through SDO.

Two parts, kept apart on purpose:

- :data:`LEAD`: ids from a public endpoint table whose firmware version was not stated
  (axis0.config.watchdog_timeout = 200, ...). Probably right for some 0.6.x build; not checked.
- :data:`PLACEHOLDER`: endpoints we need and for which we have no id at all (the controller
  gains and input mode). Their ids are invented, taken from the top of the 16-bit range
  (0xFF00 upwards) so that they cannot be mistaken for a published id; a real ODrive answers
  nothing to them. Only the simulated driver serves them.

``type`` is how the value sits in the SDO's 32-bit Value field (little-endian): ``float``
(IEEE-754 float32 bits), ``bool`` (0 or 1), ``uint8`` / ``uint32`` (the integer).

May import: the standard library only.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

SDO_OPCODE_READ = 0
"""RxSdo.Opcode: read the endpoint; the driver answers with TxSdo carrying its value."""
SDO_OPCODE_WRITE = 1
"""RxSdo.Opcode: write the endpoint; the driver answers nothing."""

VALUE_TYPES = ("float", "bool", "uint8", "uint32")

_F32 = struct.Struct("<f")
_U32 = struct.Struct("<I")


@dataclass(frozen=True)
class Endpoint:
    """One ODrive endpoint reachable through RxSdo/TxSdo."""

    path: str
    id: int
    type: str
    source: str
    verified: bool = False
    placeholder: bool = False

    def __post_init__(self) -> None:
        if self.type not in VALUE_TYPES:
            raise ValueError(f"{self.path}: type {self.type!r} not one of {VALUE_TYPES}")
        if not 0 <= self.id <= 0xFFFF:
            raise ValueError(f"{self.path}: endpoint id {self.id} outside 16 bits")

    def to_raw(self, value: float | int | bool) -> int:
        """The SDO Value field (uint32) carrying ``value`` as this endpoint's type."""
        if self.type == "float":
            return _U32.unpack(_F32.pack(float(value)))[0]
        raw = int(value)
        limit = 1 if self.type == "bool" else (0xFF if self.type == "uint8" else 0xFFFFFFFF)
        if not 0 <= raw <= limit:
            raise ValueError(f"{self.path}: {value!r} outside {self.type}")
        return raw

    def from_raw(self, raw: int) -> float | int | bool:
        """The value carried by an SDO Value field (uint32). Raises ValueError for a bool other
        than 0/1 or an uint8 above 255."""
        raw = int(raw)
        if self.type == "float":
            return _F32.unpack(_U32.pack(raw))[0]
        if self.type == "bool":
            if raw not in (0, 1):
                raise ValueError(f"{self.path}: {raw} is not a bool")
            return bool(raw)
        if self.type == "uint8" and raw > 0xFF:
            raise ValueError(f"{self.path}: {raw} outside uint8")
        return raw


_LEAD_SOURCE = "a public ODrive endpoint table, firmware version not stated (UNVERIFIED)"
_PLACEHOLDER_SOURCE = "no id found: invented placeholder, served only by the simulated driver"

LEAD: tuple[Endpoint, ...] = (
    Endpoint("config.dc_bus_undervoltage_trip_level", 142, "float", _LEAD_SOURCE),
    Endpoint("config.dc_bus_overvoltage_trip_level", 143, "float", _LEAD_SOURCE),
    Endpoint("axis0.current_state", 180, "uint8", _LEAD_SOURCE),
    Endpoint("axis0.requested_state", 181, "uint8", _LEAD_SOURCE),
    Endpoint("axis0.pos_estimate", 182, "float", _LEAD_SOURCE),
    Endpoint("axis0.vel_estimate", 183, "float", _LEAD_SOURCE),
    Endpoint("axis0.config.watchdog_timeout", 200, "float", _LEAD_SOURCE),
    Endpoint("axis0.config.enable_watchdog", 201, "bool", _LEAD_SOURCE),
    Endpoint("axis0.config.can.node_id", 229, "uint32", _LEAD_SOURCE),
)
"""Ids from the lead (a public table of unstated firmware version): all UNVERIFIED."""

PLACEHOLDER: tuple[Endpoint, ...] = (
    Endpoint("axis0.controller.config.input_mode", 0xFF00, "uint8", _PLACEHOLDER_SOURCE, placeholder=True),
    Endpoint("axis0.controller.config.pos_gain", 0xFF01, "float", _PLACEHOLDER_SOURCE, placeholder=True),
    Endpoint("axis0.controller.config.vel_gain", 0xFF02, "float", _PLACEHOLDER_SOURCE, placeholder=True),
    Endpoint("axis0.controller.config.vel_integrator_gain", 0xFF03, "float", _PLACEHOLDER_SOURCE,
             placeholder=True),
)
"""Endpoints with NO known id: invented ids (0xFF00 upwards), never to be sent to a real ODrive."""

ENDPOINTS: tuple[Endpoint, ...] = LEAD + PLACEHOLDER
BY_PATH: dict[str, Endpoint] = {e.path: e for e in ENDPOINTS}
BY_ID: dict[int, Endpoint] = {e.id: e for e in ENDPOINTS}
if len(BY_PATH) != len(ENDPOINTS) or len(BY_ID) != len(ENDPOINTS):
    raise RuntimeError("protocol.endpoints: duplicate endpoint path or id")

WATCHDOG_TIMEOUT = BY_PATH["axis0.config.watchdog_timeout"]
ENABLE_WATCHDOG = BY_PATH["axis0.config.enable_watchdog"]


def endpoint(path: str) -> Endpoint:
    """The endpoint named ``path`` (KeyError, with the path, if the table has none)."""
    try:
        return BY_PATH[path]
    except KeyError:
        raise KeyError(f"no endpoint {path!r} in protocol.endpoints") from None


__all__ = ["ENDPOINTS", "LEAD", "PLACEHOLDER", "BY_PATH", "BY_ID", "Endpoint", "endpoint", "WATCHDOG_TIMEOUT",
           "ENABLE_WATCHDOG", "SDO_OPCODE_READ", "SDO_OPCODE_WRITE"]
