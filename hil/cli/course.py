"""``course``: one long walk over obstacles at random spacing, heights and depths, learning online.

The same seed lays out the same course for every method (docs/course.md); each method walks it
into ``DIR/<method>/``, a learn run folder that survives stops like ``learn``'s (docs/runs.md): the
same command again resumes where it stopped, with the same records. Then ``DIR/course.json`` (the
layout and a summary per method) and ``DIR/figures/course.png`` / ``.svg``: success over the last
``--window`` obstacles against the distance walked, every method on one figure.

Bad values are usage errors (exit 2, one line): a malformed option by argparse, a range outside
what a course allows (a gap below the leg's recovery distance, a height above the leg's limit for
the deepest block) by the course's configuration. A folder that is not a course's is refused (exit 3).
"""

from __future__ import annotations

import argparse
import math
import sys

from controller.cli.common import non_negative, positive, sigterm_as_sigint


def _range(text: str) -> tuple[float, float]:
    """``MIN,MAX``: two finite numbers, MIN <= MAX (what a course allows is the configuration's check)."""
    parts = text.split(",")
    try:
        pair = tuple(float(p) for p in parts)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not MIN,MAX (two numbers)") from None
    if len(pair) != 2 or not all(math.isfinite(v) for v in pair):
        raise argparse.ArgumentTypeError(f"{text!r} is not MIN,MAX (two finite numbers)")
    if pair[0] > pair[1]:
        raise argparse.ArgumentTypeError(f"{text!r}: MIN must not exceed MAX")
    return pair[0], pair[1]


def _methods(text: str) -> tuple[str, ...]:
    from hil.experiments.methods import METHODS

    names = tuple(n.strip() for n in text.split(","))
    unknown = [n for n in names if n not in METHODS]
    if unknown or not names:
        raise argparse.ArgumentTypeError(f"unknown method {unknown[0] if unknown else text!r}; choose from "
                                         f"{', '.join(METHODS)}")
    if len(set(names)) != len(names):
        raise argparse.ArgumentTypeError(f"{text!r} names a method twice")
    return names


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--obstacles", type=positive(int), default=150, help="obstacles in the course (default 150)")
    p.add_argument("--seed", type=non_negative(int), default=0,
                   help="seed of the course's layout (the same for every method) and of the sensor noise (default 0)")
    p.add_argument("--methods", type=_methods, default=("paper", "improved", "none", "oracle"), metavar="LIST",
                   help="comma list of the method registry's names, each walks the course (default "
                        "paper,improved,none,oracle)")
    p.add_argument("--heights-m", type=_range, default=(0.04, 0.12), metavar="MIN,MAX",
                   help="obstacle heights [m], uniform; above 0.03 and at most the leg's limit for the deepest "
                        "block (0.20 m is the tallest this stack clears: docs/leg_limits.md) (default 0.04,0.12)")
    p.add_argument("--depths-m", type=_range, default=(0.05, 0.15), metavar="MIN,MAX",
                   help="obstacle depths along the rail [m], uniform, within [0.01, 0.3] (default 0.05,0.15)")
    p.add_argument("--gap-m", type=_range, default=(0.6, 3.0), metavar="MIN,MAX",
                   help="far edge to the next near edge [m], uniform; MIN at least 0.6, the closest spacing the "
                        "leg recovers from (docs/course.md) (default 0.6,3)")
    p.add_argument("--window", type=positive(int), default=20,
                   help="the figure's success is over the last this many obstacles (default 20)")
    p.add_argument("--out", required=True,
                   help="course folder: one learn run folder per method, course.json, figures/ (a stopped course "
                        "in it resumes)")
    p.add_argument("--overwrite", action="store_true",
                   help="clear a method's run of another configuration from --out first (never other files)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    from controller.errors import EXIT_INTERRUPTED, UsageError
    from hil.experiments.journal import prepare_folder

    prepare_folder(args.out, "--out", create=False)  # before anything else (no simulation imported yet)
    from hil.experiments.course import CourseConfig, course_into
    from hil.experiments.learn import RunStopped

    try:
        base = CourseConfig(trials=args.obstacles, seed=args.seed, method=args.methods[0], gap_m=args.gap_m,
                            heights_m=args.heights_m, depths_m=args.depths_m)
    except ValueError as exc:
        option = str(exc).split(":", 1)[0].replace("_", "-")
        raise UsageError(f"--{option}{str(exc)[len(option):]}") from None

    def said(method: str, outcome) -> None:
        s = outcome.metrics["summary"]
        trials = outcome.metrics["trials"]
        kept = " (already in the folder)" if outcome.status == "finished" else (
            f" (resumed after {outcome.kept})" if outcome.status == "resumed" else "")
        print(f"{method}: {sum(t['success'] for t in trials)}/{len(trials)} obstacles cleared over "
              f"{trials[-1]['walked_m']:.0f} m{kept}; {s['wall_s']:.0f} s", flush=True)

    with sigterm_as_sigint():  # SIGTERM stops like SIGINT: what finished is kept
        try:
            course = course_into(base, args.methods, args.out, progress=not args.quiet, overwrite=args.overwrite,
                                 window=args.window, on_method=said)
        except RunStopped as stop:
            print(f"elegant-stepping course: stopped after {stop.recorded} of {stop.total} obstacles in {stop.folder}; "
                  f"run the same command again to resume", file=sys.stderr)
            return EXIT_INTERRUPTED
    parts = [f"{m} {s['success_rate']:.0%} (last {s['window']}: {s['success_last']:.0%})"
             for m, s in course["summary"].items()]
    print(f"course seed {args.seed}, {args.obstacles} obstacles: success {', '.join(parts)}; wrote "
          f"{args.out}/course.json and figures/course.png")
    return 0
