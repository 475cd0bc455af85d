"""The deployment configuration: one TOML file for the whole leg, validated on load.

On a simulated bus (``bus.interface = "virtual"``, or a ``bus.channel`` starting with ``vcan``)
every section and every key is optional: what a file leaves out keeps its default (the
simulated leg's). On a real bus the file must give the ``[bus]`` section and each axis's
``node_id``, ``gear_ratio``, ``direction``, ``zero_offset_rev``, ``min_rad`` and ``max_rad``
itself (:data:`REAL_BUS_REQUIRED`): the defaults are the simulated leg's, never a real leg's
calibration. ``elegant-stepping config show [FILE]`` prints the effective configuration, every default
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
                    arming (:class:`~controller.io.axis.AxisConfig`)
``[drivers]``       what the drivers themselves are configured with: their command watchdog
                    timeout (:class:`DriverSettings`)
``[weights]``       where the learned weights live, how often they are saved, how many good
                    generations are kept (:class:`WeightsSettings`)
``[service]``       the daemon as a service: its control socket, the group allowed to command
                    it, the records' rotation (:class:`ServiceSettings`)
``[calibration]``   whether a person confirmed this leg's calibration after a bring-up that
                    passed (:class:`CalibrationSettings`): a leg is never armed on a calibration
                    nobody confirmed (:meth:`DeployConfig.armable_reason`)
``[cpg]``,          the model, field by field onto the dataclass of the same name in
``[gait]``, ...     :class:`~controller.config.ControllerConfig`: ``cpg``, ``gait``, ``geometry``,
                    ``learner``, ``encoder``, ``range_filter``, ``reflexes``, ``height``; and
                    ``[health]``, the drivers' runtime bounds (:class:`~controller.io.health.HealthConfig`)
==================  ==========================================================================

The schema is not written here: each key's kind, unit, range and one-line comment are the
dataclass field's own declaration (:func:`controller.settings.schema.setting`, beside the module
the dataclass configures), which the dataclass also checks on creation; this module adds the
sections and the checks across fields.

Validation (:func:`load_config`, :func:`config_from_dict`) collects every problem in the file
and raises one :class:`ConfigError` listing them all. Each problem names the dotted field, the
value found, and what is allowed with its unit, e.g. ``axes.knee.gear_ratio = -6: must be in
[0.1, 1000] rev/rev``. Problems are: TOML that does not parse (with the line); unknown sections
and keys (the known ones listed); wrong types (a string where a number belongs, a float node
id, a number where true/false belongs); values out of range; and the cross-field checks: the two
axes on different node ids, neither the sensor board's; ``min_rad < max_rad`` and a joint
range that holds float32 motor positions; ``stale_heartbeat_periods >= silence_periods``; a
node-silence timeout (``heartbeat_period_s * silence_periods``) between 5 control periods and
:data:`MAX_SILENCE_TIMEOUT_S`; at least :data:`MIN_COMMANDS_PER_WATCHDOG` commands per driver
watchdog timeout; a standard CAN bit rate with room for the loop's frames
(:data:`MAX_BUS_LOAD`); the CPG's burst bounds; ``health.min_bus_voltage_v <
health.max_bus_voltage_v``; the encoder's cells within its range and its
range within the range filter's; a leg long enough to reach the ground; ``controller.auto_arm``
only on a simulated bus; on a real bus, the keys of :data:`REAL_BUS_REQUIRED` given in the file.

The sensor board's node id is not a setting: it is the bus contract's
(:data:`protocol.SENSOR_BOARD_NODE_ID`).

Relative paths (``[weights] path``, ``[service] control_socket``) are taken relative to the
configuration file's folder, ``~`` expanded, and stored absolute. :func:`to_toml` writes a configuration back (a small emitter for this schema: tables
of scalars and one array); :func:`write_config` writes a file and checks that it reads back to
the same configuration.

TOML is read with the standard library's ``tomllib`` (Python 3.11+) or, on Python 3.10, with
``tomli``, the package ``tomllib`` was taken from.
"""

from __future__ import annotations

import dataclasses
import datetime
import logging
import os
import re
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, TextIO

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10: the same parser, as a package
    import tomli as tomllib  # type: ignore[no-redef]

from can.interfaces import VALID_INTERFACES

from controller.atomic import write_text_atomic
from controller.config import ControllerConfig
from controller.errors import InputError
from controller.io.axis import AxisConfig, float32_target_bounds_rev
from controller.motion.kinematics import REACH
from controller.settings.schema import (Setting, _num, _show, check_settings, setting, settings_of, toml_string,
                                       toml_value)
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


@dataclass(frozen=True)
class BusSettings:
    """The CAN bus, as python-can opens it: by default Linux SocketCAN's ``can0`` (a USB-CAN
    adapter or a CAN HAT; ``vcan0`` for the simulated leg). Interfaces that set the bit rate
    (pcan, kvaser, slcan, gs_usb, ...) are given it; for SocketCAN it is set on the link (``ip link
    set can0 type can bitrate 1000000``) and must match the drivers' ``can.config.baud_rate``.
    """

    interface: str = setting("socketcan", doc="python-can interface", choices=tuple(sorted(VALID_INTERFACES)))
    channel: str = setting("can0", doc="bus channel, e.g. can0 or vcan0", check=_check_channel)
    bitrate: int = setting(1_000_000, "bit/s (a standard CAN rate)", 10_000, 1_000_000,
                           "CAN bit rate, the drivers' can.config.baud_rate", choices=STANDARD_BITRATES)

    def __post_init__(self) -> None:
        check_settings(self, "bus")

    def can_kwargs(self) -> dict[str, Any]:
        """Keyword arguments for :class:`can.Bus`."""
        return {"interface": self.interface, "channel": self.channel, "bitrate": self.bitrate}


@dataclass(frozen=True)
class DriverSettings:
    """What the motor drivers are configured with.

    ``watchdog_timeout_s``: an axis that hears no command for this long disarms (IDLE,
    WATCHDOG_TIMER_EXPIRED). ODrive's ``axis.config.watchdog_timeout`` (enabled with
    ``axis.config.enable_watchdog``, set with odrivetool). The controller writes this value to
    every axis through RxSdo at arming and checks it back through TxSdo (a mismatch or no answer
    is a latched fault; the endpoint ids are in :mod:`protocol.endpoints`, marked unverified), and
    checks its own command period against it (at least :data:`MIN_COMMANDS_PER_WATCHDOG` commands
    per timeout). The default is the simulated drivers'.
    """

    watchdog_timeout_s: float = setting(0.1, "s", 0.005, 1.0, "the drivers' command watchdog "
                                        "(ODrive axis.config.watchdog_timeout; written by RxSdo at arming)")

    def __post_init__(self) -> None:
        check_settings(self, "drivers")


@dataclass(frozen=True)
class WeightsSettings:
    """Where the learned weights live.

    ``path``: the weights file (``.npz``, :mod:`controller.stepping.weights`), resumed from at start
    (else its ``.prev`` copy, else zeros) and saved while walking and at exit; ``""``: not
    persisted. ``~`` is expanded; a relative path is relative to the configuration file's folder.
    ``save_every_s``: saved after this much walking only if the weights changed.
    ``generations``: how many good files are kept, the newest first (``FILE``, ``FILE.prev``,
    ``FILE.prev2``, ...).
    """

    path: str = setting("", doc="the learned weights' .npz file; \"\" = not persisted", check=_check_weights_path)
    save_every_s: float = setting(10.0, "s", 0.1, 86400.0, "save after this much walking, if they changed")
    generations: int = setting(3, "(files)", 1, 100, "good weight files kept: FILE, FILE.prev, FILE.prev2, ...")

    def __post_init__(self) -> None:
        check_settings(self, "weights")


SIM_CHANNEL_PREFIX = "vcan"
"""A ``bus.channel`` starting with this is a virtual SocketCAN link: a simulated leg."""

UNIX_SOCKET_PATH_MAX = 107
"""The longest path a Unix socket can be bound to on Linux [bytes] (``sun_path`` is 108 with the NUL)."""

_GROUP_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_.-]{0,31}\$?")


def _check_socket_path(text: str) -> str | None:
    if not text or text != text.strip() or "\x00" in text or "\n" in text:
        return "must be a file path for the control socket (e.g. \"/run/elegant-stepping/control.sock\")"
    if len(os.fsencode(text)) > UNIX_SOCKET_PATH_MAX:
        return f"must be at most {UNIX_SOCKET_PATH_MAX} bytes long (a Unix socket's path)"
    return None


def _check_group(text: str) -> str | None:
    if text and not _GROUP_NAME.fullmatch(text):
        return "must be a group name (letters, digits, _ . -; at most 32) or \"\" for the daemon's own group"
    return None


def _check_one_line(text: str) -> str | None:
    if "\n" in text or "\r" in text or "\x00" in text:
        return "must be one line"
    return None


def _check_utc_time(text: str) -> str | None:
    if not text:
        return None
    import datetime

    try:
        when = datetime.datetime.fromisoformat(text.replace("Z", "+00:00"))
    except ValueError:
        return "must be an ISO 8601 time (e.g. \"2025-01-31T12:00:00Z\") or \"\""
    if when.tzinfo is None or when.utcoffset() != datetime.timedelta(0):
        return "must be a UTC time (ending in Z or +00:00)"
    return None


@dataclass(frozen=True)
class ServiceSettings:
    """The daemon as a service (systemd).

    ``control_socket``: the Unix socket a person's ``elegant-stepping-leg status|arm|disarm|estop|
    clear-faults`` talks to (mode 0660); the unit's ``RuntimeDirectory=elegant-stepping`` makes
    ``/run/elegant-stepping``. ``~`` is expanded; a relative path is relative to the configuration
    file's folder (like the weights'). ``control_group``: the group allowed to command the daemon
    (the socket's group); ``""``: the daemon's own. ``records_max_bytes``, ``records_keep``: the
    daemon's records file is rotated at this size, this many old ones kept.
    """

    control_socket: str = setting("/run/elegant-stepping/control.sock",
                                  doc="the control socket (Unix); a relative path is beside this file",
                                  check=_check_socket_path)
    control_group: str = setting("", doc="the group allowed to command the daemon; \"\" = the daemon's own group",
                                 check=_check_group)
    records_max_bytes: int = setting(50_000_000, "bytes", 10_000, 10**12, "rotate the daemon's records at this size")
    records_keep: int = setting(3, "(files)", 0, 1000, "rotated records files kept")

    def __post_init__(self) -> None:
        check_settings(self, "service")


@dataclass(frozen=True)
class CalibrationSettings:
    """Whether a person confirmed this leg's calibration (``[axes.*]``: node ids, gear ratios,
    directions, zero offsets, joint limits) after a bring-up that passed on it.

    Written by ``elegant-stepping-leg config confirm FILE --bringup REPORT.json`` (which checks the
    report), never assumed: a configuration that is not confirmed is never armed
    (:meth:`DeployConfig.armable_reason`). ``confirmed_at``: when (UTC, ISO 8601); ``bringup``:
    one line, the bring-up report's summary, its file and time.
    """

    confirmed: bool = setting(False, doc="a person confirmed the calibration after a bring-up that passed "
                                         "(elegant-stepping-leg config confirm)")
    confirmed_at: str = setting("", doc="when it was confirmed (UTC, ISO 8601)", check=_check_utc_time)
    bringup: str = setting("", doc="the bring-up it was confirmed on: summary, report file, time",
                           check=_check_one_line)

    def __post_init__(self) -> None:
        check_settings(self, "calibration")


@dataclass(frozen=True)
class DeployConfig:
    """Everything the controller daemon needs to run a leg.

    Attributes:
        bus: the CAN bus (:class:`BusSettings`).
        controller: the controller, axes and model (:class:`~controller.config.ControllerConfig`).
        drivers: what the drivers are configured with (:class:`DriverSettings`).
        weights: where the learned weights live (:class:`WeightsSettings`).
        service: the control socket and the records' rotation (:class:`ServiceSettings`).
        calibration: whether a person confirmed the calibration (:class:`CalibrationSettings`).
        source: the file it was read from, for messages (not compared).
    """

    bus: BusSettings = BusSettings()
    controller: ControllerConfig = field(default_factory=ControllerConfig)
    drivers: DriverSettings = DriverSettings()
    weights: WeightsSettings = WeightsSettings()
    service: ServiceSettings = ServiceSettings()
    calibration: CalibrationSettings = CalibrationSettings()
    source: str = field(default="", compare=False)
    """The file it was read from ("" if none): named in messages, not part of the configuration."""

    @property
    def weights_file(self) -> str | None:
        """The weights file, or None when the weights are not persisted."""
        return self.weights.path or None

    @property
    def simulated_bus(self) -> bool:
        """True on a simulated bus: python-can's ``virtual`` interface or a ``vcan*`` channel."""
        return is_simulated_bus(self.bus.interface, self.bus.channel)

    def armable_reason(self) -> str | None:
        """None if this configuration may be armed, else why not (one line): its calibration was
        not confirmed by a person after a bring-up that passed (``config confirm``)."""
        if self.calibration.confirmed:
            return None
        file = self.source or "FILE"
        return (f"calibration not confirmed: run `elegant-stepping-leg bringup --config {file} --json report.json` "
                f"on the leg, then `elegant-stepping-leg config confirm {file} --bringup report.json`")


def is_simulated_bus(interface: str, channel: str) -> bool:
    """A simulated bus: python-can's ``virtual`` interface, or a channel named ``vcan*``."""
    return interface == "virtual" or str(channel).startswith(SIM_CHANNEL_PREFIX)


class ConfigError(InputError):
    """A configuration with problems (an :class:`~controller.errors.InputError`: exit 3).
    ``problems``: one line each, every one naming its field; ``source``: the file (or
    ``"<config>"``). ``str()`` is every problem on its own line, each prefixed with the source."""

    def __init__(self, problems: list[str], source: str | os.PathLike = "<config>") -> None:
        self.problems = list(problems)
        self.source = str(source)
        super().__init__("\n".join(self.lines()))

    def lines(self) -> list[str]:
        return [f"{self.source}: {p}" for p in self.problems]

    def reported(self, stream: TextIO | None = None) -> InputError:
        """What a command raises for this error: with one problem, itself (one line); with
        several, each is printed on its own line to ``stream`` (stderr) and the error returned is
        one line counting them."""
        if len(self.problems) <= 1:
            return self
        for line in self.lines():
            print(line, file=sys.stderr if stream is None else stream)
        return InputError(f"{self.source}: {len(self.problems)} problems in the configuration (each on its own "
                          "line above)")


# ----------------------------------------------------------------------------- the schema
# Every key, its kind, unit, range and comment: the dataclasses' own declarations
# (controller.settings.schema.setting), section by section.
_BASE = ControllerConfig()

BUS = settings_of(BusSettings)
CONTROLLER = settings_of(ControllerConfig)  # its scalar fields; sensor_node_id is the bus contract's
AXIS = settings_of(AxisConfig)  # all but the name, which is the section's
DRIVERS = settings_of(DriverSettings)
WEIGHTS = settings_of(WeightsSettings)
SERVICE = settings_of(ServiceSettings)
CALIBRATION = settings_of(CalibrationSettings)
MODEL: dict[str, tuple[Setting, ...]] = {
    section: settings_of(type(getattr(_BASE, section)))
    for section in ("cpg", "gait", "geometry", "learner", "encoder", "range_filter", "reflexes", "height", "health")
}

AXIS_NAMES = ("hip", "knee")

SECTIONS: dict[str, tuple[Setting, ...]] = {
    "bus": BUS,
    "controller": CONTROLLER,
    **{f"axes.{name}": AXIS for name in AXIS_NAMES},
    "drivers": DRIVERS,
    "weights": WEIGHTS,
    "service": SERVICE,
    "calibration": CALIBRATION,
    **MODEL,
}
"""Every section, in the order ``config show`` writes them, with its settings."""

_SETTING = {section: {s.key: s for s in settings} for section, settings in SECTIONS.items()}

REAL_BUS_REQUIRED: dict[str, tuple[str, ...]] = {
    "bus": ("interface", "channel", "bitrate"),
    **{f"axes.{name}": ("node_id", "gear_ratio", "direction", "zero_offset_rev", "min_rad", "max_rad")
       for name in AXIS_NAMES},
}
"""The keys a configuration for a real bus must give itself (no default is a real leg's)."""


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
        "service": _fields(config.service, SERVICE),
        "calibration": _fields(config.calibration, CALIBRATION),
    }
    for section, settings in MODEL.items():
        tables[section] = _fields(getattr(ctl, section), settings)
    return tables


def _build(tables: Tables, source: str = "") -> DeployConfig:
    base = ControllerConfig()
    axes = tuple(AxisConfig(name=name, **tables[f"axes.{name}"]) for name in AXIS_NAMES)
    model = {section: dataclasses.replace(getattr(base, section), **tables[section]) for section in MODEL}
    controller = dataclasses.replace(base, axes=axes, **tables["controller"], **model)
    return DeployConfig(bus=BusSettings(**tables["bus"]), controller=controller,
                        drivers=DriverSettings(**tables["drivers"]), weights=WeightsSettings(**tables["weights"]),
                        service=ServiceSettings(**tables["service"]),
                        calibration=CalibrationSettings(**tables["calibration"]), source=source)


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
        node = _SETTING[hip.rsplit(".", 1)[0]]["node_id"]
        problems.append(f"{hip} = {v(hip)} and {knee} = {v(knee)}: the two axes need different CAN node ids "
                        f"({_num(node.lo)}..{_num(node.hi)}, not {SENSOR_BOARD_NODE_ID})")
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
    for first, then, what in (("gait.tuck_from_amplitude", "gait.tuck_full_amplitude", "above"),
                              ("gait.tuck_forward_phase", "gait.tuck_land_phase", "after"),
                              ("gait.tuck_rise_phase", "gait.tuck_descend_phase", "after")):
        if ok(first, then) and not v(first) < v(then):  # GaitConfig's own checks, named here
            problems.append(f"{then} = {_show(v(then))} must be {what} {first} = {_show(v(first))}")
    vmin, vmax = "health.min_bus_voltage_v", "health.max_bus_voltage_v"
    if ok(vmin, vmax) and not v(vmin) < v(vmax):  # HealthConfig's own check, named here
        problems.append(f"{vmin} = {_show(v(vmin))} V must be below {vmax} = {_show(v(vmax))} V")
    width, enc_range, filt_range = "encoder.cell_width_m", "encoder.max_range_m", "range_filter.max_range_m"
    if ok(width, enc_range) and v(width) > v(enc_range):
        problems.append(f"{width} = {_show(v(width))} m must be at most {enc_range} = {_show(v(enc_range))} m")
    if ok(enc_range, filt_range) and v(enc_range) > v(filt_range):
        problems.append(f"{enc_range} = {_show(v(enc_range))} m must be at most {filt_range} = "
                        f"{_show(v(filt_range))} m (cells beyond the filtered range are never active)")
    reach = ("geometry.thigh_m", "geometry.shank_m", "geometry.hip_height_m", "geometry.foot_radius_m",
             "gait.stance_press_m")
    if ok(*reach):
        leg_m = REACH * (v("geometry.thigh_m") + v("geometry.shank_m"))  # the kinematics' reach
        down_m = v("geometry.hip_height_m") - v("geometry.foot_radius_m") + v("gait.stance_press_m")
        if down_m > leg_m:
            problems.append(f"geometry.hip_height_m - geometry.foot_radius_m + gait.stance_press_m = {_num(down_m)} m: "
                            f"the stance foot cannot reach the ground with geometry.thigh_m + geometry.shank_m = "
                            f"{_num(leg_m / REACH)} m")


def validate_tables(data: Mapping[str, Any]) -> tuple[Tables, list[str]]:
    """Check a parsed TOML document against :data:`SECTIONS` and the cross-field checks: (every
    section's values, the defaults for what it leaves out; every problem found)."""
    problems: list[str] = []
    tables = config_tables(DeployConfig())
    bad: set[str] = set()
    given: set[str] = set()
    for section, values in _sections_given(data, problems).items():
        known = _SETTING[section]
        for key, value in values.items():
            dotted = f"{section}.{key}"
            given.add(dotted)
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
    _real_bus_checks(tables, bad, given, problems)
    return tables, problems


def _bus_words(t: Tables) -> str:
    return f"bus.interface = {_show(t['bus']['interface'])}, bus.channel = {_show(t['bus']['channel'])}"


def _real_bus_checks(t: Tables, bad: set[str], given: set[str], problems: list[str]) -> None:
    """On a real bus (not ``virtual``, channel not ``vcan*``): ``controller.auto_arm`` refused, and
    every key of :data:`REAL_BUS_REQUIRED` given in the file (the defaults are the simulated leg's)."""
    if "bus.interface" in bad or "bus.channel" in bad or is_simulated_bus(t["bus"]["interface"], t["bus"]["channel"]):
        return
    n_given = len({"bus.interface", "bus.channel"} & given)
    defaults = ("", ", partly the defaults", ", the defaults")[2 - n_given]
    if t["controller"].get("auto_arm") is True and "controller.auto_arm" not in bad:
        problems.append(f"controller.auto_arm = true with {_bus_words(t)}{defaults and f' ({defaults[2:]})'}: a leg arms by itself only on a "
                        f"simulated bus (bus.interface \"virtual\" or a bus.channel starting with "
                        f"\"{SIM_CHANNEL_PREFIX}\"); on a real leg a person arms it (`elegant-stepping-leg arm`): "
                        "set auto_arm = false")
    for section, keys in REAL_BUS_REQUIRED.items():
        missing = [k for k in keys if f"{section}.{k}" not in given]
        if not missing:
            continue
        if section == "bus" and len(missing) == len(keys):
            problems.append(f"[bus]: missing; without it the bus is {_bus_words(t)}, a real CAN bus: give [bus] "
                            f"{', '.join(keys)} in the file (a simulated leg: interface \"virtual\" or a "
                            f"\"{SIM_CHANNEL_PREFIX}*\" channel)")
            continue
        what = "every axis's" if section.startswith("axes.") else "its"
        problems.append(f"[{section}] {', '.join(missing)}: not given; on a real CAN bus ({_bus_words(t)}{defaults}) "
                        f"the file must give {what} {', '.join(keys)} itself (the defaults are the simulated leg's, "
                        "never a real leg's calibration: docs/deploy.md, section 3)")


MAX_NESTING = 16
"""The deepest nesting of tables and arrays :func:`config_from_dict` looks into (a configuration
has at most three: ``axes``, ``hip``, a value); deeper is refused before validation, whose
messages and checks recurse."""


def _too_deep(data: Any, limit: int = MAX_NESTING) -> str | None:
    """The dotted path of the first value nested deeper than ``limit`` tables and arrays in
    ``data``, or None; iterative, so no depth can exhaust Python's recursion."""
    stack: list[tuple[Any, str, int]] = [(data, "", 0)]
    while stack:
        value, where, depth = stack.pop()
        if isinstance(value, Mapping):
            items = [(str(k), v) for k, v in value.items()]
        elif isinstance(value, (list, tuple)):
            items = [(f"[{i}]", v) for i, v in enumerate(value)]
        else:
            continue
        if depth >= limit:
            return where or "the document"
        for key, v in items:
            stack.append((v, f"{where}{key}" if key.startswith("[") or not where else f"{where}.{key}", depth + 1))
    return None


def config_from_dict(data: Mapping[str, Any], source: str | os.PathLike = "<config>",
                     base_dir: str | os.PathLike | None = None) -> DeployConfig:
    """The configuration a parsed TOML document describes, defaults for what it leaves out.
    ``base_dir``: relative paths (the weights', the control socket's) are taken relative to it
    (and stored absolute).
    Raises :class:`ConfigError` with every problem found (a document nested deeper than
    :data:`MAX_NESTING` with that one problem)."""
    deep = _too_deep(data)
    if deep is not None:
        raise ConfigError([f"{deep}: nested more than {MAX_NESTING} tables or arrays deep: not a configuration (it "
                           "is tables of keys and values)"], source)
    tables, problems = validate_tables(data)
    if not problems:
        for section, key in (("weights", "path"), ("service", "control_socket")):
            tables[section][key] = _beside(tables[section][key], base_dir)
        socket_path = tables["service"]["control_socket"]
        if len(os.fsencode(socket_path)) > UNIX_SOCKET_PATH_MAX:
            problems.append(f"service.control_socket = {_show(socket_path)} (taken beside the file): "
                            f"{len(os.fsencode(socket_path))} bytes, a Unix socket's path has at most "
                            f"{UNIX_SOCKET_PATH_MAX}: give a shorter or absolute path")
    if not problems:
        try:
            return _build(tables, "" if source == "<config>" else str(source))
        except ValueError as exc:  # a check of the dataclasses this schema does not make itself (a bug)
            problems.append(str(exc))
    raise ConfigError(problems, source)


def _beside(path: str, base_dir: str | os.PathLike | None) -> str:
    """``path`` with ``~`` expanded and, if relative and ``base_dir`` is given, taken relative to
    it (absolute); ``""`` stays ``""``."""
    path = os.path.expanduser(path)
    if path and base_dir is not None and not os.path.isabs(path):
        path = os.path.normpath(os.path.join(os.path.abspath(base_dir), path))
    return path


_AT_LINE = re.compile(r"at line (\d+), column (\d+)")


def config_from_toml(text: str, source: str | os.PathLike = "<config>",
                     base_dir: str | os.PathLike | None = None) -> DeployConfig:
    """The configuration in TOML ``text`` (see :func:`config_from_dict`). Whatever the parser
    refuses is one :class:`ConfigError` naming the source: malformed TOML (with the line), a
    document nested deeper than the parser's recursion allows (``tomllib`` raises ``RecursionError``
    near 300-500 levels: no configuration is nested more than two), an integer longer than Python
    converts (4300 digits)."""
    try:
        data = tomllib.loads(text)
    except RecursionError:
        raise ConfigError(["not a configuration: TOML nested too deeply to read (arrays or tables inside each "
                           "other hundreds of times; a configuration is tables of keys and values)"], source) from None
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
    except ValueError as exc:  # what tomllib passes on from int() or datetime (an integer of 5000 digits)
        raise ConfigError([f"not valid TOML: {' '.join(str(exc).split())}"], source) from None
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
    return write_text_atomic(path, text)


def summary(config: DeployConfig) -> str:
    """One line: the bus, the axes, the rate, the watchdog, the weights."""
    bus, ctl = config.bus, config.controller

    def axis(a: AxisConfig) -> str:
        return (f"{a.name} node {a.node_id} ({_num(a.gear_ratio)}:1, direction {a.direction:+d}, "
                f"[{_num(a.min_rad)}, {_num(a.max_rad)}] rad, {_num(a.current_limit_a)} A, "
                f"{_num(a.vel_limit_rev_s)} rev/s)")

    weights = config.weights_file or "not persisted"
    confirmed = (f"calibration confirmed {config.calibration.confirmed_at}".rstrip() if config.calibration.confirmed
                 else "calibration NOT confirmed")
    return (f"{bus.interface} {bus.channel} at {bus.bitrate} bit/s; {', '.join(axis(a) for a in ctl.axes)}; "
            f"{_num(ctl.rate_hz)} Hz, watchdog {_num(config.drivers.watchdog_timeout_s)} s; weights {weights}; "
            f"{confirmed}")


# ----------------------------------------------------------------------------- confirming the calibration
class ConfirmRefused(InputError):
    """``config confirm`` refused: one line saying why and what to do (exit 3: the report or the
    file is the input to fix)."""


def bringup_report_problem(config: DeployConfig, report: Any, report_name: str) -> str | None:
    """Why the bring-up report ``report`` (its JSON, :meth:`controller.bringup.procedure.BringupReport.to_dict`)
    cannot confirm ``config``'s calibration, or None: it must be a bring-up report that passed, with
    its moves done (not ``--no-move``), for the same axes on the same node ids."""
    keys = ("channel", "passed", "summary", "items", "axes")
    if not isinstance(report, dict) or any(k not in report for k in keys) or not isinstance(report["axes"], dict) \
            or not isinstance(report["items"], list):
        return (f"{report_name} is not a bring-up report (a JSON object with {', '.join(keys)}): write one with "
                f"`elegant-stepping-leg bringup --config FILE --json {report_name}`")
    if report["passed"] is not True:
        return (f"{report_name}: the bring-up did not pass ({report['summary']}): fix what failed, run it again, "
                "then confirm")
    ours = {a.name: a.node_id for a in config.controller.axes}
    theirs = {name: (info.get("node_id") if isinstance(info, dict) else None) for name, info in report["axes"].items()}
    if ours != theirs:
        def show(d: dict) -> str:
            return ", ".join(f"{n} node {i}" for n, i in sorted(d.items()))
        return (f"{report_name} is a bring-up of {show(theirs) or 'no axis'}, this configuration has {show(ours)}: "
                "run the bring-up with this configuration (--config FILE)")
    items = {i.get("name"): i.get("status") for i in report["items"] if isinstance(i, dict)}
    for name in ours:
        for item in (f"{name}: position", f"{name}: move", f"{name}: move back"):
            if items.get(item) != "PASS":
                status = items.get(item, "absent")
                return (f"{report_name}: item '{item}' is {status}, not PASS: a calibration is confirmed on a bring-up "
                        "that checked every axis's position and moved it (without --no-move)")
    return None


def _calibration_text(cal: CalibrationSettings) -> dict[str, str]:
    return {s.key: toml_value(getattr(cal, s.key)) for s in CALIBRATION}


_HEADER = re.compile(r"^\s*\[\s*(?P<name>[^\]\s]+)\s*\]\s*(#.*)?$")
_HEADER_ANY = re.compile(r"^\s*\[")


def with_calibration(text: str, cal: CalibrationSettings) -> str | None:
    """``text`` (a configuration file) with its ``[calibration]`` keys set to ``cal``'s, every other
    line (comments included) as it was; None if the file is not laid out simply enough to edit by
    lines (the caller then writes the whole configuration)."""
    lines = text.splitlines()
    values = _calibration_text(cal)
    start = next((i for i, line in enumerate(lines) if (m := _HEADER.match(line)) and m["name"] == "calibration"), None)
    if start is None:
        block = ["", "[calibration]"] + [f"{k} = {v}" for k, v in values.items()]
        while lines and not lines[-1].strip():
            lines.pop()
        return "\n".join(lines + block) + "\n"
    end = next((i for i in range(start + 1, len(lines)) if _HEADER_ANY.match(lines[i])), len(lines))
    done: set[str] = set()
    for i in range(start + 1, end):
        m = re.match(r"^(\s*)([A-Za-z_]+)\s*=", lines[i])
        if m and m[2] in values:
            if m[2] in done:
                return None
            lines[i] = f"{m[1]}{m[2]} = {values[m[2]]}"
            done.add(m[2])
    extra = [f"{k} = {v}" for k, v in values.items() if k not in done]
    return "\n".join(lines[:start + 1] + extra + lines[start + 1:]) + "\n"


def confirm_calibration(path: str | os.PathLike, report_path: str | os.PathLike,
                        now: "datetime.datetime | None" = None) -> tuple[DeployConfig, Path, bool]:
    """Confirm the calibration in the configuration file ``path`` on the bring-up report
    ``report_path`` (:func:`bringup_report_problem`): ``[calibration] confirmed = true``,
    ``confirmed_at`` (UTC, ISO 8601), ``bringup`` (the report's summary, file and time).

    The file is copied to ``FILE.bak`` first, then written atomically (its mode and owner kept):
    the ``[calibration]`` lines edited in place (every comment kept) where the file allows it,
    else the whole configuration by :func:`to_toml` (the comments then are only in ``FILE.bak``).
    Returns (the configuration written, the backup, whether the comments were kept). Raises
    :class:`ConfirmRefused` (one line) or :class:`ConfigError` (the file's own problems)."""
    import datetime
    import json
    import shutil

    path, report_path = Path(path), Path(report_path)
    config = load_config(path)
    try:
        raw = report_path.read_text(encoding="utf-8")
        report_stat = report_path.stat()
    except OSError as exc:
        raise ConfirmRefused(f"cannot read the bring-up report {report_path}: {exc.strerror or exc} (run "
                             f"`elegant-stepping-leg bringup --config {path} --json {report_path}` on the leg "
                             "first)") from None
    try:
        report = json.loads(raw)
    except ValueError:
        report = None
    problem = bringup_report_problem(config, report, str(report_path))
    if problem:
        raise ConfirmRefused(problem)
    if report_stat.st_mtime < path.stat().st_mtime:
        raise ConfirmRefused(f"{report_path} is older than {path}: the configuration changed after that bring-up; "
                             f"run `elegant-stepping-leg bringup --config {path} --json {report_path}` again")
    now = now or datetime.datetime.now(datetime.timezone.utc)
    stamp = now.astimezone(datetime.timezone.utc).replace(microsecond=0).isoformat().replace("+00:00", "Z")
    report_time = datetime.datetime.fromtimestamp(report_stat.st_mtime, datetime.timezone.utc).replace(
        microsecond=0).isoformat().replace("+00:00", "Z")
    summary_text = " ".join(str(report["summary"]).split())
    cal = CalibrationSettings(confirmed=True, confirmed_at=stamp,
                              bringup=f"{summary_text} on {' '.join(str(report['channel']).split())}: "
                                      f"{report_path.resolve()} ({report_time})")
    expected = dataclasses.replace(config, calibration=cal)
    text = path.read_text(encoding="utf-8")
    edited = with_calibration(text, cal)
    kept = False
    if edited is not None:
        try:
            kept = config_from_toml(edited, path, base_dir=path.parent) == expected
        except ConfigError:
            kept = False
    if not kept:
        edited = to_toml(expected, header=f"elegant-stepping configuration, rewritten by `elegant-stepping-leg config "
                                          f"confirm` at {stamp}\n(the file before, with its comments: {path.name}.bak)")
        if config_from_toml(edited, path) != expected:
            raise ConfigError(["does not read back to the configuration written (a bug in the emitter)"], path)
    backup = path.with_name(path.name + ".bak")
    shutil.copy2(path, backup)
    before = path.stat()
    write_text_atomic(path, edited)
    os.chmod(path, before.st_mode & 0o7777)
    try:
        os.chown(path, before.st_uid, before.st_gid)
    except OSError:  # not ours to give away (not root): the file stays ours, with the same mode
        pass
    log.warning("calibration of %s confirmed on %s (%s)", path, report_path, summary_text)
    return expected, backup, kept


__all__ = [
    "BusSettings", "DriverSettings", "WeightsSettings", "DeployConfig", "ConfigError", "Setting", "SECTIONS",
    "load_config", "config_from_dict", "config_from_toml", "validate_tables", "config_tables", "check_config",
    "to_toml", "toml_string", "toml_value", "write_config", "summary", "ServiceSettings", "CalibrationSettings",
    "REAL_BUS_REQUIRED", "is_simulated_bus", "ConfirmRefused", "bringup_report_problem", "with_calibration",
    "confirm_calibration",
]
