"""``learn``: learning trials: approach an obstacle and step over it, again and again."""

from __future__ import annotations

import argparse

from controller.cli.common import positive


def add_arguments(p: argparse.ArgumentParser) -> None:
    from hil.experiments.methods import DEFAULT_METHOD, METHODS

    p.add_argument("--method", choices=METHODS, default=DEFAULT_METHOD,
                   help=f"what drives the stride: a name of the method registry (default {DEFAULT_METHOD}: "
                        "the paper's learner)")
    p.add_argument("--trials", type=int, default=150, help="number of approaches (default 150)")
    p.add_argument("--seed", type=int, default=0, help="seed of start distances and sensor noise (default 0)")
    p.add_argument("--out", required=True, help="output folder for metrics.json and weights.npz")
    p.add_argument("--obstacle-height-m", type=positive(float), default=0.08, help="obstacle height [m] (0.08)")
    p.add_argument("--obstacle-depth-m", type=positive(float), default=0.10, help="obstacle depth [m] (0.10)")
    p.add_argument("--range-noise-m", type=float, default=0.02, help="range sensor noise, 1 sigma [m] (0.02)")
    p.add_argument("--no-learning", action="store_true", help="freeze the weights at zero (the baseline)")
    p.add_argument("--no-figures", action="store_true", help="skip DIR/figures/")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    from hil.experiments.learn import LearnConfig, run_learning

    config = LearnConfig(
        trials=args.trials,
        seed=args.seed,
        obstacle_height_m=args.obstacle_height_m,
        obstacle_depth_m=args.obstacle_depth_m,
        range_noise_m=args.range_noise_m,
        learning=not args.no_learning,
        method=args.method,
        trace_trials=(0, -1),
    )
    metrics = run_learning(config, out_dir=args.out, progress=not args.quiet, figures=not args.no_figures)
    s = metrics["summary"]
    late = "n/a" if s["mistakes_101_150"] is None else s["mistakes_101_150"]
    early = "n/a" if s["success_21_40"] is None else f"{s['success_21_40']:.0%}"
    print(
        f"{config.method}{'' if config.learning else ' (no learning)'}, seed {config.seed}: success {s['success_rate']:.0%} "
        f"over {s['trials']} trials, {early} in trials 21-40, {late} mistakes in 101-150; "
        f"{s['sim_s']:.0f} s simulated in {s['wall_s']:.0f} s ({s['trials_per_minute']:.0f} trials/min); "
        f"wrote {args.out}/metrics.json and weights.npz"
    )
    return 0
