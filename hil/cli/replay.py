"""``replay``: feed a recorded bus log to the controller offline.

A damaged log is exit 3 with the frame (BLF) or line (text log) where the damage starts, unless
``--partial`` (the valid frames are replayed, one warning line says how many and where it
stopped); a configuration, records or metadata file that is missing or of the wrong structure or
version is exit 3 naming it (:mod:`hil.analysis.replay`).
"""

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
    p.add_argument("--partial", action="store_true",
                   help="a damaged log: replay the valid frames before the damage (a warning, exit 0) instead of "
                        "refusing it (exit 3)")


def run(args: argparse.Namespace) -> int:
    from hil.analysis.replay import main_replay

    return main_replay(args)
