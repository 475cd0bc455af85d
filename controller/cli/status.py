"""``status``: the running daemon's status: version, lifecycle and phase, each axis's state and errors, bus voltage, tick statistics, the weights file and its age.

One request on the daemon's control socket (:mod:`controller.daemon.control`; the shared code is
:mod:`controller.daemon.command`). ``--socket PATH``, or ``--config FILE`` (its ``[service]
control_socket``), default ``/run/elegant-stepping/control.sock``; ``--json`` prints the reply.

Exit codes (:mod:`controller.errors`; each failure one line, ``elegant-stepping-leg VERB: error:
...``): 0 accepted; 1 refused by the daemon (the reason on stderr); 2 a malformed option; 3 an
input to fix: ``--config`` unreadable or invalid, or permission denied on the socket (its group
is named: join it); 4 no daemon answers (no socket file, nothing listening, no reply within
``--timeout-s``: is the service running?).
"""

from __future__ import annotations

import argparse

VERB = "status"


def add_arguments(p: argparse.ArgumentParser) -> None:
    from controller.daemon.command import add_control_arguments

    add_control_arguments(p, json_help="print the daemon's whole reply as JSON")


def run(args: argparse.Namespace) -> int:
    from controller.daemon.command import leg_verb

    return leg_verb(VERB, args)
