"""``elegant-stepping bringup``: the bring-up checklist against real nodes on a CAN bus.

Loads the axes' configuration (``--config FILE``: the deployment TOML file, read by
``controller.settings.file.load_config``, imported when it is needed; no ``--config``: the
:class:`ControllerConfig` defaults), opens the bus (``--interface/--channel/--bitrate``, else the
file's ``[bus]`` settings, else python-can's own configuration), runs :func:`controller.bringup.procedure.run_bringup` on
the monotonic clock, prints one line per item and a summary, and writes the report as JSON with
``--json FILE``.

Exit codes: 0 every item passed (warnings and skipped items allowed), 1 an item failed (or
Ctrl-C: the axis being moved is sent IDLE first), 2 a usage or configuration error, 3 the bus
could not be opened. Bring-up is for real hardware: it runs where it is started, never inside
User-Mode Linux by itself (the ``vcan`` test starts it there with ``firmware-sim``).
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from controller.config import ControllerConfig

log = logging.getLogger(__name__)

EXIT_OK, EXIT_FAILED, EXIT_USAGE, EXIT_NO_BUS = 0, 1, 2, 3
_BUS_KEYS = ("interface", "channel", "bitrate")


def _find_controller_config(loaded: Any, path: str) -> ControllerConfig:
    """The ControllerConfig in what ``load_config`` returned (itself, or one of its fields)."""
    from controller.config import ControllerConfig

    if isinstance(loaded, ControllerConfig):
        return loaded
    if dataclasses.is_dataclass(loaded):
        for f in dataclasses.fields(loaded):
            value = getattr(loaded, f.name)
            if isinstance(value, ControllerConfig):
                return value
    raise ValueError(f"{path}: the configuration holds no controller configuration (axes)")


def _bus_settings(loaded: Any) -> dict[str, Any]:
    """interface/channel/bitrate from a deployment config's ``bus`` section, where it has one."""
    bus = getattr(loaded, "bus", None)
    if bus is None:
        return {}
    get = bus.get if isinstance(bus, dict) else (lambda k: getattr(bus, k, None))
    return {k: get(k) for k in _BUS_KEYS if get(k) is not None}


def load_bringup_config(path: str | None) -> tuple[ControllerConfig, dict[str, Any]]:
    """(controller configuration, bus settings from the file) for ``--config``."""
    from controller.config import ControllerConfig

    if path is None:
        return ControllerConfig(), {}
    if not Path(path).exists():
        raise FileNotFoundError(f"{path}: no such configuration file")
    try:
        from controller.settings.file import load_config  # the deployment loader (issue 7), once it exists
    except ModuleNotFoundError as exc:
        if exc.name != "controller.settings.file":
            raise
        load_config = None
    if load_config is None:
        raise ValueError(f"{path}: reading a configuration file needs controller.settings.file (the TOML loader), "
                         "which this build lacks; run without --config for the built-in defaults")
    loaded = load_config(path)
    return _find_controller_config(loaded, path), _bus_settings(loaded)


def open_bus(args: argparse.Namespace, from_file: dict[str, Any]):
    """(bus, channel name) or raises what python-can raised."""
    import can

    from controller.settings.daemon import bus_kwargs
    from controller.daemon.fastbus import lean

    given = {k: getattr(args, k) for k in _BUS_KEYS}
    merged = {k: given[k] if given[k] is not None else from_file.get(k) for k in _BUS_KEYS}
    kw = bus_kwargs(merged["interface"], merged["channel"], merged["bitrate"])
    raw = can.Bus(**kw)
    channel = str(kw.get("channel") or getattr(raw, "channel_info", None) or getattr(raw, "channel", "the bus"))
    return raw, lean(raw, timestamps=False), channel


def main_bringup(args: argparse.Namespace) -> int:
    from controller.bringup.procedure import run_bringup
    from hil.cli.main import _write_json

    try:
        config, from_file = load_bringup_config(args.config)
    except (ValueError, TypeError, FileNotFoundError, OSError) as exc:
        print(f"elegant-stepping bringup: configuration error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    try:
        raw, bus, channel = open_bus(args, from_file)
    except Exception as exc:  # noqa: BLE001 - python-can raises many kinds; all mean "no bus"
        where = args.channel or from_file.get("channel") or "python-can's configured channel"
        print(f"elegant-stepping bringup: cannot open the bus {where!s}: {exc}. Is the interface there and up "
              f"(ip -details link show {where}; ip link set {where} up type can bitrate 1000000)?", file=sys.stderr)
        return EXIT_NO_BUS
    try:
        report = run_bringup(bus, config.axes, sensor_node_id=config.sensor_node_id, channel=channel,
                             move=not args.no_move, clear_errors=args.clear_errors)
    except KeyboardInterrupt:
        print("elegant-stepping bringup: interrupted (the axis being moved was sent IDLE)", file=sys.stderr)
        return EXIT_FAILED
    finally:
        raw.shutdown()
    out = sys.stderr if args.json == "-" else sys.stdout
    for line in report.checklist.lines():
        print(line, file=out)
    print(f"bring-up on {channel}: {report.checklist.summary()} ({report.elapsed_s:.1f} s)", file=out)
    if args.json is not None:
        _write_json(args.json, report.to_dict())
    return EXIT_OK if report.passed else EXIT_FAILED


def add_bringup_args(p: argparse.ArgumentParser) -> None:
    """The options after ``--interface/--channel/--bitrate``."""
    p.add_argument("--config", default=None, metavar="FILE",
                   help="configuration with the axes (node ids, gear ratio, direction, zero offset, joint limits); "
                        "default: the built-in defaults")
    p.add_argument("--no-move", action="store_true", help="only listen and ask: no closed loop, no move")
    p.add_argument("--clear-errors", action="store_true",
                   help="send Clear_Errors to axes with latched errors (after you fixed their cause)")
    p.add_argument("--json", default=None, metavar="FILE", help="also write the report as JSON here ('-': stdout)")
