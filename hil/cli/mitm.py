"""``mitm``: a man-in-the-middle node.

Options are checked before a channel is opened: a fault spec that does not parse is a usage error
naming ``--to-leg``/``--from-leg`` (exit 2), and so is a silence on the other clock
(``--silence-after-s`` with ``--clock sim``, ``--silence-at-sim-s`` without it); a channel that
cannot be opened a bus error naming ``--controller-channel``/``--leg-channel`` (exit 4);
``--json``/``--ready-file`` that cannot be written an input error (exit 3).
"""

from __future__ import annotations

import argparse

from controller.cli.common import bounded, non_negative, positive


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--controller-channel", default="vcan0", help="the controller's channel (default vcan0)")
    p.add_argument("--leg-channel", default="vcan1", help="the leg's channel (default vcan1)")
    p.add_argument("--to-leg", default="", metavar="SPEC", help="faults on frames to the leg, e.g. drop=0.05")
    p.add_argument("--from-leg", default="", metavar="SPEC", help="faults on frames from the leg")
    p.add_argument("--seed", type=non_negative(int), default=0, help="seed of the faults (default 0)")
    p.add_argument("--silence-node", type=bounded(int, 0, 63), default=None, metavar="ID",
                   help="the node to silence (its frames to the controller dropped) on SIGUSR1 (with --clock sim: "
                        "from the next sync) or at --silence-after-s / --silence-at-sim-s")
    p.add_argument("--silence-after-s", type=non_negative(float), default=None, metavar="T",
                   help="silence the node T s (wall clock) after start; not with --clock sim")
    p.add_argument("--clock", choices=("wall", "sim"), default="wall",
                   help="the faults' clock: wall (the monotonic clock, default) or sim (the plant's ES_Sim_Sync "
                        "frames, for hil --clock sim: the simulated-time frames pass untouched, the faults "
                        "depend on the frames alone)")
    p.add_argument("--silence-at-sim-s", type=non_negative(float), default=None, metavar="T",
                   help="with --clock sim: silence the node from the first sync at simulated time >= T s")
    p.add_argument("--poll-s", type=positive(float), default=None,
                   help="pause after each batch of frames [s] (default 0.0005; 0.002 inside User-Mode Linux)")
    p.add_argument("--seconds", type=positive(float), default=None, help="stop after this long (default: run)")
    p.add_argument("--json", default=None, metavar="FILE", help="write the counts here at exit")
    p.add_argument("--ready-file", default=None, metavar="FILE", help="create this file once both channels are open")


def run(args: argparse.Namespace) -> int:
    from controller.cli.common import check_output_file
    from controller.daemon.openbus import open_bus
    from controller.errors import BusError, UsageError
    from hil.faults.mitm import run_mitm
    from hil.faults.model import FaultSpec

    specs = {}
    for option, text in (("--to-leg", args.to_leg), ("--from-leg", args.from_leg)):
        try:
            specs[option] = FaultSpec.parse(text)
        except ValueError as exc:
            raise UsageError(f"{option}: {exc}") from None
    if args.clock == "sim" and args.silence_after_s is not None:
        raise UsageError("--silence-after-s is wall time: with --clock sim use --silence-at-sim-s")
    if args.clock != "sim" and args.silence_at_sim_s is not None:
        raise UsageError("--silence-at-sim-s is simulated time: it needs --clock sim")
    if args.controller_channel == args.leg_channel:
        raise UsageError(f"--controller-channel and --leg-channel must differ, got {args.leg_channel!r} twice")
    check_output_file(args.json, "--json")
    check_output_file(args.ready_file, "--ready-file")
    for option, channel in (("--controller-channel", args.controller_channel), ("--leg-channel", args.leg_channel)):
        try:  # can it open? (before run_mitm installs its signal handlers)
            open_bus({"interface": "socketcan", "channel": channel}).shutdown()
        except BusError as exc:
            raise BusError(f"{option} {channel}: {exc}") from None
    run_mitm(args.controller_channel, args.leg_channel, to_leg=specs["--to-leg"], from_leg=specs["--from-leg"],
             seed=args.seed, silence_node=args.silence_node, silence_after_s=args.silence_after_s,
             poll_s=args.poll_s, duration_s=args.seconds, json_path=args.json, ready_path=args.ready_file,
             clock=args.clock, silence_at_sim_s=args.silence_at_sim_s)
    return 0
