"""The leg verbs that command a running daemon (``status``, ``arm``, ``disarm``, ``clear-faults``,
``estop``): what they share, behind their one-line modules in :mod:`controller.cli`.

Each sends one request on the control socket (:func:`controller.daemon.control.request`). Exit
codes (:mod:`controller.errors`): 0 the daemon accepted it; 1 the daemon refused it (the reason on
stderr); 2 a malformed option; 3 an input to fix: a ``--config`` that cannot be read or is invalid,
or a socket this user may not connect to (not in its group); 4 no daemon answers: no socket file,
nothing listening on it, no reply within ``--timeout-s``, a reply that is not the protocol's. Each
failure is one line, ``elegant-stepping-leg VERB: error: ...``. The socket is ``--socket PATH``,
else ``--config FILE``'s ``[service] control_socket``, else ``/run/elegant-stepping/control.sock``.

May import: the standard library and ``controller`` (the leg's install).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from typing import Any

from controller.daemon.control import DEFAULT_SOCKET, request


def add_control_arguments(p: argparse.ArgumentParser, json_help: str = "print the daemon's reply as JSON") -> None:
    """``--socket PATH``, ``--config FILE``, ``--timeout-s S``, ``--json`` (the verbs call this inside
    their own ``add_arguments`` only through :mod:`controller.cli` modules' duplicates)."""
    p.add_argument("--socket", default=None, metavar="PATH",
                   help=f"the daemon's control socket (default: --config's [service] control_socket, else {DEFAULT_SOCKET})")
    p.add_argument("--config", default=None, metavar="FILE", help="the configuration the daemon runs with (TOML)")
    from controller.cli.common import positive

    p.add_argument("--timeout-s", type=positive(float), default=5.0, help="wait this long for the daemon's reply [s]")
    p.add_argument("--json", action="store_true", help=json_help)


def socket_path(args: argparse.Namespace) -> str:
    if getattr(args, "socket", None):
        return args.socket
    if getattr(args, "config", None):
        from controller.settings.file import load_config

        from controller.settings.file import ConfigError

        try:
            return load_config(args.config).service.control_socket
        except ConfigError as exc:
            raise exc.reported() from None  # every problem on its own line, then one: exit 3
    return DEFAULT_SOCKET


def _fmt(x: Any, unit: str = "", digits: int = 3) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "?"
    if isinstance(x, float):
        return f"{x:.{digits}f}{unit}"
    return f"{x}{unit}"


def _age(s: float | None) -> str:
    if s is None:
        return "no file yet"
    if s < 120:
        return f"{s:.0f} s ago"
    if s < 7200:
        return f"{s / 60:.0f} min ago"
    if s < 172800:
        return f"{s / 3600:.1f} h ago"
    return f"{s / 86400:.1f} days ago"


def format_status(st: dict[str, Any]) -> str:
    """The daemon's status as a few readable lines."""
    lines = [f"elegant-stepping controller {st.get('version', '?')} (pid {st.get('pid', '?')}, "
             f"up {_fmt(st.get('uptime_s'), ' s', 0)})",
             f"lifecycle {st.get('lifecycle', '?')}, phase {st.get('phase', '?')}"]
    if st.get("fault_cause"):
        lines.append(f"fault: {st['fault_cause']} (at t={_fmt(st.get('fault_t_s'), ' s')})")
    if st.get("arm_blocked"):
        lines.append(f"arming blocked: {st['arm_blocked']}")
    for name, a in (st.get("axes") or {}).items():
        err = a.get("error") or 0
        names = ", ".join(a.get("error_names") or []) or "none"
        lines.append(f"  {name:<6} {a.get('state', '?'):<20} error {names} ({err:#x})  pos {_fmt(a.get('pos_rad'), ' rad')}"
                     f"  bus {_fmt(a.get('bus_voltage_v'), ' V', 1)}")
    pacing = st.get("pacing") or {}
    lines.append(f"ticks {st.get('ticks', '?')} at {_fmt(st.get('rate_hz'), ' Hz', 0)}, late {st.get('late_ticks', '?')}, "
                 f"skipped {pacing.get('skipped', '?')}, longest period "
                 f"{_fmt(None if st.get('max_period_s') is None else st['max_period_s'] * 1e3, ' ms', 1)}; "
                 f"steps {st.get('steps', '?')}, reflexes {st.get('reflexes', '?')}")
    w = st.get("weights")
    if w is None:
        lines.append("weights: not persisted")
    else:
        age = "no file yet" if w.get("age_s") is None else f"saved {_age(w['age_s'])}"
        lines.append(f"weights: {w.get('file')} ({age}; started from {w.get('source')}; "
                     f"{w.get('saves', 0)} save(s) this run" + (f", {w['failures']} failed" if w.get("failures") else "")
                     + ")")
        for moved in w.get("set_aside") or []:
            lines.append(f"  set aside (another configuration's): {moved}")
    return "\n".join(lines)


def leg_verb(verb: str, args: argparse.Namespace) -> int:
    """Send ``verb``; print the outcome; the exit code: 0 accepted, 1 refused. No reply raises
    :class:`~controller.daemon.control.ControlError` (exit 4, or 3 for a permission), a bad
    ``--config`` :class:`~controller.settings.file.ConfigError` (exit 3): one line each, printed by
    :func:`controller.cli.common.main`."""
    prog = f"elegant-stepping-leg {verb}"
    path = socket_path(args)
    reply = request(path, verb, timeout_s=getattr(args, "timeout_s", 5.0))  # ControlError: one line, exit 4 or 3
    if getattr(args, "json", False):
        print(json.dumps(reply, indent=2))
    elif verb == "status" and reply.get("status"):
        print(format_status(reply["status"]))
    elif reply.get("ok"):
        st = reply.get("status") or {}
        print(f"{verb}: accepted (lifecycle {st.get('lifecycle', '?')}, phase {st.get('phase', '?')})")
    if reply.get("ok"):
        return 0
    print(f"{prog}: refused: {reply.get('refused') or 'no reason given'}", file=sys.stderr)
    return 1


__all__ = ["add_control_arguments", "format_status", "leg_verb", "socket_path"]
