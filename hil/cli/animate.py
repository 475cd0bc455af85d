"""``animate``: GIFs of the leg before and after learning (PyBullet renderer).

``--out`` and ``--json`` are checked before the trials run (exit 3 naming the option); numbers by
their argparse types (exit 2).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from controller.cli.common import non_negative, positive, write_json


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--trials", type=positive(int), default=60, help="learning trials; the first and last are filmed (60)")
    p.add_argument("--seed", type=non_negative(int), default=0, help="seed of start distances and sensor noise (default 0)")
    p.add_argument("--out", required=True, help="output folder for before.gif, after.gif, before_after.gif")
    p.add_argument("--obstacle-height-m", type=positive(float), default=0.08, help="obstacle height [m] (0.08)")
    p.add_argument("--fps", type=positive(float), default=15.0, help="frames per simulated second (15)")
    p.add_argument("--width", type=positive(int), default=360, help="frame width [px] (360)")
    p.add_argument("--height", type=positive(int), default=240, help="frame height [px] (240)")
    p.add_argument("--json", default=None, help="also write the summary as JSON here ('-': stdout)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    from controller.cli.common import check_output_file, check_output_folder
    from controller.errors import UsageError
    from hil.analysis.animation import AnimationConfig, animate
    from hil.experiments.learn import LearnConfig

    if args.trials < 2:
        raise UsageError(f"--trials must be at least 2 (the first and the last trial are filmed), got {args.trials}")
    check_output_folder(args.out, "--out")
    check_output_file(args.json, "--json")

    config = LearnConfig(trials=args.trials, seed=args.seed, obstacle_height_m=args.obstacle_height_m)
    anim = AnimationConfig(fps=args.fps, width_px=args.width, height_px=args.height)
    result = animate(config, args.out, anim, progress=not args.quiet)
    if args.json is not None:
        write_json(args.json, result)
    files = ", ".join(f"{Path(f['path']).name} ({f['frames']} frames, {f['size_px'][0]}x{f['size_px'][1]})"
                      for f in result["files"].values())
    outcome = {k: "cleared" if v else "hit" for k, v in result["success"].items()}
    print(f"trial 1 {outcome['before']}, trial {config.trials} {outcome['after']}; wrote {files}; "
          f"rendering took {result['render_wall_s']:.1f} s of {result['wall_s']:.1f} s", file=sys.stderr)
    return 0
