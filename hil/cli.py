"""The ``elegant-stepping`` command line."""

from __future__ import annotations

import argparse
import json
import logging
import math
import sys
from pathlib import Path
from typing import Any, Sequence

log = logging.getLogger("elegant_stepping")


def _positive(kind):
    def parse(text: str):
        value = kind(text)
        if not (math.isfinite(value) and value > 0):
            raise argparse.ArgumentTypeError(f"must be a positive number, got {text!r}")
        return value

    return parse


def _write_json(path: str | None, data: Any) -> None:
    text = json.dumps(data, indent=2, sort_keys=False)
    if path in (None, "-"):
        print(text)
        return
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_suffix(out.suffix + ".tmp")
    tmp.write_text(text + "\n")
    tmp.replace(out)
    log.info("wrote %s", out)


def cmd_walk(args: argparse.Namespace) -> int:
    from hil.walk import run_walk

    metrics = run_walk(args.seconds, seed=args.seed, burst_s=args.burst_s, progress=not args.quiet)
    _write_json(args.json, metrics)
    stride = metrics["mean_stride_m"]
    print(
        f"walked {metrics['sim_s']:.1f} s in {metrics['wall_s']:.2f} s wall: {metrics['steps']} steps, "
        f"mean stride {stride if stride is None else round(stride, 3)} m, "
        f"clearance {metrics['swing_clearance_min_m']}, phase {metrics['phase']}",
        file=sys.stderr,
    )
    return 0 if metrics["phase"] == "walk" else 1


def cmd_learn(args: argparse.Namespace) -> int:
    from hil.learn import LearnConfig, run_learning

    config = LearnConfig(
        trials=args.trials,
        seed=args.seed,
        obstacle_height_m=args.obstacle_height_m,
        obstacle_depth_m=args.obstacle_depth_m,
        range_noise_m=args.range_noise_m,
        learning=not args.no_learning,
    )
    metrics = run_learning(config, out_dir=args.out, progress=not args.quiet, figures=not args.no_figures)
    s = metrics["summary"]
    late = "n/a" if s["mistakes_101_150"] is None else s["mistakes_101_150"]
    early = "n/a" if s["success_21_40"] is None else f"{s['success_21_40']:.0%}"
    print(
        f"{'learning' if config.learning else 'no learning'}, seed {config.seed}: success {s['success_rate']:.0%} "
        f"over {s['trials']} trials, {early} in trials 21-40, {late} mistakes in 101-150; "
        f"{s['sim_s']:.0f} s simulated in {s['wall_s']:.0f} s ({s['trials_per_minute']:.0f} trials/min); "
        f"wrote {args.out}/metrics.json and weights.npz"
    )
    return 0


def cmd_analyze(args: argparse.Namespace) -> int:
    from hil.analysis import analyze

    _write_json(args.json, analyze(args.folders))
    return 0


def cmd_bench(args: argparse.Namespace) -> int:
    from hil.bench import run_bench

    result = run_bench(seconds=args.seconds, seed=args.seed, learn_trials=args.learn_trials)
    _write_json(args.json, result)
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="elegant-stepping", description=__doc__)
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-vv for debug)")
    sub = parser.add_subparsers(dest="command", required=True)

    walk = sub.add_parser("walk", help="walk on flat ground through the whole stack in lockstep")
    walk.add_argument("--seconds", type=_positive(float), default=20.0, help="simulated seconds (default 20)")
    walk.add_argument("--seed", type=int, default=0, help="seed of the sensor noise (default 0)")
    walk.add_argument("--burst-s", type=_positive(float), default=None, help="CPG burst length [s] (default 0.30)")
    walk.add_argument("--json", default="-", help="where to write the metrics (default: stdout)")
    walk.add_argument("--quiet", action="store_true", help="no progress bar")
    walk.set_defaults(func=cmd_walk)

    learn = sub.add_parser("learn", help="learning trials: approach an obstacle and step over it, again and again")
    learn.add_argument("--trials", type=int, default=150, help="number of approaches (default 150)")
    learn.add_argument("--seed", type=int, default=0, help="seed of start distances and sensor noise (default 0)")
    learn.add_argument("--out", required=True, help="output folder for metrics.json and weights.npz")
    learn.add_argument("--obstacle-height-m", type=_positive(float), default=0.08, help="obstacle height [m] (0.08)")
    learn.add_argument("--obstacle-depth-m", type=_positive(float), default=0.10, help="obstacle depth [m] (0.10)")
    learn.add_argument("--range-noise-m", type=float, default=0.02, help="range sensor noise, 1 sigma [m] (0.02)")
    learn.add_argument("--no-learning", action="store_true", help="freeze the weights at zero (the baseline)")
    learn.add_argument("--no-figures", action="store_true", help="skip DIR/figures/")
    learn.add_argument("--quiet", action="store_true", help="no progress bar")
    learn.set_defaults(func=cmd_learn)

    analyze = sub.add_parser("analyze", help="acceptance figures from one or more learn output folders")
    analyze.add_argument("folders", nargs="+", help="learn output folders (one per seed)")
    analyze.add_argument("--json", default="-", help="where to write the figures (default: stdout)")
    analyze.set_defaults(func=cmd_analyze)

    bench = sub.add_parser("bench", help="performance figures as JSON, ratios measured side by side")
    bench.add_argument("--seconds", type=_positive(float), default=10.0, help="simulated seconds per figure")
    bench.add_argument("--seed", type=int, default=0)
    bench.add_argument("--learn-trials", type=int, default=10, help="learning trials timed (default 10)")
    bench.add_argument("--json", default="-", help="where to write the figures (default: stdout)")
    bench.set_defaults(func=cmd_bench)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    level = logging.WARNING - 10 * min(args.verbose, 2)
    logging.basicConfig(level=level, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    try:
        return args.func(args)
    except (ValueError, FileNotFoundError) as exc:
        print(f"elegant-stepping {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
