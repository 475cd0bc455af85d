"""``bench``: performance figures as JSON, ratios measured side by side.

``--json`` is checked before anything is measured (exit 3). With ``--hil`` where neither a vcan
nor User-Mode Linux can be had, the figures without HIL are written and the exit code is 6 (this
install lacks what ``--hil`` needs).

``--profile DIR`` is another job of the same verb: where a learning run's time goes, per layer of
the stack (:mod:`hil.bench.profile`), written into DIR (``profile.json``, ``profile.txt``,
``profile.pstats``) and the table printed; no other figure is measured, and the options of those
figures (``--json``, ``--hil``) are refused beside it rather than ignored (exit 2). DIR is checked
before anything runs (exit 3).
"""

from __future__ import annotations

import argparse
import sys

from controller.cli.common import non_negative, positive, write_json


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--seconds", type=positive(float), default=10.0, help="simulated seconds per figure")
    p.add_argument("--seed", type=non_negative(int), default=0, help="seed of the runs timed (default 0)")
    p.add_argument("--learn-trials", type=positive(int), default=10, help="learning trials timed (default 10)")
    p.add_argument("--json", default=None, help="where to write the figures (default: stdout)")
    p.add_argument("--hil", action="store_true",
                   help="also the HIL figures on a real vcan0 (User-Mode Linux where needed), beside the floor")
    p.add_argument("--hil-seconds", type=positive(float), default=10.0,
                   help="seconds of walking (and of each floor run) for --hil (default 10)")
    p.add_argument("--profile", metavar="DIR", default=None,
                   help="instead of the figures: profile a learning run (bring-up included, --seed) under "
                        "cProfile and write where its time goes, per layer, into DIR (profile.json, profile.txt, "
                        "profile.pstats); no other figure is run, and --json/--hil are refused beside it")
    p.add_argument("--profile-trials", type=positive(int), default=3,
                   help="learning trials of the --profile run (default 3)")


def run(args: argparse.Namespace) -> int:
    from controller.cli.common import check_output_file
    from controller.errors import EXIT_MISSING
    from hil.bench.run import run_bench

    if args.profile is not None:
        return _profile(args)
    json_path = "-" if args.json is None else args.json
    check_output_file(json_path, "--json")
    result = run_bench(seconds=args.seconds, seed=args.seed, learn_trials=args.learn_trials,
                       hil_seconds=args.hil_seconds if args.hil else None)
    write_json(json_path, result)
    if args.hil:
        h = result["hil"]
        if not h.get("available"):
            print(f"elegant-stepping bench: error: --hil: {h.get('error')} (install: {h.get('install')})",
                  file=sys.stderr)
            return EXIT_MISSING
        f = h["figures"]

        def pair(key: str) -> str:
            x = f[key]
            r = "n/a" if x["ratio"] is None else f"{x['ratio']:.1f}x"
            fmt = lambda v: "n/a" if v is None else f"{v:.0f}"  # noqa: E731
            return f"{fmt(x['hil'])} vs {fmt(x['floor'])} ({r})"

        print(f"bench --hil ({h['where']}): jitter p99 {pair('period_jitter_p99_us')} us, late/10k "
              f"{pair('late_ticks_per_10k')}, command->feedback median {pair('command_to_feedback_median_us')} us, "
              f"p99 {pair('command_to_feedback_p99_us')} us (HIL vs floor)", file=sys.stderr)
        if h.get("error"):
            print(f"elegant-stepping bench --hil: {h['error']}", file=sys.stderr)
            return 1
    return 0


def _profile(args: argparse.Namespace) -> int:
    """``--profile DIR``: the per-layer profile of a learning run into DIR, its table on stdout."""
    from controller.cli.common import check_output_folder
    from controller.errors import UsageError

    if args.json is not None or args.hil:
        raise UsageError(f"--profile writes only the profile; give {'--json' if args.json is not None else '--hil'} "
                         "in a run without it")
    check_output_folder(args.profile, "--profile")
    from hil.bench.profile import table, write_profile

    result = write_profile(args.profile, trials=args.profile_trials, seed=args.seed)
    print(table(result), end="")
    return 0
