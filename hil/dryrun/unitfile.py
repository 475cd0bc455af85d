"""Reading a systemd unit file, as far as the dry run and the tests need it.

:func:`read_unit` parses the INI-like syntax of ``systemd.syntax(7)``: ``[Section]`` headers,
``Key=Value`` lines (a key may repeat: every value is kept, in order; an empty assignment clears
the list, as systemd does for list settings), ``#`` and ``;`` comments, and a trailing backslash
continuing a line. :func:`command_line` splits an ``Exec*=`` value into its prefix characters
(``@ - : + !``) and its argv (shell-like quoting; systemd's ``%`` specifiers and ``$VAR``
expansion are not applied, our unit uses neither). :func:`time_span_s` reads a ``*Sec=`` value
("1", "500ms", "1min 30s", "infinity") in seconds. :func:`environment` reads ``Environment=``
lines into a dict.
"""

from __future__ import annotations

import math
import re
import shlex
from pathlib import Path

Unit = dict[str, dict[str, list[str]]]

_UNITS_S = {
    "us": 1e-6, "usec": 1e-6, "ms": 1e-3, "msec": 1e-3, "s": 1.0, "sec": 1.0, "second": 1.0, "seconds": 1.0,
    "m": 60.0, "min": 60.0, "minute": 60.0, "minutes": 60.0, "h": 3600.0, "hr": 3600.0, "hour": 3600.0,
    "hours": 3600.0, "d": 86400.0, "day": 86400.0, "days": 86400.0, "w": 604800.0, "week": 604800.0,
    "weeks": 604800.0,
}
_SPAN = re.compile(r"\s*([0-9]+(?:\.[0-9]*)?)\s*([a-z]*)")
EXEC_PREFIXES = "@-:+!"


def parse_unit(text: str, where: str = "<unit>") -> Unit:
    """The sections of a unit file's text, each a dict of key -> list of values."""
    unit: Unit = {}
    section: dict[str, list[str]] | None = None
    pending = ""
    for number, raw in enumerate(text.splitlines(), 1):
        line = pending + raw.strip() if pending else raw.strip()
        if line.endswith("\\"):
            pending = line[:-1] + " "
            continue
        pending = ""
        if not line or line[0] in "#;":
            continue
        if line.startswith("["):
            if not line.endswith("]") or len(line) < 3:
                raise ValueError(f"{where}:{number}: bad section header {line!r}")
            section = unit.setdefault(line[1:-1], {})
            continue
        if section is None:
            raise ValueError(f"{where}:{number}: assignment outside a section: {line!r}")
        key, sep, value = line.partition("=")
        key, value = key.strip(), value.strip()
        if not sep or not key or not re.fullmatch(r"[A-Za-z0-9_-]+", key):
            raise ValueError(f"{where}:{number}: not a Key=Value line: {line!r}")
        values = section.setdefault(key, [])
        if value:
            values.append(value)
        else:
            values.clear()
    if pending:
        raise ValueError(f"{where}: the last line ends with a continuation backslash")
    return unit


def read_unit(path: str | Path) -> Unit:
    return parse_unit(Path(path).read_text(), str(path))


def value(unit: Unit, section: str, key: str, default: str | None = None) -> str | None:
    """The last value of ``key`` in ``section`` (systemd: the last assignment wins)."""
    values = unit.get(section, {}).get(key, [])
    return values[-1] if values else default


def command_line(text: str) -> tuple[str, list[str]]:
    """An ``Exec*=`` value -> (prefix characters, argv)."""
    i = 0
    while i < len(text) and text[i] in EXEC_PREFIXES:
        i += 1
    argv = shlex.split(text[i:])
    if not argv:
        raise ValueError(f"empty command line: {text!r}")
    return text[:i], argv


def time_span_s(text: str) -> float:
    """A systemd time span [s]: a bare number is seconds; "infinity" is math.inf."""
    text = text.strip()
    if text == "infinity":
        return math.inf
    total, pos = 0.0, 0
    while pos < len(text):
        m = _SPAN.match(text, pos)
        if m is None or m.end() == pos:
            raise ValueError(f"not a time span: {text!r}")
        number, unit = m.groups()
        if unit not in _UNITS_S and unit != "":
            raise ValueError(f"unknown time unit {unit!r} in {text!r}")
        total += float(number) * _UNITS_S.get(unit, 1.0)
        pos = m.end()
        while pos < len(text) and text[pos] == " ":
            pos += 1
    if pos == 0:
        raise ValueError(f"not a time span: {text!r}")
    return total


def environment(unit: Unit, section: str = "Service") -> dict[str, str]:
    """The ``Environment=`` assignments of ``section``, in order (a later one wins)."""
    env: dict[str, str] = {}
    for line in unit.get(section, {}).get("Environment", []):
        for word in shlex.split(line):
            name, sep, val = word.partition("=")
            if not sep or not name:
                raise ValueError(f"Environment: not an assignment: {word!r}")
            env[name] = val
    return env


__all__ = ["Unit", "parse_unit", "read_unit", "value", "command_line", "time_span_s", "environment"]
