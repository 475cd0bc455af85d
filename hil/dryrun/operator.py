"""The person at the leg, played by the dry run: the leg's verbs against the running daemon.

The dry run's daemon starts inactive (its copy of the simulated leg's config has ``auto_arm``
off, as a real leg's has), and :class:`Operator` does what ``docs/deploy.md`` asks of a person:
``status``, ``arm``, ``estop``, and after a restart of the daemon ``arm`` again (refused: the
drivers' e-stop is latched), ``clear-faults``, ``arm``. Each verb runs as a person runs it, the
leg's console script (``python -m controller.cli VERB --socket PATH``) in its own process, and
each outcome is one item of the dry run's checklist.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from typing import Any, Callable


class Operator:
    """Runs the leg's verbs against the control socket at ``socket`` and keeps what they said."""

    def __init__(self, socket: str, say: Callable[[str], None] = lambda text: None) -> None:
        self.socket = socket
        self.say = say
        self.items: list[dict[str, Any]] = []
        self.transcript: list[dict[str, Any]] = []

    def verb(self, name: str) -> tuple[int, dict[str, Any], str]:
        """(exit code, the daemon's reply as JSON where the verb gave one, stderr) of ``name``."""
        argv = [sys.executable, "-m", "controller.cli", name, "--socket", self.socket, "--json"]
        done = subprocess.run(argv, capture_output=True, text=True, timeout=60, stdin=subprocess.DEVNULL)
        try:
            reply = json.loads(done.stdout) if done.stdout.strip() else {}
        except json.JSONDecodeError:
            reply = {}
        self.transcript.append({"verb": name, "exit": done.returncode, "stderr": done.stderr.strip()[-500:]})
        self.say(f"elegant-stepping-leg {name}: exit {done.returncode} {done.stderr.strip()[-200:]}")
        return done.returncode, reply, done.stderr

    def status(self) -> dict[str, Any]:
        """The daemon's status (empty if it did not answer)."""
        _, reply, _ = self.verb("status")
        return reply.get("status") or reply

    def wait_for(self, phase: str, timeout_s: float, alive: Callable[[], bool]) -> dict[str, Any]:
        """Poll ``status`` until the daemon's phase is ``phase`` (or the time is up); the last status."""
        deadline = time.monotonic() + timeout_s
        status: dict[str, Any] = {}
        while time.monotonic() < deadline and alive():
            status = self.status()
            if status.get("phase") == phase:
                break
            time.sleep(0.25)
        return status

    def check(self, name: str, ok: bool, detail: str) -> bool:
        self.items.append({"check": name, "ok": bool(ok), "detail": detail})
        return bool(ok)


def axes_text(status: dict[str, Any]) -> str:
    axes = status.get("axes") or {}
    return ", ".join(f"{n} {a.get('state')}" + (f" ({', '.join(a.get('error_names') or [])})" if a.get("error") else "")
                     for n, a in axes.items()) or "no axes"
