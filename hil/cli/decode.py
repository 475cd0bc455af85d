"""``decode``: print a bus log as named signals."""

from __future__ import annotations

import argparse


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("log", help="bus log (.blf, .log, .asc, ...)")
    p.add_argument("--limit", type=int, default=None, help="print at most this many frames")
    p.add_argument("--load", action="store_true",
                   help="print the bus load instead (JSON: frames/s x bits/frame, per message)")
    p.add_argument("--bitrate", type=int, default=1_000_000, help="bus bitrate for --load [bit/s] (1000000)")
    p.add_argument("--skip-s", type=float, default=0.0, help="leave out the first seconds for --load (0)")


def run(args: argparse.Namespace) -> int:
    from hil.analysis.replay import main_decode

    return main_decode(args)
