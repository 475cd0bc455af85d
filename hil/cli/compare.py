"""``compare``: are two runs' records the same, field for field (wall-clock figures aside)?

Exit 0 the same, 1 they differ (the first difference is printed), 3 a file is missing or not JSON
(the exit code of every input error, :mod:`controller.errors`), 2 a malformed option.
"""

from __future__ import annotations

import argparse
import sys

from controller.cli.common import write_json


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("first", help="a learn output folder (or its metrics.json), or a JSON file (walk --json, ...)")
    p.add_argument("second", help="the same of the other run")
    p.add_argument("--json", default=None, help="also write the comparison as JSON here ('-': stdout)")


def run(args: argparse.Namespace) -> int:
    from controller.cli.common import check_output_file
    from hil.analysis.records import compare, read

    check_output_file(args.json, "--json")
    result = compare(read(args.first), read(args.second))
    if args.json is not None:
        write_json(args.json, result)
    if result["kind"] == "learn":
        n = result["trials"]
        what = (f"{n[1]} trials, per-trial records identical: {not result['differing_trials']}; "
                f"summary identical: {result['summary_same']}")
    else:
        what = f"identical: {result['same']}"
    print(f"{args.second} vs {args.first}: {what}", file=sys.stderr)
    if not result["same"]:
        print(f"first difference: {result['first_difference']}", file=sys.stderr)
    return 0 if result["same"] else 1
