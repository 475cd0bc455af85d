"""``mitm``: a man-in-the-middle node."""

from __future__ import annotations

import argparse

from controller.cli.common import positive


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--controller-channel", default="vcan0", help="the controller's channel (default vcan0)")
    p.add_argument("--leg-channel", default="vcan1", help="the leg's channel (default vcan1)")
    p.add_argument("--to-leg", default="", metavar="SPEC", help="faults on frames to the leg, e.g. drop=0.05")
    p.add_argument("--from-leg", default="", metavar="SPEC", help="faults on frames from the leg")
    p.add_argument("--seed", type=int, default=0, help="seed of the faults (default 0)")
    p.add_argument("--silence-node", type=int, default=None, metavar="ID",
                   help="the node to silence (its frames to the controller dropped) on SIGUSR1 or at --silence-after-s")
    p.add_argument("--silence-after-s", type=float, default=None, metavar="T", help="silence the node T s after start")
    p.add_argument("--poll-s", type=positive(float), default=None,
                   help="pause after each batch of frames [s] (default 0.0005; 0.002 inside User-Mode Linux)")
    p.add_argument("--seconds", type=positive(float), default=None, help="stop after this long (default: run)")
    p.add_argument("--json", default=None, metavar="FILE", help="write the counts here at exit")
    p.add_argument("--ready-file", default=None, metavar="FILE", help="create this file once both channels are open")


def run(args: argparse.Namespace) -> int:
    from hil.faults.model import FaultSpec
    from hil.faults.mitm import run_mitm

    run_mitm(args.controller_channel, args.leg_channel, to_leg=FaultSpec.parse(args.to_leg),
             from_leg=FaultSpec.parse(args.from_leg), seed=args.seed, silence_node=args.silence_node,
             silence_after_s=args.silence_after_s, poll_s=args.poll_s, duration_s=args.seconds,
             json_path=args.json, ready_path=args.ready_file)
    return 0
