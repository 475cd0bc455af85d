"""``elegant-stepping-leg``: the command line deployed on the leg's computer.

Its verbs (:data:`VERBS`, the one place a leg verb is added): ``run``, the controller daemon at its
fixed rate on the CAN bus (:mod:`controller.cli.run`; the systemd unit's ``ExecStart``);
``bringup``, the bring-up checklist against the real nodes (:mod:`controller.cli.bringup`);
``config check|show``, the TOML configuration (:mod:`controller.cli.config`); and the verbs a
person drives the running daemon with, over its control socket (:mod:`controller.daemon.control`):
``status``, ``arm``, ``disarm``, ``clear-faults``, ``estop`` (one module each). The machinery they
share (registry, bus arguments, exit codes) is :mod:`controller.cli.common`. The harness's
``elegant-stepping`` command line offers the same three verbs from these same modules.

May import: what :mod:`controller` may (the standard library, numpy, filterpy, python-can,
cantools, ``protocol``), nothing else: a leg installs the core package only, so neither ``hil``,
``firmware_sim``, pybullet, matplotlib, tqdm nor dask may be imported on any path from
:func:`main` (``tests/test_layout.py`` proves it).
"""

from __future__ import annotations

from typing import Sequence

from controller.cli.common import Verb
from controller.cli.common import main as _main

VERBS: tuple[Verb, ...] = (
    Verb("run", "controller.cli.run", "the controller daemon at its fixed rate on a CAN bus"),
    Verb("bringup", "controller.cli.bringup", "bring-up checklist on the real leg: nodes, versions, errors, "
                                              "bus voltage, positions, small slow moves; PASS/FAIL per item"),
    Verb("config", "controller.cli.config", "the configuration file (TOML): check it, or show the effective one"),
    Verb("status", "controller.cli.status", "the running daemon's status: lifecycle, phase, axes, errors, ticks, weights"),
    Verb("arm", "controller.cli.arm", "arm the leg (from inactive): closed loop, ramp, walk"),
    Verb("disarm", "controller.cli.disarm", "disarm the leg: axes IDLE, back to inactive"),
    Verb("clear-faults", "controller.cli.clear_faults", "clear the drivers' errors (Clear_Errors) and a latched fault"),
    Verb("estop", "controller.cli.estop", "emergency stop: ODrive's Estop to every axis, a latched fault"),
)


def main(argv: Sequence[str] | None = None) -> int:
    """``elegant-stepping-leg [-v] VERB ...``: the exit code of the verb."""
    return _main("elegant-stepping-leg", "The walking leg's controller: run it, bring the leg up, check its "
                 "configuration.", VERBS, argv)
