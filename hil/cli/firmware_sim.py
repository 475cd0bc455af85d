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


def run(args: argparse.Namespace) -> int:
    from controller.settings.daemon import bus_kwargs
    from hil.session.firmware import run_firmware
    from hil.session.scenario import claim_address

    if args.scenario is not None:
        claim_address(args.scenario)  # before the plant loads: a bad address is refused at once
    final = run_firmware(bus_kwargs(args.interface, args.channel, args.bitrate), seed=args.seed, gui=args.gui,
                         scenario=args.scenario, range_noise_m=args.range_noise_m,
                         range_dropout_prob=args.range_dropout_prob, duration_s=args.seconds,
                         steps_per_wake=args.steps_per_wake)
    print(json.dumps({k: final[k] for k in ("t_s", "axes", "watchdog_trips", "host", "pacing")}), file=sys.stderr)
    return 0
