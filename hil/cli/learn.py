"""``learn``: learning trials: approach an obstacle and step over it, again and again.

The run folder survives stops (docs/runs.md): each trial is appended to ``DIR/trials.jsonl`` as
it finishes; the same command again resumes a stopped run, says so and exits 0 for a finished
one, and refuses a folder of another configuration unless ``--overwrite``. SIGINT and SIGTERM stop
the run with one line and exit 130; the finished trials are kept.

The experimental conditions (rail speeds, start distances, sensor noise and dropout, obstacle
depth and heights) are options and keys of ``--experiment FILE``, declared once in
:mod:`hil.experiments.conditions` (docs/runs.md); a folder of another experiment is refused.
"""

from __future__ import annotations

import argparse
import sys

from controller.cli.common import non_negative, positive, sigterm_as_sigint


def _one_height(text: str) -> tuple[float]:
    """``--obstacle-height-m H``: one height, checked as an item of ``--obstacle-heights-m``."""
    from hil.experiments.conditions import SETTINGS

    try:
        number = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"obstacle_height_m: {text!r} is not a number") from None
    value, problem = SETTINGS["obstacle_heights_m"]._number(number, float)
    if problem:
        raise argparse.ArgumentTypeError(f"obstacle_height_m: {text!r} {problem}")
    return (value,)


def add_arguments(p: argparse.ArgumentParser) -> None:
    from hil.experiments.methods import DEFAULT_METHOD, METHODS

    p.add_argument("--method", choices=METHODS, default=DEFAULT_METHOD,
                   help=f"what drives the stride: a name of the method registry (default {DEFAULT_METHOD}, "
                        "the learner that won on held-out seeds; paper: the paper's learner, the one the "
                        "daemon deploys)")
    p.add_argument("--trials", type=positive(int), default=150, help="number of approaches (default 150)")
    p.add_argument("--seed", type=non_negative(int), default=0,
                   help="seed of start distances and sensor noise (default 0)")
    p.add_argument("--out", required=True,
                   help="run folder: trials.jsonl, weights.npz, metrics.json, figures/ (a stopped run in it resumes)")
    p.add_argument("--overwrite", action="store_true",
                   help="clear a learn run of another configuration from --out first (never other files)")
    from hil.experiments.conditions import add_arguments as add_conditions

    p.add_argument("--obstacle-height-m", type=_one_height, default=None,
                   metavar="H", help="one obstacle height for every trial [m] (= --obstacle-heights-m H; default 0.08)")
    add_conditions(p, helps={"obstacle_heights_m": "obstacle heights [m], comma list: each trial's drawn from it "
                                                    "(seeded) if several; each in [0.03, 0.5] m, not 0.03, and at "
                                                    "most the leg's limit "
                                                    "(0.223 m for the default block; docs/leg_limits.md) "
                                                    "(default 0.08)"})
    p.add_argument("--no-learning", action="store_true",
                   help="freeze the method's weights at zero (the paper's learner frozen is the no-adaptation "
                        "baseline, --method none)")
    p.add_argument("--no-figures", action="store_true", help="skip DIR/figures/")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    from hil.experiments.gui import add_arguments as add_gui

    add_gui(p)  # --gui, --gui-speed, --screenshot: a window on the run, never part of its configuration


def describe(config, summary: dict) -> str:
    """One line of a run's outcome (without where it was written)."""
    late = "n/a" if summary["mistakes_101_150"] is None else summary["mistakes_101_150"]
    early = "n/a" if summary["success_21_40"] is None else f"{summary['success_21_40']:.0%}"
    return (f"{config.method}{'' if config.learning else ' (no learning)'}, seed {config.seed}: success "
            f"{summary['success_rate']:.0%} over {summary['trials']} trials, {early} in trials 21-40, {late} "
            f"mistakes in 101-150")


def run(args: argparse.Namespace) -> int:
    from controller.errors import EXIT_INTERRUPTED, InputError
    from hil.experiments.conditions import conditions_from
    from hil.experiments.journal import prepare_folder

    if args.obstacle_height_m is not None:
        if args.obstacle_heights_m is not None:
            raise InputError("--obstacle-height-m and --obstacle-heights-m: give one of them")
        args.obstacle_heights_m = args.obstacle_height_m
    conditions = conditions_from(args)  # defaults < --experiment FILE < options (a bad file: exit 3)
    prepare_folder(args.out, "--out", create=False)  # before anything else (no simulation imported yet)
    from hil.experiments.gui import view_from

    view = view_from(args)  # --gui: the display checked before anything starts
    from hil.experiments.learn import FIGURE_TRACES, LearnConfig, LearningRun, RunStopped, learn_into

    config = LearnConfig(
        trials=args.trials,
        seed=args.seed,
        **conditions.learn_fields(),
        learning=not args.no_learning,
        method=args.method,
        trace_trials=FIGURE_TRACES,
    )
    with sigterm_as_sigint():  # SIGTERM stops like SIGINT: what finished is kept
        try:
            watched = {}
            if view is not None:  # the same run in a window (hil.experiments.gui)
                import functools

                from hil.experiments.gui import watched_harness

                watched = {"run_class": functools.partial(LearningRun, harness=watched_harness(view))}
            outcome = learn_into(config, args.out, progress=not args.quiet, figures=not args.no_figures,
                                 overwrite=args.overwrite, **watched)
        except RunStopped as stop:
            print(f"elegant-stepping learn: stopped after {stop.recorded} of {stop.total} trials; "
                  f"run the same command again to resume", file=sys.stderr)
            return EXIT_INTERRUPTED
    s = outcome.metrics["summary"]
    if outcome.status == "finished":
        print(f"{args.out} already holds this finished run ({describe(config, s)}); nothing to run "
              f"(--overwrite runs it again){'; no window, no screenshot' if view is not None else ''}")
        return 0
    if view is not None and view.shot is not None:
        print(view.shot.describe(), file=sys.stderr)
    resumed = f"resumed after {outcome.kept} kept trials (re-run and checked); " if outcome.status == "resumed" else ""
    print(f"{describe(config, s)}; {resumed}{s['sim_s']:.0f} s simulated in {s['wall_s']:.0f} s "
          f"({s['trials_per_minute']:.0f} trials/min); wrote {args.out}/metrics.json"
          f"{'' if outcome.metrics.get('weights_file') is None else ' and weights.npz'}")
    return 0
