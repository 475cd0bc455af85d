"""``run``: the controller daemon at its fixed rate on a CAN bus (the systemd unit's ``ExecStart``).

The configuration (``--config FILE``, TOML: bus, controller, axes, drivers, weights) with each of
``--interface/--channel/--bitrate``, ``--weights`` and ``--save-every-s`` given on the command
line in its place (:func:`controller.settings.daemon.daemon_settings`); the process itself is
:func:`controller.daemon.run.run_controller`. Its final record goes to stderr as one JSON line.

Exit codes: 0 stopped as asked (SIGTERM, SIGINT, ``--seconds``) with the axes IDLE and the weights
saved; 1 a latched fault or weights that could not be saved; 2 a bad option or configuration.
"""

from __future__ import annotations

import argparse
import json
import sys

from controller.cli.common import add_bus_args, positive


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_bus_args(p)
    p.add_argument("--config", default=None, metavar="FILE",
                   help="the configuration (TOML, see configs/; defaults otherwise): bus, controller, axes, weights")
    p.add_argument("--records", default=None, metavar="FILE", help="write the controller's records here (JSON lines)")
    p.add_argument("--weights", default=None, metavar="FILE",
                   help="resume from these learned weights (else FILE.prev, else zeros) and save them here "
                        "while walking and at exit (.npz; default: the configuration's [weights] path)")
    p.add_argument("--save-every-s", type=positive(float), default=None,
                   help="save the weights every this many seconds of walking, if they changed "
                        "(default: the configuration's [weights] save_every_s, else 10)")
    p.add_argument("--ticks", default=None, metavar="FILE", help="write every tick's clock here (for replay)")
    p.add_argument("--seconds", type=positive(float), default=None, help="stop after this long (default: run)")


def run(args: argparse.Namespace) -> int:
    from controller.daemon.run import run_controller
    from controller.settings.daemon import daemon_settings

    d = daemon_settings(args.config, args.interface, args.channel, args.bitrate, args.weights, args.save_every_s)
    final = run_controller(d.bus_kw, d.controller, records=args.records, weights=d.weights, ticks=args.ticks,
                           duration_s=args.seconds, save_every_s=d.save_every_s)
    final.pop("weights", None)
    print(json.dumps(final), file=sys.stderr)
    if final["weights_saved"] is False:
        return 1  # the learned weights could not be saved (logged)
    if final["stopped_by"] in ("SIGTERM", "SIGINT"):
        return 0  # a stop asked for, done in order: axes IDLE, weights saved (a fault is in the final record)
    return 0 if final["phase"] != "fault" else 1
