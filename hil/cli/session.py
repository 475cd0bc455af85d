"""``hil``: learning trials with the controller and the simulated leg as two processes on a real
SocketCAN bus (inside User-Mode Linux where the kernel has no CAN), with optional fault injection.

Every option is checked before anything starts (User-Mode Linux boots in tens of seconds): a bad
number is a usage error (exit 2), an output folder that cannot be written an input error (3), no
vcan and no User-Mode Linux a missing dependency (6)."""

from __future__ import annotations

import argparse

from controller.cli.common import non_negative, positive


def add_arguments(p: argparse.ArgumentParser) -> None:
    from hil.faults.session import add_hil_fault_args

    p.add_argument("--trials", type=positive(int), default=10, help="number of approaches (default 10)")
    p.add_argument("--seed", type=non_negative(int), default=0, help="seed of start distances and sensor noise (default 0)")
    p.add_argument("--out", required=True, help="output folder: metrics.json, bus.blf/bus.log, weights.npz, logs")
    p.add_argument("--channel", default="vcan0", help="SocketCAN channel (default vcan0)")
    p.add_argument("--obstacle-height-m", type=positive(float), default=0.08, help="obstacle height [m] (0.08)")
    p.add_argument("--range-noise-m", type=non_negative(float), default=0.02, help="range sensor noise, 1 sigma [m] (0.02)")
    p.add_argument("--no-learning", action="store_true", help="freeze the weights at zero (the baseline)")
    p.add_argument("--log-format", choices=("blf", "log"), default="blf",
                   help="bus recording: BLF (bus.blf) or candump (bus.log); default blf")
    p.add_argument("--where", choices=("auto", "native", "uml"), default="auto",
                   help="native vcan, User-Mode Linux, or auto: native if vcan can be had, else UML")
    p.add_argument("--timeout", type=positive(float), default=None, help="give up after this many seconds")
    p.add_argument("--quiet", action="store_true", help="less output")
    add_hil_fault_args(p)


def run(args: argparse.Namespace) -> int:
    from hil.session.run import main_hil

    return main_hil(args)
