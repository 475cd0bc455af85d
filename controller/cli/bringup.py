"""``bringup``: the bring-up checklist against real nodes on a CAN bus.

Loads the axes' configuration and the bus settings as the daemon does
(:func:`controller.settings.daemon.daemon_settings`: ``--config FILE``, the command line's
``--interface/--channel/--bitrate`` over the file's ``[bus]``, without a file python-can's own
configuration), opens the bus, runs :func:`controller.bringup.procedure.run_bringup` on
the monotonic clock, prints one line per item and a summary, and writes the report as JSON with
``--json FILE``.

Exit codes (:mod:`controller.errors`): 0 every item passed (warnings and skipped items allowed);
1 an item failed (the bus failing during bring-up is a failed item); 2 a malformed option
(argparse); 3 the configuration is missing, unreadable or invalid (each problem on its own line,
then one line), or the report cannot be written; 4 the bus cannot be opened (one line naming the
interface, the channel and the system's reason: :func:`controller.daemon.openbus.open_bus`);
130 Ctrl-C (the axis being moved is sent IDLE first; no report is written). ``--json FILE`` is
checked before the bus is opened (a folder, or under a file: exit 3 at once). Bring-up is for
real hardware: it runs where it is started, never inside User-Mode Linux by itself (the ``vcan``
test starts it there with ``firmware-sim``).
"""

from __future__ import annotations

import argparse
import logging
import sys
from typing import Any

log = logging.getLogger(__name__)

EXIT_OK, EXIT_FAILED = 0, 1  # controller.errors' codes


def open_bus(bus_kw: dict[str, Any]):
    """(python-can bus, the lean front the procedure uses, channel name); raises
    :class:`controller.errors.BusError` (one line, exit 4) when the bus cannot be opened."""
    from controller.daemon.fastbus import lean
    from controller.daemon.openbus import open_bus as open_can

    raw = open_can(bus_kw)
    channel = str(bus_kw.get("channel") or getattr(raw, "channel_info", None) or getattr(raw, "channel", "the bus"))
    return raw, lean(raw, timestamps=False), channel


def check_report_path(path: str) -> None:
    """Refuse (:class:`controller.errors.InputError`, exit 3) a ``--json`` path that cannot be
    written, before anything runs: an existing folder, or a path under a file. Its folder is made."""
    from pathlib import Path

    from controller.errors import InputError

    out = Path(path)
    if out.is_dir():
        raise InputError(f"--json {path}: is a folder; give a file name, e.g. {out / 'report.json'}")
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"--json {path}: its folder cannot be made ({exc.strerror or exc})") from None


def run(args: argparse.Namespace) -> int:
    from controller.bringup.procedure import run_bringup
    from controller.cli.common import write_json

    from controller.settings.daemon import daemon_settings
    from controller.settings.file import ConfigError

    try:
        settings = daemon_settings(args.config, args.interface, args.channel, args.bitrate)
    except ConfigError as exc:
        raise exc.reported() from None  # exit 3: every problem on its own line, then one line
    config = settings.controller
    if args.json not in (None, "-"):
        check_report_path(args.json)
    raw, bus, channel = open_bus(settings.bus_kw)  # BusError: exit 4
    try:
        report = run_bringup(bus, config.axes, sensor_node_id=config.sensor_node_id, channel=channel,
                             move=not args.no_move, clear_errors=args.clear_errors)
    except KeyboardInterrupt:
        log.warning("bring-up interrupted: the axis being moved was sent IDLE; no report written")
        raise  # controller.cli.common.main: one line, exit 130
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
