"""``sweep``: learning runs over seeds x obstacle heights x methods, with a report.

A sweep cannot lose results (docs/runs.md): the same command again resumes it (finished cells
are kept, stopped cells resume from their trial records); a folder of another sweep configuration
is refused unless ``--overwrite``; SIGINT and SIGTERM stop the workers too and exit 130.

The experimental conditions are ``learn``'s (:mod:`hil.experiments.conditions`, ``--experiment
FILE`` too), every cell runs them; ``--obstacle-heights-m`` stays the grid (``--mixed-heights``:
one scenario drawing per trial).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any, Callable

from controller.cli.common import positive, sigterm_as_sigint


def _option(parse: Callable[[str], Any]) -> Callable[[str], Any]:
    """An argparse type from a parser that raises ValueError (argparse then names the option)."""

    def wrapped(text: str) -> Any:
        try:
            return parse(text)
        except ValueError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None

    return wrapped


def _seeds(text: str) -> tuple[int, ...]:
    from hil.experiments.sweep import parse_seeds

    return parse_seeds(text)


def _methods(text: str) -> tuple[str, ...]:
    from hil.experiments.methods import METHODS
    from hil.experiments.sweep import parse_methods

    methods = parse_methods(text)
    unknown = [m for m in methods if m not in METHODS]
    if unknown or not methods:
        raise ValueError(f"unknown method {unknown[0]!r}; choose from {', '.join(METHODS)}" if unknown
                         else "need at least one method")
    return methods


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", required=True, help="sweep folder: cells/, summary.json, timing.json, report.md")
    p.add_argument("--overwrite", action="store_true",
                   help="clear the sweep's own files in --out first (a sweep of another configuration is refused "
                        "without it)")
    p.add_argument("--seeds", type=_option(_seeds), default="0-9",
                   help="seeds: a list 0,1,2 and/or ranges 0-9 (default 0-9)")
    from hil.experiments.conditions import add_arguments as add_conditions

    add_conditions(p, helps={"obstacle_heights_m": "obstacle heights [m], comma list: the grid, one scenario each "
                                                    "(with --mixed-heights, one scenario drawing per trial); each in "
                                                    "[0.03, 0.5] m, not 0.03, and at most the leg's limit (0.223 m for the "
                                                    "default block; docs/leg_limits.md) (default 0.08)"})
    p.add_argument("--mixed-heights", action="store_true",
                   help="one scenario in which each trial draws its height from the list")
    from hil.experiments.methods import DEFAULT_SWEEP_METHODS, METHODS

    p.add_argument("--methods", type=_option(_methods), default=",".join(DEFAULT_SWEEP_METHODS),
                   help=f"methods, comma list of the method registry's names: {', '.join(METHODS)} "
                        f"(default {','.join(DEFAULT_SWEEP_METHODS)})")
    p.add_argument("--trials", type=positive(int), default=150, help="trials per run (default 150)")
    p.add_argument("--workers", type=positive(int), default=None, help="worker processes (default: os.cpu_count())")
    p.add_argument("--dask", default=None, metavar="ADDRESS",
                   help="run on the Dask scheduler at ADDRESS, or 'local' for a LocalCluster of --workers")
    p.add_argument("--report-only", action="store_true", help="only rewrite report.md and figures/ from DIR")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    from controller.errors import EXIT_INTERRUPTED
    from hil.analysis.report import write_report
    from hil.experiments.sweep import SweepConfig, SweepStopped, run_sweep

    if args.report_only:
        report = write_report(args.out)
        print(f"wrote {report['report']} and {args.out}/figures/", file=sys.stderr)
        return 0
    from hil.experiments.journal import prepare_folder

    from hil.experiments.conditions import conditions_from

    conditions = conditions_from(args)  # defaults < --experiment FILE < options (a bad file: exit 3)
    prepare_folder(args.out, "--out", create=False)  # before any work (Path("") would be the current folder)
    config = SweepConfig(
        out_dir=Path(args.out),
        seeds=args.seeds,
        obstacle_heights_m=conditions.obstacle_heights_m,
        methods=args.methods,
        trials=args.trials,
        mixed_heights=args.mixed_heights,
        conditions=conditions,
        dask=args.dask,
        **({} if args.workers is None else {"workers": args.workers}),
    )
    with sigterm_as_sigint():  # SIGTERM stops like SIGINT, workers included
        try:
            stats = run_sweep(config, progress=not args.quiet, overwrite=args.overwrite)
        except SweepStopped as stop:
            print(f"elegant-stepping sweep: stopped with {stop.finished} of {stop.total} cells finished (the running "
                  f"cells keep their finished trials); run the same command again to resume", file=sys.stderr)
            return EXIT_INTERRUPTED
    if stats["rows"]:
        write_report(config.out_dir)
    print(f"sweep: {stats['cells']} cells, {stats['ran']} run, {stats['resumed']} resumed, "
          f"{len(stats['failed'])} failed, {len(stats['refused'])} refused, {len(stats['busy'])} busy; "
          f"wrote {args.out}/summary.json, timing.json{', report.md' if stats['rows'] else ''}", file=sys.stderr)
    code = 0
    for key, what in (("failed", "failed"), ("refused", "hold something else and were kept as they are (--overwrite "
                                             "starts the sweep over)"),
                      ("busy", "are being written by another process")):
        if stats[key]:
            print(f"elegant-stepping sweep: {len(stats[key])} cells {what}: {', '.join(stats[key])} "
                  f"(details in {args.out}/timing.json)", file=sys.stderr)
            code = 1
    return code
