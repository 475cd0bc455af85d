"""``analyze``: acceptance figures from one or more learn output folders."""

from __future__ import annotations

import argparse

from controller.cli.common import write_json


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("folders", nargs="+", help="learn output folders (one per seed)")
    p.add_argument("--json", default="-", help="where to write the figures (default: stdout)")


def run(args: argparse.Namespace) -> int:
    from hil.analysis.metrics import analyze

    write_json(args.json, analyze(args.folders))
    return 0
