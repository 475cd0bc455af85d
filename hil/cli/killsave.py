"""``killsave``: kill -9 a process while it saves weights.

``--folder`` and ``--json`` are checked before the first kill (exit 3); numbers by their argparse
types (exit 2).
"""

from __future__ import annotations

import argparse
import sys

from controller.cli.common import non_negative, positive, write_json


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--kills", type=positive(int), default=1000, help="number of kill -9s (default 1000)")
    p.add_argument("--seed", type=non_negative(int), default=0, help="seed of the kill delays (default 0)")
    p.add_argument("--max-delay-s", type=positive(float), default=0.02,
                   help="kill after a uniform random delay below this [s] (default 0.02)")
    p.add_argument("--folder", default=None, help="where to save (default: a temporary folder, removed)")
    p.add_argument("--json", default="-", help="where to write the counts (default: stdout)")


def run(args: argparse.Namespace) -> int:
    import tempfile

    from controller.cli.common import check_output_file, check_output_folder
    from controller.errors import UsageError
    from hil.faults.killsave import kill_during_saves

    if args.kills < 1:
        raise UsageError(f"--kills must be at least 1, got {args.kills}")
    check_output_folder(args.folder, "--folder")
    check_output_file(args.json, "--json")
    if args.folder is None:
        with tempfile.TemporaryDirectory(prefix="es-killsave-") as folder:
            result = kill_during_saves(args.kills, folder, args.seed, args.max_delay_s)
    else:
        result = kill_during_saves(args.kills, args.folder, args.seed, args.max_delay_s)
    write_json(args.json, result)
    print(f"killsave: {result['kills']} kill -9s ({result['kills_mid_save']} inside a save) over "
          f"{result['saves_completed']} completed saves in {result['elapsed_s']:.1f} s: {result['corrupt_loads']} corrupt "
          f"loads, {result['loads_ok_from_file']} from the file, {result['loads_from_prev']} from .prev, "
          f"{result['zeros']} zeros; {result['tmp_files_left']} temporary files left", file=sys.stderr)
    return 0 if result["corrupt_loads"] == 0 and result["prev_corrupt"] == 0 and result["child_errors"] == 0 else 1
