"""``walk``: walk on flat ground through the whole stack in lockstep.

Options are checked before the simulation starts: a burst length outside the CPG's bounds is a
usage error naming ``--burst-s`` (exit 2), a ``--json`` that cannot be written an input error (3).
``--gui`` opens PyBullet's window on the same walk (docs/gui.md); without a display it is refused
in one line (exit 2) before anything starts.
"""

from __future__ import annotations

import argparse
import sys

from controller.cli.common import non_negative, positive, write_json


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--seconds", type=positive(float), default=20.0, help="simulated seconds (default 20)")
    p.add_argument("--seed", type=non_negative(int), default=0, help="seed of the sensor noise (default 0)")
    p.add_argument("--burst-s", type=positive(float), default=None, help="CPG burst length [s] (default 0.30)")
    p.add_argument("--json", default="-", help="where to write the metrics (default: stdout)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    from hil.experiments.gui import add_arguments as add_gui

    add_gui(p)


def run(args: argparse.Namespace) -> int:
    from controller.cli.common import check_output_file
    from controller.errors import UsageError
    from hil.experiments.gui import view_from, watched_harness

    check_output_file(args.json, "--json")
    view = view_from(args)  # --gui: the display is checked before anything starts (PyBullet not yet imported)
    from hil.experiments.walk import run_walk, walk_config

    try:
        walk_config(args.seed, args.burst_s)  # the CPG's own bounds, before the plant loads
    except ValueError as exc:
        raise UsageError(f"--burst-s {args.burst_s}: {exc}") from None
    metrics = run_walk(args.seconds, seed=args.seed, burst_s=args.burst_s, progress=not args.quiet,
                       **({} if view is None else {"harness": watched_harness(view)}))
    write_json(args.json, metrics)
    stride = metrics["mean_stride_m"]
    print(
        f"walked {metrics['sim_s']:.1f} s in {metrics['wall_s']:.2f} s wall: {metrics['steps']} steps, "
        f"mean stride {stride if stride is None else round(stride, 3)} m, "
        f"clearance {metrics['swing_clearance_min_m']}, phase {metrics['phase']}",
        file=sys.stderr,
    )
    if view is not None and view.shot is not None:
        print(view.shot.describe(), file=sys.stderr)
    return 0 if metrics["phase"] == "walk" else 1
