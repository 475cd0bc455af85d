"""``analyze``: acceptance figures from one or more learn output folders.

A folder without a ``metrics.json``, or with one of the wrong structure or version, is one line
naming it (exit 3: :func:`hil.analysis.metrics.load_run`); ``--json`` is checked before reading.
"""

from __future__ import annotations

import argparse

from controller.cli.common import write_json


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("folders", nargs="+", help="learn output folders (one per seed)")
    p.add_argument("--json", default="-", help="where to write the figures (default: stdout)")


def run(args: argparse.Namespace) -> int:
    from controller.cli.common import check_output_file
    from hil.analysis.metrics import analyze

    check_output_file(args.json, "--json")
    write_json(args.json, analyze(args.folders))
    return 0
