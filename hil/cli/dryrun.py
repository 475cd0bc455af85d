"""``dryrun``: the deployment dry run: the systemd unit's own command line against the simulated leg
on vcan0, playing systemd's notify socket; a checklist."""

from __future__ import annotations

import argparse


def add_arguments(p: argparse.ArgumentParser) -> None:
    from hil.dryrun.run import add_dryrun_args

    add_dryrun_args(p)


def run(args: argparse.Namespace) -> int:
    from hil.dryrun.run import main_dryrun

    return main_dryrun(args)
