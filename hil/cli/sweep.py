"""``sweep``: learning runs over seeds x obstacle heights x methods, with a report."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", required=True, help="sweep folder: cells/, summary.json, timing.json, report.md")
    p.add_argument("--seeds", default="0-9", help="seeds: a list 0,1,2 and/or ranges 0-9 (default 0-9)")
    p.add_argument("--obstacle-heights-m", default="0.08", help="obstacle heights [m], comma list (0.08)")
    p.add_argument("--mixed-heights", action="store_true",
                   help="one scenario in which each trial draws its height from the list")
    from hil.experiments.methods import DEFAULT_SWEEP_METHODS, METHODS

    p.add_argument("--methods", default=",".join(DEFAULT_SWEEP_METHODS),
                   help=f"methods, comma list of the method registry's names: {', '.join(METHODS)} "
                        f"(default {','.join(DEFAULT_SWEEP_METHODS)})")
    p.add_argument("--trials", type=int, default=150, help="trials per run (default 150)")
    p.add_argument("--workers", type=int, default=None, help="worker processes (default: os.cpu_count())")
    p.add_argument("--dask", default=None, metavar="ADDRESS",
                   help="run on the Dask scheduler at ADDRESS, or 'local' for a LocalCluster of --workers")
    p.add_argument("--report-only", action="store_true", help="only rewrite report.md and figures/ from DIR")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    from hil.analysis.report import write_report
    from hil.experiments.sweep import SweepConfig, parse_heights, parse_methods, parse_seeds, run_sweep

    if args.report_only:
        report = write_report(args.out)
        print(f"wrote {report['report']} and {args.out}/figures/", file=sys.stderr)
        return 0
    config = SweepConfig(
        out_dir=Path(args.out),
        seeds=parse_seeds(args.seeds),
        obstacle_heights_m=parse_heights(args.obstacle_heights_m),
        methods=parse_methods(args.methods),
        trials=args.trials,
        mixed_heights=args.mixed_heights,
        dask=args.dask,
        **({} if args.workers is None else {"workers": args.workers}),
    )
    stats = run_sweep(config, progress=not args.quiet)
    if stats["rows"]:
        write_report(config.out_dir)
    print(f"sweep: {stats['cells']} cells, {stats['ran']} run, {stats['resumed']} resumed, "
          f"{len(stats['failed'])} failed; wrote {args.out}/summary.json, timing.json"
          f"{', report.md' if stats['rows'] else ''}", file=sys.stderr)
    if stats["failed"]:
        print(f"elegant-stepping sweep: {len(stats['failed'])} cells failed: {', '.join(stats['failed'])} "
              f"(errors in {args.out}/timing.json)", file=sys.stderr)
        return 1
    return 0
