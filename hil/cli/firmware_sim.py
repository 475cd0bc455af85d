"""``firmware-sim``: the simulated leg (plant, drivers, sensor board) on a CAN bus, real time."""

from __future__ import annotations

import argparse
import json
import sys

from controller.cli.common import add_bus_args, positive


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_bus_args(p)
    p.add_argument("--seed", type=int, default=0, help="seed of the sensor noise (default 0)")
    p.add_argument("--gui", action="store_true", help="open PyBullet's window")
    p.add_argument("--scenario", default=None, metavar="ADDR",
                   help="Unix socket for the scenario side channel ('@name': abstract namespace)")
    p.add_argument("--range-noise-m", type=float, default=None, help="range sensor noise, 1 sigma [m]")
    p.add_argument("--range-dropout-prob", type=float, default=None, help="range dropout probability")
    p.add_argument("--seconds", type=positive(float), default=None, help="stop after this much time (default: run)")
    p.add_argument("--steps-per-wake", type=int, default=None,
                   help="physics steps per wake-up (default 1; 2 inside User-Mode Linux)")


def run(args: argparse.Namespace) -> int:
    from controller.settings.daemon import bus_kwargs
    from hil.session.firmware import run_firmware

    final = run_firmware(bus_kwargs(args.interface, args.channel, args.bitrate), seed=args.seed, gui=args.gui, scenario=args.scenario,
                         range_noise_m=args.range_noise_m, range_dropout_prob=args.range_dropout_prob,
                         duration_s=args.seconds, steps_per_wake=args.steps_per_wake)
    print(json.dumps({k: final[k] for k in ("t_s", "axes", "watchdog_trips", "host", "pacing")}), file=sys.stderr)
    return 0
