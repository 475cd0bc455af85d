"""``firmware-sim``: the simulated leg (plant, drivers, sensor board) on a CAN bus, real time.

``--scenario PATH`` serves the side channel on a Unix socket at PATH; it never removes a file
that is not a socket, nor a socket another process serves (exit 3); a stale socket left by a
killed firmware-sim is replaced (:func:`hil.session.scenario.claim_address`). A bus that cannot be
opened is exit 4, naming ``--interface``/``--channel``.
"""

from __future__ import annotations

import argparse
import json
import sys

from controller.cli.common import add_bus_args, bounded, non_negative, positive


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_bus_args(p)
    p.add_argument("--seed", type=non_negative(int), default=0, help="seed of the sensor noise (default 0)")
    p.add_argument("--gui", action="store_true", help="open PyBullet's window")
    p.add_argument("--scenario", default=None, metavar="ADDR",
                   help="Unix socket for the scenario side channel ('@name': abstract namespace); an existing file "
                        "there is never removed unless it is a stale socket")
    p.add_argument("--range-noise-m", type=non_negative(float), default=None, help="range sensor noise, 1 sigma [m]")
    p.add_argument("--range-dropout-prob", type=bounded(float, 0.0, 1.0), default=None,
                   help="range dropout probability")
    p.add_argument("--seconds", type=positive(float), default=None, help="stop after this much time (default: run)")
    p.add_argument("--steps-per-wake", type=positive(int), default=None,
                   help="physics steps per wake-up (default 1; 2 inside User-Mode Linux)")
    p.add_argument("--clock", choices=("wall", "sim"), default="wall",
                   help="wall: physics paced to this machine's clock (the default); sim: simulated time, stepping "
                        "when the controller has answered each period's sync, the trials of a learning run "
                        "requested on --scenario (hil --clock sim)")


def run(args: argparse.Namespace) -> int:
    from controller.settings.daemon import bus_kwargs
    from hil.session.firmware import run_firmware
    from hil.session.scenario import claim_address

    if args.clock == "sim" and args.scenario is None:
        from controller.errors import UsageError

        raise UsageError("--clock sim needs --scenario: the learning run is requested on the side channel")
    if args.scenario is not None:
        claim_address(args.scenario)  # before the plant loads: a bad address is refused at once
    if args.clock == "sim":
        from hil.session.simplant import run_sim_plant

        final = run_sim_plant(bus_kwargs(args.interface, args.channel, args.bitrate), scenario=args.scenario,
                              gui=args.gui)
        print(json.dumps({k: final.get(k) for k in ("t_s", "axes", "host", "sync")}), file=sys.stderr)
        return 0
    final = run_firmware(bus_kwargs(args.interface, args.channel, args.bitrate), seed=args.seed, gui=args.gui,
                         scenario=args.scenario, range_noise_m=args.range_noise_m,
                         range_dropout_prob=args.range_dropout_prob, duration_s=args.seconds,
                         steps_per_wake=args.steps_per_wake)
    print(json.dumps({k: final[k] for k in ("t_s", "axes", "watchdog_trips", "host", "pacing")}), file=sys.stderr)
    return 0
