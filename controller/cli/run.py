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

Exit codes (:mod:`controller.errors`; every failure is one line, ``elegant-stepping-leg run: error:
...``, never a traceback unless it is a bug):

==== =============================================================================================
0    stopped as asked (a stop signal, ``--seconds``) with the axes IDLE and the weights saved; also
     after a latched fault, when a stop signal ended the run (the stop was done in order)
1    the learned weights could not be saved at the end (logged; the final record says so)
2    a malformed option (argparse)
3    an input to fix, nothing started: the configuration is missing, unreadable or invalid (every
     problem on its own line, then one line counting them); the weights' folder is not writable;
     an incompatible weights file could not be set aside; the control socket cannot be made
     (already served by another daemon, not a socket, an unknown group, a folder that cannot be
     created); the records or ticks file cannot be written
4    the bus cannot be opened: one line naming the interface, the channel and the system's reason
     (``--channel can9``: no such device; a kernel without SocketCAN: address family not
     supported; ``--interface nosuch``: not one of python-can's), with what to check
5    safety stop: ``--seconds`` ended with the leg stopped by itself (a latched FAULT: an axis
     error, a silent node, an estop). The daemon never exits *because* of a fault (a faulted leg
     holds its axes IDLE and waits for a person, and systemd must not restart it), so 5 comes only
     from a run with ``--seconds`` (tests, the harness)
130  interrupted before the loop began (Ctrl-C during start-up); once running, SIGINT is a stop
     signal like SIGTERM (exit 0)
==== =============================================================================================

The systemd unit (``deploy/elegant-stepping-controller.service``) does not restart after 2, 3 or 6
(``RestartPreventExitStatus``): a restart would not fix them; after 4 it retries (an adapter that
comes up late).
"""

from __future__ import annotations

import argparse
import json
import sys

from controller.cli.common import add_bus_args, positive

EXIT_OK, EXIT_FAILED, EXIT_SAFETY = 0, 1, 5  # controller.errors' codes (imported there inside run)


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
    p.add_argument("--bursts", default=None, metavar="FILE",
                   help="write every tick's clock and CPG burst length here (float64 pairs; for figures)")
    p.add_argument("--clock", choices=("wall", "sim"), default="wall",
                   help="wall: tick at the fixed rate on this machine's clock (a real leg; the default); sim: tick "
                        "once per ES_Sim_Sync frame of a simulated plant, on its simulated time (hil --clock sim; "
                        "refused on a bus that is not vcan or virtual)")


STOPPED_AS_ASKED = ("SIGTERM", "SIGINT", "SIGHUP", "SIGUSR1", "event")


def simulated_bus(bus_kw: dict) -> bool:
    """A bus only a simulated plant can be on: python-can's ``virtual``, or a SocketCAN ``vcan``
    channel. ``--clock sim`` is refused on any other (a real leg runs on the wall clock)."""
    return bus_kw.get("interface") == "virtual" or str(bus_kw.get("channel") or "").startswith("vcan")


def run(args: argparse.Namespace) -> int:
    from controller.daemon.control import DEFAULT_SOCKET
    from controller.daemon.run import run_controller
    from controller.settings.daemon import daemon_settings
    from controller.settings.file import ConfigError

    try:
        d = daemon_settings(args.config, args.interface, args.channel, args.bitrate, args.weights, args.save_every_s)
    except ConfigError as exc:
        raise exc.reported() from None  # exit 3: every problem on its own line, then one line
    if args.clock == "sim" and not simulated_bus(d.bus_kw):
        from controller.errors import UsageError

        raise UsageError(f"--clock sim ticks on a simulated plant's sync frames; the bus {d.bus_kw.get('interface')}:"
                         f"{d.bus_kw.get('channel')} is not a virtual one (vcan*, or python-can's virtual): a real leg "
                         f"runs on the wall clock")
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
        restore_signals=False, sim_time=args.clock == "sim",
        bursts=args.bursts)  # a signal after the stop, while this prints, still changes nothing
    final.pop("weights", None)
    print(json.dumps(final), file=sys.stderr)
    if final["weights_saved"] is False:
        return EXIT_FAILED  # the learned weights could not be saved (logged)
    if final["stopped_by"] in STOPPED_AS_ASKED:
        return EXIT_OK  # a stop asked for, done in order: axes IDLE, weights saved (a fault is in the final record)
    return EXIT_OK if final["phase"] != "fault" else EXIT_SAFETY  # --seconds ended with the leg stopped by itself
