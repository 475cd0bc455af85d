"""A HIL session's outcome: its error type and the list of what went wrong.

Shared by the session (:mod:`hil.session.run`), its fault side (:mod:`hil.faults.session`), the
dry run and the bench, so none of them imports another for these.
"""

from __future__ import annotations

from typing import Any


class HilError(RuntimeError):
    """A session could not go on (a process ended, no answer in time, ...); reported in the metrics."""


def session_ok(m: dict[str, Any], trials: int) -> list[str]:
    """What went wrong in a session (empty: nothing)."""
    h = m["hil"]
    problems = []
    if h["error"]:
        problems.append(h["error"])
    if h["trials_completed"] != trials:
        problems.append(f"{h['trials_completed']} of {trials} trials completed")
    if h["watchdog_trips"] != 0:
        problems.append(f"watchdog trips: {h['watchdog_trips']}")
    if "fault" in h["phases"]:
        problems.append(f"safe stop: {h['fault_cause']}")
    if not (h["bus"]["controller_to_leg"] and h["bus"]["leg_to_controller"]):
        problems.append("frames did not flow both ways")
    return problems
