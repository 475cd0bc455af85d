"""The deployment configuration: one TOML file for the whole leg, validated on load.

Every section and every key is optional: what a file leaves out keeps its default, and
``elegant-stepping config show [FILE]`` prints the effective configuration, every default
included, as TOML (with each key's unit and allowed range in a comment). Units are SI and are
part of every name.

==================  ==========================================================================
section             what it sets
==================  ==========================================================================
``[bus]``           the CAN bus: python-can interface, channel, bit rate (:class:`BusSettings`)
``[controller]``    loop rate, heartbeat period, node-silence and stale-heartbeat timeouts,
                    bring-up timeout, late ticks (the scalar fields of
                    :class:`~controller.config.ControllerConfig`)
``[axes.hip]``,     per axis: CAN node id, gear ratio, direction, zero offset (calibration),
``[axes.knee]``     joint limits, the current and velocity limits sent with Set_Limits at
                    arming (:class:`~controller.config.AxisConfig`)
``[drivers]``       what the drivers themselves are configured with: their command watchdog
                    timeout (:class:`DriverSettings`)
``[weights]``       where the learned weights live, how often they are saved (:class:`WeightsSettings`)
``[cpg]``,          the model, field by field onto the dataclass of the same name in
``[gait]``, ...     :class:`~controller.config.ControllerConfig`: ``cpg``, ``gait``, ``geometry``,
                    ``learner``, ``encoder``, ``range_filter``, ``reflexes``, ``height``
==================  ==========================================================================

Validation (:func:`load_config`, :func:`config_from_dict`) collects every problem in the file
and raises one :class:`ConfigError` listing them all. Each problem names the dotted field, the
value found, and what is allowed with its unit, e.g. ``axes.knee.gear_ratio = -6: must be in
[0.1, 1000] rev/rev``. Problems are: TOML that does not parse (with the line); unknown sections
and keys (the known ones listed); wrong types (a string where a number belongs, a float node
id, a number where true/false belongs); values out of range; and the cross-field checks: the two
axes on different node ids, neither the sensor board's 16; ``min_rad < max_rad`` and a joint
range that holds float32 motor positions; ``stale_heartbeat_periods >= silence_periods``; a
node-silence timeout (``heartbeat_period_s * silence_periods``) between 5 control periods and
:data:`MAX_SILENCE_TIMEOUT_S`; at least :data:`MIN_COMMANDS_PER_WATCHDOG` commands per driver
watchdog timeout; a standard CAN bit rate with room for the loop's frames
(:data:`MAX_BUS_LOAD`); the CPG's burst bounds; the encoder's cells within its range and its
range within the range filter's; a leg long enough to reach the ground.

The sensor board's node id is not a setting: it is the bus contract's
(:data:`protocol.SENSOR_BOARD_NODE_ID`, 16).

Relative weight paths are taken relative to the configuration file's folder, and stored
absolute. :func:`to_toml` writes a configuration back (a small emitter for this schema: tables
of scalars and one array); :func:`write_config` writes a file and checks that it reads back to
the same configuration.

TOML is read with the standard library's ``tomllib`` (Python 3.11+) or, on Python 3.10, with
``tomli``, the package ``tomllib`` was taken from.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10: the same parser, as a package
    import tomli as tomllib  # type: ignore[no-redef]

from can.interfaces import VALID_INTERFACES

from controller.io.axis import float32_target_bounds_rev
from controller.config import AxisConfig, ControllerConfig
from protocol import SENSOR_BOARD_NODE_ID

log = logging.getLogger(__name__)

STANDARD_BITRATES = (10_000, 20_000, 50_000, 100_000, 125_000, 250_000, 500_000, 800_000, 1_000_000)
"""The standard CAN bit rates [bit/s]: CiA 301's bit-timing table, plus the common 100 kbit/s."""

MIN_COMMANDS_PER_WATCHDOG = 3
"""The drivers' watchdog must see at least this many control periods per timeout."""

MAX_SILENCE_TIMEOUT_S = 2.0
"""Longest node-silence timeout [s]: a node lost longer than this leaves the rest of the leg
walking unsupervised."""

FRAME_BITS = 135
"""Bits of an 8-byte standard CAN data frame on the wire, worst-case bit stuffing and the
interframe space included."""

FRAMES_PER_TICK = 4
"""Frames each control tick puts on the bus at least: a Set_Input_Pos per axis and, at the same
rate, one Get_Encoder_Estimates per axis back."""

MAX_BUS_LOAD = 0.7
"""Largest fraction of the bit rate those frames may take (heartbeats, sensor frames and
retransmissions need the rest)."""


# ----------------------------------------------------------------------------- the dataclasses
@dataclass(frozen=True)
class BusSettings:
    """The CAN bus, as python-can opens it.

    Attributes:
        interface: python-can interface; default ``"socketcan"`` (Linux SocketCAN: ``can0`` for
            a USB-CAN adapter or a CAN HAT, ``vcan0`` for the simulated leg).
        channel: the channel; default ``"can0"``.
        bitrate: bit rate [bit/s]; default 1000000. Interfaces that set it (pcan, kvaser,
            slcan, gs_usb, ...) are given it; for SocketCAN it is set on the link (``ip link set
            can0 type can bitrate 1000000``) and must match the drivers' ``can.config.baud_rate``.
    """

    interface: str = "socketcan"
    channel: str = "can0"
    bitrate: int = 1_000_000

    def can_kwargs(self) -> dict[str, Any]:
        """Keyword arguments for :class:`can.Bus`."""
        return {"interface": self.interface, "channel": self.channel, "bitrate": self.bitrate}


@dataclass(frozen=True)
class DriverSettings:
    """What the motor drivers are configured with (in the drivers, not over CAN).

    Attributes:
        watchdog_timeout_s: the drivers' command watchdog [s]: an axis that hears no command
            for this long disarms (IDLE, WATCHDOG_TIMER_EXPIRED). ODrive's
            ``axis.config.watchdog_timeout`` (with ``axis.config.enable_watchdog``), set with
            odrivetool: CANSimple 0.6 cannot set it. The controller only checks its own command
            period against it (at least :data:`MIN_COMMANDS_PER_WATCHDOG` commands per
            timeout). Default 0.1, the simulated drivers'.
    """

    watchdog_timeout_s: float = 0.1


@dataclass(frozen=True)
class WeightsSettings:
    """Where the learned weights live.

    Attributes:
        path: the weights file (``.npz``, :mod:`controller.stepping.weights`): resumed from at start (else
            its ``.prev`` copy, else zeros) and saved while walking and at exit; ``""`` (default):
            not persisted. ``~`` is expanded; a relative path is relative to the configuration
            file's folder.
        save_every_s: save after this many seconds of walking, if the weights changed [s];
            default 10.0.
    """

    path: str = ""
    save_every_s: float = 10.0


@dataclass(frozen=True)
class DeployConfig:
    """Everything the controller daemon needs to run a leg.

    Attributes:
        bus: the CAN bus (:class:`BusSettings`).
        controller: the controller, axes and model (:class:`~controller.config.ControllerConfig`).
        drivers: what the drivers are configured with (:class:`DriverSettings`).
        weights: where the learned weights live (:class:`WeightsSettings`).
    """

    bus: BusSettings = BusSettings()
    controller: ControllerConfig = field(default_factory=ControllerConfig)
    drivers: DriverSettings = DriverSettings()
    weights: WeightsSettings = WeightsSettings()

    @property
    def weights_file(self) -> str | None:
        """The weights file, or None when the weights are not persisted."""
        return self.weights.path or None


class ConfigError(ValueError):
    """A configuration with problems. ``problems``: one line each, every one naming its field;
    ``source``: the file (or ``"<config>"``). ``str()`` is every problem on its own line, each
    prefixed with the source."""

    def __init__(self, problems: list[str], source: str | os.PathLike = "<config>") -> None:
        self.problems = list(problems)
        self.source = str(source)
        super().__init__("\n".join(self.lines()))

    def lines(self) -> list[str]:
        return [f"{self.source}: {p}" for p in self.problems]


# ----------------------------------------------------------------------------- the schema
def _num(x: float) -> str:
    """A bound or a computed figure, for a message: 1000 not 1000.0, 6.28319 not 6.283185307."""
    if isinstance(x, int) and not isinstance(x, bool):
        return str(x)
    if math.isfinite(x) and x == int(x) and abs(x) < 1e15:
        return str(int(x))
    return f"{x:.6g}"


def toml_string(text: str) -> str:
    """``text`` as a TOML basic string (quotation mark, backslash and control characters escaped)."""
    out = ['"']
    for ch in text:
        if ch == '"':
            out.append('\\"')
        elif ch == "\\":
            out.append("\\\\")
        elif ch in "\b\t\n\f\r":
            out.append({"\b": "\\b", "\t": "\\t", "\n": "\\n", "\f": "\\f", "\r": "\\r"}[ch])
        elif ord(ch) < 0x20 or ord(ch) == 0x7F:
            out.append(f"\\u{ord(ch):04X}")
        else:
            out.append(ch)
    out.append('"')
    return "".join(out)


def toml_value(value: Any) -> str:
    """A value of this schema (bool, int, float, str, or a tuple/list of numbers) as TOML."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)  # the shortest text that reads back to the same float; valid TOML
    if isinstance(value, str):
        return toml_string(value)
    if isinstance(value, (tuple, list)):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    raise TypeError(f"no TOML for {value!r}")


def _show(value: Any) -> str:
    """The value found, for a message: as it would be written in TOML."""
    if isinstance(value, dict):
        return "a table"
    try:
        return toml_value(value)
    except TypeError:
        return repr(value)


def _type_name(value: Any) -> str:
    if isinstance(value, bool):
        return "true/false"
    return {int: "an integer", float: "a float", str: "a string", list: "an array", dict: "a table"}.get(
        type(value), type(value).__name__)


@dataclass(frozen=True)
class Setting:
    """One key of a section.

    Attributes:
        key: the key (the dataclass field of the same name).
        kind: ``"float"`` (an integer is taken too), ``"int"``, ``"bool"``, ``"str"``, or
            ``"floats"`` (an array of numbers).
        unit: the unit, as printed after the range (a physical unit, or words in parentheses).
        lo, hi: the allowed range (inclusive), for numbers and each number of an array.
        doc: one line: what it is.
        choices: the only values allowed, if not empty.
        exclude: (value, reason) pairs refused even inside the range.
        items: (fewest, most) numbers in an array.
        check: a further check of the value, returning a problem (without the field) or None.
    """

    key: str
    kind: str
    unit: str = ""
    lo: float | None = None
    hi: float | None = None
    doc: str = ""
    choices: tuple = ()
    exclude: tuple[tuple[Any, str], ...] = ()
    items: tuple[int, int] = (1, 1)
    check: Callable[[Any], str | None] | None = None

    def _unit(self) -> str:
        return f" {self.unit}" if self.unit else ""

    def _range(self) -> str:
        return f"[{_num(self.lo)}, {_num(self.hi)}]{self._unit()}"

    def _choices(self) -> str:
        shown = [_show(c) for c in self.choices]
        if len(shown) <= 2:
            return " or ".join(shown) + self._unit()
        return "one of " + ", ".join(shown[:-1]) + " or " + shown[-1] + self._unit()

    def allowed(self) -> str:
        """What is allowed, with the unit: ``[0.1, 1000] rev/rev``, ``1 or -1 (sign ...)``."""
        if self.kind == "bool":
            return "true or false"
        if self.choices:
            return self._choices()
        if self.lo is not None and self.hi is not None:
            text = ("each in " if self.kind == "floats" else "") + self._range()
            return text + "".join(f", not {_num(bad)}" for bad, _ in self.exclude)
        return self.unit or "any"

    def parse(self, value: Any) -> tuple[Any, str | None]:
        """(the value converted, None) or (None, the problem without the field's name)."""
        kind = self.kind
        if kind == "bool":
            if not isinstance(value, bool):
                return None, f"must be true or false ({self.doc}), not {_type_name(value)}"
            return value, None
        if kind == "str":
            if not isinstance(value, str):
                return None, f"must be a string ({self.doc}), not {_type_name(value)}"
            if self.choices and value not in self.choices:
                return None, f"must be {self._choices()}"
            if self.check is not None:
                problem = self.check(value)
                if problem:
                    return None, problem
            return value, None
        if kind == "floats":
            fewest, most = self.items
            if not isinstance(value, list):
                return None, f"must be an array of {fewest} to {most} numbers, each in {self._range()}, " \
                             f"not {_type_name(value)}"
            if not fewest <= len(value) <= most:
                return None, f"must list {fewest} to {most} numbers, each in {self._range()}; it lists {len(value)}"
            out = []
            for i, v in enumerate(value):
                number, problem = self._number(v, float)
                if problem:
                    return None, f"item {i} ({_show(v)}) {problem}"
                out.append(number)
            if self.check is not None:
                problem = self.check(tuple(out))
                if problem:
                    return None, problem
            return tuple(out), None
        return self._number(value, int if kind == "int" else float)

    def _number(self, value: Any, kind: type) -> tuple[Any, str | None]:
        ranged = self.lo is not None and self.hi is not None
        if isinstance(value, bool) or not isinstance(value, (int, float)) or (kind is int and isinstance(value, float)):
            what = "an integer" if kind is int else "a number"
            if ranged:
                expect = f" in {self._range()}"
            else:
                expect = ", " + self._choices() + ("" if self.unit else f" ({self.doc})")
            return None, f"must be {what}{expect}, not {_type_name(value)}"
        number = kind(value)
        if ranged and not (math.isfinite(number) and self.lo <= number <= self.hi):
            return None, f"must be in {self._range()}"
        if self.choices and number not in self.choices:
            return None, f"must be {self._choices()}" + ("" if self.unit else f" ({self.doc})")
        for bad, reason in self.exclude:
            if number == bad:
                return None, f"must be in {self._range()} and not {_num(bad)}: {reason}"
        return number, None


def _f(key: str, unit: str, lo: float, hi: float, doc: str, **kw: Any) -> Setting:
    return Setting(key, "float", unit, lo, hi, doc, **kw)


def _i(key: str, unit: str, lo: int, hi: int, doc: str, **kw: Any) -> Setting:
    return Setting(key, "int", unit, lo, hi, doc, **kw)


def _check_channel(text: str) -> str | None:
    if not text or text != text.strip() or "\x00" in text:
        return "must name the bus channel (e.g. \"can0\", \"vcan0\"), without spaces around it"
    return None


def _check_weights_path(text: str) -> str | None:
    if "\x00" in text:
        return "must be a file path (.npz) or \"\" for none, without NUL characters"
    if text and not text.endswith(".npz"):
        return "must be an .npz file path (e.g. \"/var/lib/elegant-stepping/weights.npz\") or \"\" for none"
    return None


def _check_increasing(values: tuple[float, ...]) -> str | None:
    if any(b <= a for a, b in zip(values, values[1:])):
        return "must be strictly increasing (lowest beam first) [m]"
    return None


TWO_PI = 2.0 * math.pi

BUS = (
    Setting("interface", "str", "", doc="python-can interface", choices=tuple(sorted(VALID_INTERFACES))),
    Setting("channel", "str", "", doc="bus channel, e.g. can0 or vcan0", check=_check_channel),
    _i("bitrate", "bit/s (a standard CAN rate)", 10_000, 1_000_000, "CAN bit rate, the drivers' can.config.baud_rate",
       choices=STANDARD_BITRATES),
)

CONTROLLER = (
    _f("rate_hz", "Hz", 10.0, 5000.0, "control loop rate"),
    _f("heartbeat_period_s", "s", 0.001, 10.0,
       "the nodes' heartbeat period (ODrive axis.config.can.heartbeat_msg_rate_ms / 1000)"),
    _f("silence_periods", "heartbeat periods", 1.0, 100.0,
       "a node with no valid frame for this long is lost (safe stop)"),
    _f("stale_heartbeat_periods", "heartbeat periods", 1.0, 1000.0,
       "a node with no heartbeat for this long is lost"),
    _f("bringup_timeout_s", "s", 0.01, 600.0, "give up bringing the axes up after this long"),
    _f("late_factor", "control periods", 1.0, 100.0, "a tick longer than this is late"),
    _f("max_dt_factor", "control periods", 1.0, 100.0, "the CPG integrates at most this much per tick"),
)

AXIS = (
    _i("node_id", "(CAN node id)", 0, 63, "the axis's CANSimple node id (ODrive axis.config.can.node_id)",
       exclude=((SENSOR_BOARD_NODE_ID, "that is the sensor board's"),)),
    _f("gear_ratio", "rev/rev", 0.1, 1000.0, "motor revolutions per joint revolution"),
    Setting("direction", "int", "", doc="the sign from joint angle to motor angle", choices=(1, -1)),
    _f("zero_offset_rev", "rev", -1000.0, 1000.0, "motor position at joint angle 0 (calibration)"),
    _f("min_rad", "rad", -TWO_PI, TWO_PI, "lowest joint angle ever commanded"),
    _f("max_rad", "rad", -TWO_PI, TWO_PI, "highest joint angle ever commanded"),
    _f("current_limit_a", "A", 0.1, 200.0, "motor current limit, sent with Set_Limits at arming"),
    _f("vel_limit_rev_s", "rev/s", 0.1, 80.0, "motor velocity limit, sent with Set_Limits at arming"),
)

DRIVERS = (
    _f("watchdog_timeout_s", "s", 0.005, 1.0,
       "the drivers' command watchdog (ODrive axis.config.watchdog_timeout; set with odrivetool)"),
)

WEIGHTS = (
    Setting("path", "str", "", doc="the learned weights' .npz file; \"\" = not persisted", check=_check_weights_path),
    _f("save_every_s", "s", 0.1, 86400.0, "save after this much walking, if they changed"),
)

MODEL: dict[str, tuple[Setting, ...]] = {
    "cpg": (
        _f("stance_s", "s", 0.05, 5.0, "extension (stance) half of the ring"),
        _f("burst_s", "s", 0.05, 5.0, "base burst length (swing)"),
        _f("burst_min_s", "s", 0.05, 5.0, "shortest burst the premotor may ask for"),
        _f("burst_max_s", "s", 0.05, 5.0, "longest burst the premotor may ask for"),
        _f("activation_tau_s", "s", 0.001, 1.0, "time constant of each unit's output"),
        _i("units_per_half", "units", 1, 8, "ring units per half"),
    ),
    "gait": (
        _f("ground_speed_m_s", "m/s", 0.0, 3.0, "rail speed the stance foot matches"),
        _f("foot_ahead_m", "m", -0.5, 0.5, "foot x at touchdown, ahead of the hip"),
        _f("step_height_m", "m", 0.0, 0.3, "foot lift at full amplitude"),
        _f("stance_press_m", "m", 0.0, 0.05, "stance target below the ground"),
        _f("muscle_tau_s", "s", 0.0, 1.0, "muscle low-pass time constant"),
        _f("ramp_s", "s", 0.0, 10.0, "move to the start pose in this long"),
    ),
    "geometry": (
        _f("thigh_m", "m", 0.01, 2.0, "hip to knee"),
        _f("shank_m", "m", 0.01, 2.0, "knee to foot centre"),
        _f("hip_height_m", "m", 0.01, 4.0, "hip axis above the ground"),
        _f("foot_radius_m", "m", 0.0, 0.2, "foot sphere radius"),
    ),
    "learner": (
        _f("stm_tau_s", "s", 0.01, 60.0, "short-term memory decay"),
        _f("trace_tau_s", "s", 0.01, 60.0, "synaptic trace decay"),
        _f("learning_rate_s", "s", 0.0, 1.0, "weight change per unit trace per reflex"),
        _f("weight_limit_s", "s", 0.001, 2.0, "bound on each weight's magnitude"),
        Setting("learning", "bool", doc="false freezes the weights"),
    ),
    "encoder": (
        _f("cell_width_m", "m", 0.001, 1.0, "width of one range cell"),
        _f("max_range_m", "m", 0.01, 10.0, "the encoded range"),
    ),
    "range_filter": (
        _f("noise_m", "m", 0.0001, 1.0, "standard deviation of one range reading"),
        _f("accel_noise_m_s2", "m/s^2", 0.0, 100.0, "white-acceleration process noise"),
        _f("max_range_m", "m", 0.01, 100.0, "readings beyond this are out of range"),
        _f("stale_s", "s", 0.001, 10.0, "no valid reading for this long: no target"),
        _f("gate_sigma", "standard deviations", 0.5, 100.0, "innovation gate for outliers"),
        _i("reacquire_after", "readings", 1, 1000, "consecutive outliers that mean a new target"),
    ),
    "reflexes": (
        _f("touchdown_phase", "(fraction of the swing)", 0.0, 1.0, "after this a foot contact is a touchdown"),
        _f("on_top_height_m", "m", 0.0, 0.5, "foot contact this high means it landed on something"),
        _f("refractory_s", "s", 0.0, 10.0, "minimum time between two contact reflexes"),
        _f("lift_range_m", "m", 0.0, 3.0, "gated range below which the lift reflex fires"),
        _f("lift_amplitude", "x step height", 0.1, 5.0, "CPG amplitude during a lift"),
    ),
    "height": (
        Setting("beam_heights_m", "floats", "m", 0.001, 0.5, "profile beam heights, lowest first", items=(1, 8),
                check=_check_increasing),
        _f("match_tolerance_m", "m", 0.001, 1.0, "a beam sees the target within this of the range"),
        _i("window", "samples", 1, 1000, "profile samples voted over"),
        _f("seen_fraction", "(fraction of samples)", 0.01, 1.0, "a beam sees the target this often"),
        _f("jump_m", "m", 0.001, 10.0, "a range jump this large clears the votes"),
    ),
}

AXIS_NAMES = ("hip", "knee")

SECTIONS: dict[str, tuple[Setting, ...]] = {
    "bus": BUS,
    "controller": CONTROLLER,
    **{f"axes.{name}": AXIS for name in AXIS_NAMES},
    "drivers": DRIVERS,
    "weights": WEIGHTS,
    **MODEL,
}
"""Every section, in the order ``config show`` writes them, with its settings."""

_SETTING = {section: {s.key: s for s in settings} for section, settings in SECTIONS.items()}


# ----------------------------------------------------------------------------- dict <-> config
Tables = dict[str, dict[str, Any]]


def _fields(obj: Any, keys: tuple[Setting, ...]) -> dict[str, Any]:
    return {s.key: getattr(obj, s.key) for s in keys}


def config_tables(config: DeployConfig) -> Tables:
    """The configuration as ``{section: {key: value}}``, every key of :data:`SECTIONS`."""
    ctl = config.controller
    if ctl.sensor_node_id != SENSOR_BOARD_NODE_ID:
        raise ValueError(f"sensor_node_id {ctl.sensor_node_id}: the file format has the bus contract's "
                         f"{SENSOR_BOARD_NODE_ID} only")
    tables: Tables = {
        "bus": _fields(config.bus, BUS),
        "controller": _fields(ctl, CONTROLLER),
        **{f"axes.{name}": _fields(ctl.axis(name), AXIS) for name in AXIS_NAMES},
        "drivers": _fields(config.drivers, DRIVERS),
        "weights": _fields(config.weights, WEIGHTS),
    }
    for section, settings in MODEL.items():
        tables[section] = _fields(getattr(ctl, section), settings)
    return tables


def _build(tables: Tables) -> DeployConfig:
    base = ControllerConfig()
    axes = tuple(AxisConfig(name=name, **tables[f"axes.{name}"]) for name in AXIS_NAMES)
    model = {section: dataclasses.replace(getattr(base, section), **tables[section]) for section in MODEL}
    controller = dataclasses.replace(base, axes=axes, **tables["controller"], **model)
    return DeployConfig(bus=BusSettings(**tables["bus"]), controller=controller,
                        drivers=DriverSettings(**tables["drivers"]), weights=WeightsSettings(**tables["weights"]))


def _sections_given(data: Mapping[str, Any], problems: list[str]) -> Tables:
    """The file's tables by dotted section name; unknown sections and misplaced keys are problems."""
    given: Tables = {}
    known = ", ".join(f"[{name}]" for name in SECTIONS)
    for name, value in data.items():
        if name == "axes":
            if not isinstance(value, dict):
                problems.append(f"axes = {_show(value)}: must be the tables [axes.hip] and [axes.knee]")
                continue
            for axis, table in value.items():
                if axis not in AXIS_NAMES:
                    if isinstance(table, dict):
                        problems.append(f"[axes.{axis}]: unknown axis (known: [axes.hip], [axes.knee])")
                    else:
                        problems.append(f"axes.{axis} = {_show(table)}: axis settings go in [axes.hip] or "
                                        f"[axes.knee] (known there: {', '.join(s.key for s in AXIS)})")
                elif not isinstance(table, dict):
                    problems.append(f"axes.{axis} = {_show(table)}: must be a table [axes.{axis}]")
                else:
                    given[f"axes.{axis}"] = table
        elif name in SECTIONS:
            if not isinstance(value, dict):
                problems.append(f"{name} = {_show(value)}: must be a table [{name}]")
            else:
                given[name] = value
        elif isinstance(value, dict):
            problems.append(f"[{name}]: unknown section (known: {known})")
        else:
            problems.append(f"{name} = {_show(value)}: unknown top-level setting; every setting belongs to a "
                            f"section (known: {known})")
    return given


def _cross_checks(t: Tables, bad: set[str], problems: list[str]) -> None:
    """Checks across fields, each only when the fields it reads are valid themselves."""

    def ok(*dotted: str) -> bool:
        return not any(d in bad for d in dotted)

    def v(dotted: str) -> Any:
        section, key = dotted.rsplit(".", 1)
        return t[section][key]

    hip, knee = "axes.hip.node_id", "axes.knee.node_id"
    if ok(hip, knee) and v(hip) == v(knee):
        problems.append(f"{hip} = {v(hip)} and {knee} = {v(knee)}: the two axes need different CAN node ids "
                        f"(0..63, not {SENSOR_BOARD_NODE_ID})")
    for name in AXIS_NAMES:
        lo, hi = f"axes.{name}.min_rad", f"axes.{name}.max_rad"
        if ok(lo, hi) and not v(lo) < v(hi):
            problems.append(f"{lo} = {_show(v(lo))} rad must be below {hi} = {_show(v(hi))} rad")
        elif all(ok(f"axes.{name}.{s.key}") for s in AXIS):
            try:
                float32_target_bounds_rev(AxisConfig(name=name, **t[f"axes.{name}"]))
            except ValueError as exc:
                problems.append(f"[axes.{name}]: {exc} (zero_offset_rev too large for the joint range?)")

    silence, stale, period = "controller.silence_periods", "controller.stale_heartbeat_periods", \
        "controller.heartbeat_period_s"
    rate, watchdog = "controller.rate_hz", "drivers.watchdog_timeout_s"
    if ok(silence, stale) and v(stale) < v(silence):
        problems.append(f"{stale} = {_show(v(stale))} must be at least {silence} = {_show(v(silence))} "
                        "heartbeat periods")
    if ok(silence, period, rate):
        timeout_s = v(period) * v(silence)
        lo_s = 5.0 / v(rate)
        if not lo_s <= timeout_s <= MAX_SILENCE_TIMEOUT_S:
            problems.append(f"{period} x {silence} = {_show(v(period))} s x {_show(v(silence))} = {_num(timeout_s)} s, "
                            f"the node-silence timeout: must be in [{_num(lo_s)}, {_num(MAX_SILENCE_TIMEOUT_S)}] s "
                            f"(at least 5 control periods at {rate} = {_show(v(rate))} Hz; a node lost longer "
                            "than that leaves the leg unsupervised)")
    if ok(rate, watchdog):
        need_s = MIN_COMMANDS_PER_WATCHDOG / v(rate)
        if v(watchdog) < need_s:
            problems.append(f"{watchdog} = {_show(v(watchdog))} s with {rate} = {_show(v(rate))} Hz: the drivers' "
                            f"watchdog must see at least {MIN_COMMANDS_PER_WATCHDOG} commands per timeout, so it "
                            f"must be at least {_num(need_s)} s (or {rate} at least "
                            f"{_num(MIN_COMMANDS_PER_WATCHDOG / v(watchdog))} Hz)")
    bitrate, interface = "bus.bitrate", "bus.interface"
    if ok(rate, bitrate, interface) and v(interface) != "virtual":
        need_bit_s = FRAMES_PER_TICK * FRAME_BITS * v(rate)
        if need_bit_s > MAX_BUS_LOAD * v(bitrate):
            problems.append(f"{rate} = {_show(v(rate))} Hz on {bitrate} = {v(bitrate)} bit/s: "
                            f"{FRAMES_PER_TICK} frames per tick (a Set_Input_Pos and an encoder reply per axis, "
                            f"{FRAME_BITS} bits each) take {_num(need_bit_s)} bit/s, over {MAX_BUS_LOAD:.0%} of the "
                            f"bus: at most {_num(MAX_BUS_LOAD * v(bitrate) / (FRAMES_PER_TICK * FRAME_BITS))} Hz "
                            "at this bit rate")
    channel = "bus.channel"
    if ok(interface, channel) and v(interface) == "socketcan" and len(v(channel)) > 15:
        problems.append(f"{channel} = {_show(v(channel))}: a SocketCAN interface name has at most 15 characters")

    b, bmin, bmax = "cpg.burst_s", "cpg.burst_min_s", "cpg.burst_max_s"
    if ok(bmin, bmax) and v(bmax) < v(bmin):
        problems.append(f"{bmax} = {_show(v(bmax))} s must be at least {bmin} = {_show(v(bmin))} s")
    elif ok(b, bmin, bmax) and not v(bmin) <= v(b) <= v(bmax):
        problems.append(f"{b} = {_show(v(b))}: must be in [{bmin}, {bmax}] = [{_show(v(bmin))}, {_show(v(bmax))}] s")
    width, enc_range, filt_range = "encoder.cell_width_m", "encoder.max_range_m", "range_filter.max_range_m"
    if ok(width, enc_range) and v(width) > v(enc_range):
        problems.append(f"{width} = {_show(v(width))} m must be at most {enc_range} = {_show(v(enc_range))} m")
    if ok(enc_range, filt_range) and v(enc_range) > v(filt_range):
        problems.append(f"{enc_range} = {_show(v(enc_range))} m must be at most {filt_range} = "
                        f"{_show(v(filt_range))} m (cells beyond the filtered range are never active)")
    reach = ("geometry.thigh_m", "geometry.shank_m", "geometry.hip_height_m", "geometry.foot_radius_m",
             "gait.stance_press_m")
    if ok(*reach):
        leg_m = 0.999 * (v("geometry.thigh_m") + v("geometry.shank_m"))  # the kinematics' reach
        down_m = v("geometry.hip_height_m") - v("geometry.foot_radius_m") + v("gait.stance_press_m")
        if down_m > leg_m:
            problems.append(f"geometry.hip_height_m - geometry.foot_radius_m + gait.stance_press_m = {_num(down_m)} m: "
                            f"the stance foot cannot reach the ground with geometry.thigh_m + geometry.shank_m = "
                            f"{_num(leg_m / 0.999)} m")


def validate_tables(data: Mapping[str, Any]) -> tuple[Tables, list[str]]:
    """Check a parsed TOML document against :data:`SECTIONS` and the cross-field checks: (every
    section's values, the defaults for what it leaves out; every problem found)."""
    problems: list[str] = []
    tables = config_tables(DeployConfig())
    bad: set[str] = set()
    for section, values in _sections_given(data, problems).items():
        known = _SETTING[section]
        for key, value in values.items():
            dotted = f"{section}.{key}"
            setting = known.get(key)
            if setting is None:
                problems.append(f"{dotted}: unknown setting (known in [{section}]: {', '.join(known)})")
                continue
            parsed, problem = setting.parse(value)
            if problem:
                problems.append(f"{dotted} = {_show(value)}: {problem}")
                bad.add(dotted)
            else:
                tables[section][key] = parsed
    _cross_checks(tables, bad, problems)
    return tables, problems


def config_from_dict(data: Mapping[str, Any], source: str | os.PathLike = "<config>",
                     base_dir: str | os.PathLike | None = None) -> DeployConfig:
    """The configuration a parsed TOML document describes, defaults for what it leaves out.
    ``base_dir``: relative weight paths are taken relative to it (and stored absolute).
    Raises :class:`ConfigError` with every problem found."""
    tables, problems = validate_tables(data)
    if not problems:
        path = os.path.expanduser(tables["weights"]["path"])
        if path and base_dir is not None and not os.path.isabs(path):
            path = os.path.normpath(os.path.join(os.path.abspath(base_dir), path))
        tables["weights"]["path"] = path
        try:
            return _build(tables)
        except ValueError as exc:  # a check of the dataclasses this schema does not make itself (a bug)
            problems.append(str(exc))
    raise ConfigError(problems, source)


_AT_LINE = re.compile(r"at line (\d+), column (\d+)")


def config_from_toml(text: str, source: str | os.PathLike = "<config>",
                     base_dir: str | os.PathLike | None = None) -> DeployConfig:
    """The configuration in TOML ``text`` (see :func:`config_from_dict`)."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        problem = f"not valid TOML: {exc}"
        m = _AT_LINE.search(str(exc))
        lines = text.splitlines()
        if m and 1 <= int(m.group(1)) <= len(lines):
            problem += f": {lines[int(m.group(1)) - 1].strip()!r}"
        if text.lstrip().startswith("{"):
            problem += " (this looks like JSON: the configuration is TOML now; `elegant-stepping config show` " \
                       "prints every setting as TOML)"
        raise ConfigError([problem], source) from None
    return config_from_dict(data, source, base_dir)


def load_config(path: str | os.PathLike) -> DeployConfig:
    """Read and validate a TOML configuration file. Raises :class:`ConfigError` (a missing or
    unreadable file, malformed TOML, or every problem in the file)."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise ConfigError([f"cannot read the configuration: {exc.strerror or exc}"], path) from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ConfigError([f"not UTF-8 text (byte {exc.start}): a TOML file is UTF-8"], path) from None
    config = config_from_toml(text, path, base_dir=path.parent)
    log.info("configuration %s: %s", path, summary(config))
    return config


def check_config(config: DeployConfig) -> list[str]:
    """The problems :func:`load_config` would report for this configuration written to a file."""
    tables = config_tables(config)
    data: dict[str, Any] = {}
    for section, values in tables.items():
        if section.startswith("axes."):
            data.setdefault("axes", {})[section.split(".", 1)[1]] = dict(values)
        else:
            data[section] = {k: (list(x) if isinstance(x, tuple) else x) for k, x in values.items()}
    try:
        config_from_dict(data)
    except ConfigError as exc:
        return exc.problems
    return []


def to_toml(config: DeployConfig, comments: bool = True, header: str | None = None) -> str:
    """The configuration as TOML: every section and key of :data:`SECTIONS` (what ``config show``
    prints). ``comments``: each key's meaning, unit and allowed range after it."""
    tables = config_tables(config)
    out: list[str] = []
    if header:
        out.extend(f"# {line}".rstrip() for line in header.splitlines())
        out.append("")
    for section, settings in SECTIONS.items():
        out.append(f"[{section}]")
        for s in settings:
            line = f"{s.key} = {toml_value(tables[section][s.key])}"
            if comments:
                line = f"{line:<40}  # {s.doc}: {s.allowed()}" if s.kind != "str" else f"{line:<40}  # {s.doc}"
            out.append(line)
        out.append("")
    return "\n".join(out)


def write_config(path: str | os.PathLike, config: DeployConfig, header: str | None = None) -> Path:
    """Write ``config`` as TOML to ``path`` (atomically), after checking that it is valid and
    reads back to the same configuration. Raises :class:`ConfigError` otherwise."""
    path = Path(path)
    problems = check_config(config)
    if problems:
        raise ConfigError(problems, path)
    text = to_toml(config, header=header)
    if config_from_toml(text, path) != config:
        raise ConfigError(["does not read back to the configuration written (a bug in the emitter)"], path)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text)
    tmp.replace(path)
    return path


def summary(config: DeployConfig) -> str:
    """One line: the bus, the axes, the rate, the watchdog, the weights."""
    bus, ctl = config.bus, config.controller

    def axis(a: AxisConfig) -> str:
        return (f"{a.name} node {a.node_id} ({_num(a.gear_ratio)}:1, direction {a.direction:+d}, "
                f"[{_num(a.min_rad)}, {_num(a.max_rad)}] rad, {_num(a.current_limit_a)} A, "
                f"{_num(a.vel_limit_rev_s)} rev/s)")

    weights = config.weights_file or "not persisted"
    return (f"{bus.interface} {bus.channel} at {bus.bitrate} bit/s; {', '.join(axis(a) for a in ctl.axes)}; "
            f"{_num(ctl.rate_hz)} Hz, watchdog {_num(config.drivers.watchdog_timeout_s)} s; weights {weights}")


__all__ = [
    "BusSettings", "DriverSettings", "WeightsSettings", "DeployConfig", "ConfigError", "Setting", "SECTIONS",
    "load_config", "config_from_dict", "config_from_toml", "validate_tables", "config_tables", "check_config",
    "to_toml",
    "write_config", "summary",
]
