"""``decode``: print a bus log as named signals (or, with ``--load``, its bus load).

The frames before any damage are printed; a damaged log then ends with one line naming the frame
(BLF) or line (text log) where the damage starts and exit 3, or with ``--partial`` a warning line
and exit 0 (:mod:`hil.analysis.buslog`).
"""

from __future__ import annotations

import argparse

from controller.cli.common import non_negative, positive


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("log", help="bus log (.blf, .log, .asc, ...)")
    p.add_argument("--limit", type=non_negative(int), default=None, help="print at most this many frames")
    p.add_argument("--load", action="store_true",
                   help="print the bus load instead (JSON: frames/s x bits/frame, per message)")
    p.add_argument("--bitrate", type=positive(int), default=1_000_000, help="bus bitrate for --load [bit/s] (1000000)")
    p.add_argument("--skip-s", type=non_negative(float), default=0.0,
                   help="leave out the first seconds for --load (0)")
    p.add_argument("--partial", action="store_true",
                   help="a damaged log: use the valid frames before the damage (a warning, exit 0) instead of "
                        "exit 3")


def run(args: argparse.Namespace) -> int:
    from hil.analysis.replay import main_decode

    return main_decode(args)
