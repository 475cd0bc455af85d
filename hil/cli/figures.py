"""``figures``: the paper's figures (PNG and SVG) from learn output folders."""

from __future__ import annotations

import argparse
import sys

from controller.cli.common import write_json


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("folders", nargs="+", help="learn output folders (seeds, heights, baselines)")
    p.add_argument("--out", required=True, help="output folder for the figures")
    p.add_argument("--json", default="-", help="where to list the written files (default: stdout)")


def run(args: argparse.Namespace) -> int:
    from hil.analysis.figures import paper_figures

    written = paper_figures(args.folders, args.out)
    write_json(args.json, {name: [str(p) for p in paths] for name, paths in written.items()})
    print(f"wrote {len(written)} figures (PNG and SVG) into {args.out}", file=sys.stderr)
    return 0
