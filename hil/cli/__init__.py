"""``elegant-stepping``: the research command line (experiments, HIL sessions, faults, analysis).

:data:`VERBS` is the one place a verb is added: a name, the module with its ``add_arguments`` and
``run`` (one module per verb in this folder; the leg's own verbs ``controller``, ``config`` and
``bringup`` are the deployed package's modules, :mod:`controller.cli`), one line of help, and the
extras it needs. The machinery (parser, logging, exit codes, the one-line message for a missing
extra) is :mod:`controller.cli.common`. Verb modules import only the standard library and
``controller.cli.common`` at their top, so ``--help`` works on a core-only install and a verb whose
extra is missing says which to install.
"""

from __future__ import annotations

from typing import Sequence

from controller.cli.common import Verb
from controller.cli.common import main as _main

SIM, RESEARCH = ("sim",), ("research",)
BOTH = SIM + RESEARCH

VERBS: tuple[Verb, ...] = (
    Verb("walk", "hil.cli.walk", "walk on flat ground through the whole stack in lockstep", BOTH),
    Verb("learn", "hil.cli.learn", "learning trials: approach an obstacle and step over it, again and again", BOTH),
    Verb("course", "hil.cli.course", "a long walk over obstacles at random spacing, learning online, per method", BOTH),
    Verb("analyze", "hil.cli.analyze", "acceptance figures from one or more learn output folders"),
    Verb("bench", "hil.cli.bench", "performance figures as JSON, ratios measured side by side", BOTH),
    Verb("compare", "hil.cli.compare", "are two runs' records the same, field for field (wall-clock figures aside)?"),
    Verb("figures", "hil.cli.figures", "the paper's figures (PNG and SVG) from learn output folders", RESEARCH),
    Verb("animate", "hil.cli.animate", "GIFs of the leg before and after learning (PyBullet renderer)", BOTH),
    Verb("sweep", "hil.cli.sweep", "learning runs over seeds x obstacle heights x methods, with a report", BOTH),
    Verb("firmware-sim", "hil.cli.firmware_sim",
         "the simulated leg (plant, drivers, sensor board) on a CAN bus, real time or simulated time", SIM),
    Verb("controller", "controller.cli.run", "the controller daemon at its fixed rate on a CAN bus "
                                             "(the leg's `elegant-stepping-leg run`)"),
    Verb("config", "controller.cli.config", "the configuration file (TOML): check it, or show the effective one"),
    Verb("bringup", "controller.cli.bringup", "bring-up checklist on real hardware: nodes, versions, errors, bus "
                                              "voltage, positions, small slow moves; PASS/FAIL per item"),
    Verb("hil", "hil.cli.session", "learning trials with the controller and the simulated leg as two processes "
                                   "on a real SocketCAN bus (inside User-Mode Linux where the kernel has no CAN), on "
                                   "the wall clock or the plant's simulated time (--clock sim)", SIM),
    Verb("dryrun", "hil.cli.dryrun", "the deployment dry run: the systemd unit's command line against the "
                                     "simulated leg on vcan0, playing systemd's notify socket; a checklist", SIM),
    Verb("mitm", "hil.cli.mitm", "a man-in-the-middle node: forward between two SocketCAN channels, "
                                 "injecting faults; silence a node (SIGUSR1, --silence-after-s, or with --clock sim "
                                 "--silence-at-sim-s)"),
    Verb("faults", "hil.cli.faults", "the fault-injection matrix: inject every failure mode, report what happened",
         BOTH),
    Verb("replay", "hil.cli.replay", "feed a recorded bus log to the controller offline; print its decisions"),
    Verb("decode", "hil.cli.decode", "print a bus log as named signals (cantools with our DBC)"),
    Verb("killsave", "hil.cli.killsave", "fault injection: kill -9 a process while it saves weights, "
                                         "then load; count corrupt loads"),
)


def main(argv: Sequence[str] | None = None) -> int:
    """``elegant-stepping [-v] VERB ...``: the exit code of the verb."""
    return _main("elegant-stepping", "Elegant stepping: experiments, hardware-in-the-loop sessions, fault "
                 "injection and analysis around the walking leg's controller.", VERBS, argv)
