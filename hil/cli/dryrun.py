"""``dryrun``: the deployment dry run: the systemd unit's own command line against the simulated leg
on vcan0, playing systemd's notify socket; a checklist.

``--out`` is checked, and ``--unit`` and ``--config`` must be files, before anything starts (exit 3
naming the option); ``--seconds`` must be positive (exit 2).
"""

from __future__ import annotations

import argparse


def add_arguments(p: argparse.ArgumentParser) -> None:
    from hil.dryrun.run import add_dryrun_args

    add_dryrun_args(p)


def run(args: argparse.Namespace) -> int:
    import math
    from pathlib import Path

    from controller.cli.common import check_output_folder
    from controller.errors import InputError, UsageError
    from hil.dryrun.run import main_dryrun

    if not (math.isfinite(args.seconds) and args.seconds > 0):
        raise UsageError(f"--seconds must be a positive number, got {args.seconds}")
    check_output_folder(args.out, "--out")
    for option, path in (("--unit", args.unit), ("--config", args.config)):
        if path is not None and not Path(path).is_file():
            raise InputError(f"{option} {path}: {'a folder, not a file' if Path(path).is_dir() else 'no such file'}")
    return main_dryrun(args)
