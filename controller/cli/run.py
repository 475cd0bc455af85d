"""``run``: the controller daemon at its fixed rate on a CAN bus (the systemd unit's ``ExecStart``).

The configuration (``--config FILE``, TOML: bus, controller, axes, drivers, weights, service,
calibration) with each of ``--interface/--channel/--bitrate``, ``--weights``, ``--save-every-s``
and ``--socket`` given on the command line in its place
(:func:`controller.settings.daemon.daemon_settings`); the process itself is
:func:`controller.daemon.run.run_controller`. Its final record goes to stderr as one JSON line.

The daemon starts **inactive**: it waits for its nodes, then for ``elegant-stepping-leg arm`` on
its control socket (``--socket``, else the configuration's ``[service] control_socket``, else
``/run/elegant-stepping/control.sock``; ``--socket none``: no socket), unless the configuration
says ``[controller] auto_arm`` (a simulated bus only). An unconfirmed calibration blocks ``arm``.

Signals: SIGTERM, SIGINT, SIGHUP and SIGUSR1 all stop it the same way (axes IDLE, the weights
saved if they changed, the final record, exit 0); SIGHUP does not reload the configuration (a
change needs a restart, on purpose); a second signal during the stop changes nothing.

Exit codes: 0 stopped as asked (a stop signal, ``--seconds``) with the axes IDLE and the weights
saved; 1 a latched fault at the end of ``--seconds``, or weights that could not be saved; 2 a bad
option or configuration, or a refusal to start (one line: the weights' folder not writable, the
control socket already served or not creatable, an incompatible weights file that could not be set
aside).
"""

from __future__ import annotations

import argparse
import json
import sys

from controller.cli.common import add_bus_args, positive


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_bus_args(p)
    p.add_argument("--config", default=None, metavar="FILE",
                   help="the configuration (TOML, see configs/; defaults otherwise): bus, controller, axes, weights, "
                        "service, calibration")
    p.add_argument("--records", default=None, metavar="FILE",
                   help="write the controller's records here (JSON lines; rotated at [service] records_max_bytes, "
                        "FILE the newest)")
    p.add_argument("--weights", default=None, metavar="FILE",
                   help="resume from these learned weights (else FILE.prev, FILE.prev2, ..., else zeros) and save them "
                        "here while walking and at exit, if they changed (.npz; default: the configuration's [weights] "
                        "path)")
    p.add_argument("--save-every-s", type=positive(float), default=None,
                   help="save the weights every this many seconds of walking, if they changed "
                        "(default: the configuration's [weights] save_every_s, else 10)")
    p.add_argument("--ticks", default=None, metavar="FILE",
                   help="write every tick's clock here (for replay; rotated like the records)")
    p.add_argument("--socket", default=None, metavar="PATH",
                   help="the control socket (default: the configuration's [service] control_socket, else "
                        "/run/elegant-stepping/control.sock); 'none': no control socket")
    p.add_argument("--seconds", type=positive(float), default=None, help="stop after this long (default: run)")


STOPPED_AS_ASKED = ("SIGTERM", "SIGINT", "SIGHUP", "SIGUSR1", "event")


def run(args: argparse.Namespace) -> int:
    from controller.daemon.control import DEFAULT_SOCKET
    from controller.daemon.run import run_controller
    from controller.settings.daemon import daemon_settings

    d = daemon_settings(args.config, args.interface, args.channel, args.bitrate, args.weights, args.save_every_s)
    service = getattr(d.config, "service", None)
    if args.socket is not None:
        socket_path = None if args.socket.strip().lower() in ("", "none") else args.socket
    else:
        socket_path = service.control_socket if service is not None else DEFAULT_SOCKET
    weights_cfg = getattr(d.config, "weights", None)
    final = run_controller(
        d.bus_kw, d.controller, records=args.records, weights=d.weights, ticks=args.ticks, duration_s=args.seconds,
        save_every_s=d.save_every_s, deploy=d.config, control_socket=socket_path,
        control_group=service.control_group if service is not None else "",
        records_max_bytes=service.records_max_bytes if service is not None else None,
        records_keep=service.records_keep if service is not None else 3,
        weights_generations=getattr(weights_cfg, "generations", 3),
        restore_signals=False)  # a signal after the stop, while this prints, still changes nothing
    final.pop("weights", None)
    print(json.dumps(final), file=sys.stderr)
    if final["weights_saved"] is False:
        return 1  # the learned weights could not be saved (logged)
    if final["stopped_by"] in STOPPED_AS_ASKED:
        return 0  # a stop asked for, done in order: axes IDLE, weights saved (a fault is in the final record)
    return 0 if final["phase"] != "fault" else 1
