"""``bringup``: the bring-up checklist against real nodes on a CAN bus.

Loads the axes' configuration and the bus settings as the daemon does
(:func:`controller.settings.daemon.daemon_settings`: ``--config FILE``, the command line's
``--interface/--channel/--bitrate`` over the file's ``[bus]``, without a file python-can's own
configuration), opens the bus, runs :func:`controller.bringup.procedure.run_bringup` on
the monotonic clock, prints one line per item and a summary, and writes the report as JSON with
``--json FILE``.

Exit codes: 0 every item passed (warnings and skipped items allowed), 1 an item failed (or
Ctrl-C: the axis being moved is sent IDLE first), 2 a usage or configuration error, 3 the bus
could not be opened. Bring-up is for real hardware: it runs where it is started, never inside
User-Mode Linux by itself (the ``vcan`` test starts it there with ``firmware-sim``).
"""

from __future__ import annotations

import argparse
import logging
import sys
from typing import Any

log = logging.getLogger(__name__)

EXIT_OK, EXIT_FAILED, EXIT_USAGE, EXIT_NO_BUS = 0, 1, 2, 3


def open_bus(bus_kw: dict[str, Any]):
    """(python-can bus, the lean front the procedure uses, channel name), or raises what python-can raised."""
    import can

    from controller.daemon.fastbus import lean

    raw = can.Bus(**bus_kw)
    channel = str(bus_kw.get("channel") or getattr(raw, "channel_info", None) or getattr(raw, "channel", "the bus"))
    return raw, lean(raw, timestamps=False), channel


def run(args: argparse.Namespace) -> int:
    from controller.bringup.procedure import run_bringup
    from controller.cli.common import write_json

    from controller.settings.daemon import daemon_settings
    from controller.settings.file import ConfigError

    try:
        settings = daemon_settings(args.config, args.interface, args.channel, args.bitrate)
    except ConfigError as exc:
        for line in exc.lines():
            print(line, file=sys.stderr)
        print(f"bringup: configuration error in {exc.source}", file=sys.stderr)
        return EXIT_USAGE
    config = settings.controller
    try:
        raw, bus, channel = open_bus(settings.bus_kw)
    except Exception as exc:  # noqa: BLE001 - python-can raises many kinds; all mean "no bus"
        where = settings.bus_kw.get("channel") or "python-can's configured channel"
        print(f"bringup: cannot open the bus {where!s}: {exc}. Is the interface there and up "
              f"(ip -details link show {where}; ip link set {where} up type can bitrate 1000000)?", file=sys.stderr)
        return EXIT_NO_BUS
    try:
        report = run_bringup(bus, config.axes, sensor_node_id=config.sensor_node_id, channel=channel,
                             move=not args.no_move, clear_errors=args.clear_errors)
    except KeyboardInterrupt:
        print("bringup: interrupted (the axis being moved was sent IDLE)", file=sys.stderr)
        return EXIT_FAILED
    finally:
        raw.shutdown()
    out = sys.stderr if args.json == "-" else sys.stdout
    for line in report.checklist.lines():
        print(line, file=out)
    print(f"bring-up on {channel}: {report.checklist.summary()} ({report.elapsed_s:.1f} s)", file=out)
    if args.json is not None:
        write_json(args.json, report.to_dict())
    return EXIT_OK if report.passed else EXIT_FAILED


def add_arguments(p: argparse.ArgumentParser) -> None:
    from controller.cli.common import add_bus_args

    add_bus_args(p)
    p.add_argument("--config", default=None, metavar="FILE",
                   help="configuration with the axes (node ids, gear ratio, direction, zero offset, joint limits); "
                        "default: the built-in defaults")
    p.add_argument("--no-move", action="store_true", help="only listen and ask: no closed loop, no move")
    p.add_argument("--clear-errors", action="store_true",
                   help="send Clear_Errors to axes with latched errors (after you fixed their cause)")
    p.add_argument("--json", default=None, metavar="FILE", help="also write the report as JSON here ('-': stdout)")
