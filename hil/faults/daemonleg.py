"""The leg's daemon and a simulated leg in one process, on python-can's ``virtual`` bus.

For the fault matrix's daemon rows (signals, restarts, weights files): the real daemon
(``elegant-stepping-leg run``, :func:`controller.cli.main`) runs in the main thread, where its
signal handlers live, and the simulated leg (:class:`firmware_sim.leg.SimulatedLeg`, the same
PyBullet rig and ODrive models as every experiment) steps in a thread on the wall clock. No
SocketCAN and no second process is needed, so a row runs anywhere the tests do.

``python -m hil.faults.daemonleg --channel CH --leg-report FILE [--ready-file FILE] -- RUN-ARGS``:
``RUN-ARGS`` are the ``run`` verb's options (``--interface virtual --channel CH`` are added). At
exit the leg's ground truth (each axis's state, errors, watchdog trips) and the audit of every
Set_Input_Pos the daemon put on the bus (:class:`hil.faults.audit.CommandAudit`, against the joint
limits of the configuration it ran with) are written to ``--leg-report`` (stamped ``format:
"daemonleg-report"``, ``format_version`` :data:`REPORT_VERSION`; :func:`read_report` checks it);
the exit code is the daemon's.
"""

from __future__ import annotations

import argparse
import json
import sys
import threading
import time
from pathlib import Path
from typing import Any

REPORT_KIND = "daemonleg-report"
REPORT_VERSION = 1  # the leg report's format version: raise it when a reader of the old one could misread it


def read_report(path: str | Path) -> dict[str, Any]:
    """The leg report at ``path`` (empty when there is none), without its stamp.

    Raises:
        InputError: not JSON, another kind of file or another format version (one line).
    """
    from controller.errors import read_stamped_json

    path = Path(path)
    if not path.exists():
        return {}
    return read_stamped_json(path, REPORT_KIND, {REPORT_VERSION})


class LegThread(threading.Thread):
    """The simulated leg stepped on the wall clock (catching up when late)."""

    def __init__(self, channel: str, audit, seed: int = 0) -> None:
        super().__init__(name="simulated-leg", daemon=True)
        import can

        from firmware_sim.leg import SimulatedLeg

        self.bus = can.Bus(interface="virtual", channel=channel)
        self.tap = can.Bus(interface="virtual", channel=channel)  # hears every frame the daemon sends
        self.audit = audit
        self.leg = SimulatedLeg(self.bus, seed=seed)
        self.halt = threading.Event()

    def run(self) -> None:
        t0 = time.monotonic()
        while not self.halt.is_set():
            now = time.monotonic() - t0
            while self.leg.t_s < now and not self.halt.is_set():
                self.leg.step()
            while (msg := self.tap.recv(0)) is not None:
                self.audit(msg)
            time.sleep(0.0005)

    def report(self) -> dict:
        while (msg := self.tap.recv(0)) is not None:
            self.audit(msg)
        return {"axes": {name: {"state": a.state.name, "errors": int(a.errors), "watchdog_trips": a.stats["watchdog_trips"]}
                         for name, a in self.leg.axes.items()},
                "commands_checked": self.audit.checked, "commands_outside_limits": self.audit.outside}

    def close(self) -> None:
        self.halt.set()
        self.join(timeout=5)
        self.leg.close()
        self.bus.shutdown()
        self.tap.shutdown()


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    split = argv.index("--") if "--" in argv else len(argv)
    p = argparse.ArgumentParser(prog="python -m hil.faults.daemonleg", description=__doc__.split("\n\n")[0])
    p.add_argument("--channel", required=True, help="the virtual bus channel")
    p.add_argument("--leg-report", required=True, help="write the leg's ground truth here at exit (JSON)")
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv[:split])
    sys.setswitchinterval(0.0005)  # two loops on the wall clock in one interpreter: switch often
    from controller.settings.daemon import daemon_settings
    from hil.faults.audit import CommandAudit

    run_args = argv[split + 1:]
    config_path = run_args[run_args.index("--config") + 1] if "--config" in run_args else None
    audit = CommandAudit.from_config(daemon_settings(config_path).controller)
    leg = LegThread(args.channel, audit, args.seed)
    leg.start()
    from controller.cli import main as leg_main

    try:
        code = leg_main(["run", "--interface", "virtual", "--channel", args.channel, *run_args])
    finally:
        time.sleep(0.2)  # the last frames (IDLE) reach the drivers
        report = leg.report()
        leg.close()
        from controller.errors import stamp

        Path(args.leg_report).write_text(json.dumps({**stamp(REPORT_KIND, REPORT_VERSION), **report}))
    return code


if __name__ == "__main__":
    sys.exit(main())
