"""``faults``: the fault-injection matrix.

``--only`` names rows of the matrix; a name that is not one is a usage error listing the known
rows (exit 2), never an empty table (:func:`hil.faults.matrix.parse_only`).
"""

from __future__ import annotations

import argparse

from controller.cli.common import non_negative, positive


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--json", default="-", help="where to write the rows (default: stdout)")
    p.add_argument("--out", default="out/faults", help="folder for each case's row, trials and weights (out/faults)")
    p.add_argument("--trials", type=positive(int), default=150, help="learning trials of each rate-fault case (150)")
    p.add_argument("--seeds", default="0", help="seeds of the whole matrix, e.g. 0 or 0-2 (default 0)")
    p.add_argument("--loss-seeds", default="", help="also run 5%% frame loss on these seeds, e.g. 0-9")
    p.add_argument("--only", default="", help="only these faults, comma separated (e.g. drop,kill)")
    p.add_argument("--kills", type=non_negative(int), default=1000, help="kill -9s during weight saves (1000; 0: none)")
    p.add_argument("--hil", action="store_true", help="also the HIL rows (SocketCAN, User-Mode Linux here)")
    p.add_argument("--hil-trials", type=positive(int), default=10, help="trials of the HIL rate-fault row (10)")
    p.add_argument("--workers", type=positive(int), default=2, help="processes in parallel (2)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    from hil.faults.matrix import main_faults

    return main_faults(args)
