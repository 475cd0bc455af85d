"""``replay``: feed a recorded bus log to the controller offline."""

from __future__ import annotations

import argparse


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("log", help="bus log (.blf, .log, .asc, ...) recorded by hil")
    p.add_argument("--config", default=None, metavar="FILE",
                   help="configuration (TOML; default: controller.toml beside the log, else an old "
                   "controller.json there, else defaults)")
    p.add_argument("--records", default=None, metavar="FILE",
                   help="the live run's records to compare with (default: controller.jsonl beside the log)")
    p.add_argument("--json", default=None, help="also write the replayed decisions as JSON here ('-': stdout)")


def run(args: argparse.Namespace) -> int:
    from hil.analysis.replay import main_replay

    return main_replay(args)
