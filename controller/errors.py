"""Expected failures and the files the project writes: exit codes, error classes, format stamps.

**Exit codes** (the same for every verb of both command lines, :mod:`controller.cli.common`):

==== =====================================================================================
code meaning
==== =====================================================================================
0    done
1    the job ran and its outcome is a failure (a check failed, a cell failed, a fault row)
2    usage: an option is missing or malformed (argparse's own code)
3    input: a file or folder is missing, damaged, of the wrong structure or version, or
     unwritable; a configuration is invalid
4    bus: the CAN bus cannot be opened, or a node on it does not answer
5    safety stop: the leg stopped itself (a latched fault, an estop, an axis left closed loop)
6    this install lacks something the verb needs (an extra, User-Mode Linux)
70   a bug: the one case that prints a traceback, with a line saying it is a bug
130  interrupted (SIGINT); what was finished is kept
==== =====================================================================================

An expected failure is raised as one of the :class:`CliError` classes below with a message that
names the option or file and what is wrong, in one line; the command line prints
``PROG VERB: error: MESSAGE`` and returns the class's code. :class:`InputError` is also a
``ValueError`` so that library code which validates with ``ValueError`` keeps working.

**Format stamps.** Every JSON file the project writes carries, at its top level,
``format`` (what kind of file it is), ``format_version`` (an integer, raised when a reader of the
old version could misread the new) and ``project_version`` (the package's version that wrote it):
:func:`stamp` makes them, :func:`check_stamp` refuses a file of another kind or of a version the
reader does not know, in one line; :func:`read_stamped_json` reads a stamped JSON file and checks it
in one call (:data:`STAMP_KEYS` are the three keys). A file written before stamps existed (no ``format`` key) is
read as version 0 where the reader accepts that, for the folders of earlier runs.

May import: the standard library only.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Iterable, Mapping

EXIT_OK = 0
EXIT_FAILED = 1
EXIT_USAGE = 2
EXIT_INPUT = 3
EXIT_BUS = 4
EXIT_SAFETY = 5
EXIT_MISSING = 6
EXIT_BUG = 70
EXIT_INTERRUPTED = 130


class CliError(Exception):
    """An expected failure of a command: one line for the person, an exit code for the shell."""

    exit_code = EXIT_FAILED


class UsageError(CliError):
    """An option is malformed or contradicts another (exit 2)."""

    exit_code = EXIT_USAGE


class InputError(CliError, ValueError):
    """A file, folder or configuration is missing, damaged, of the wrong structure or version, or
    cannot be written (exit 3)."""

    exit_code = EXIT_INPUT


class BusError(CliError):
    """The CAN bus cannot be opened or a node does not answer (exit 4)."""

    exit_code = EXIT_BUS


class SafetyStop(CliError):
    """The leg stopped itself (exit 5)."""

    exit_code = EXIT_SAFETY


class MissingDependency(CliError):
    """This install lacks what the verb needs (exit 6)."""

    exit_code = EXIT_MISSING


def project_version() -> str:
    """The installed package's version, or ``"unknown"`` when run from a tree that is not installed."""
    try:
        from importlib.metadata import PackageNotFoundError, version
    except ImportError:  # pragma: no cover - Python < 3.8
        return "unknown"
    try:
        return version("elegant-stepping")
    except PackageNotFoundError:
        return "unknown"


def stamp(kind: str, format_version: int) -> dict[str, Any]:
    """The three stamp keys for a file of ``kind`` at ``format_version``; put them first in the file."""
    return {"format": kind, "format_version": int(format_version), "project_version": project_version()}


def check_stamp(data: Any, kind: str, versions: Iterable[int], source: str = "file") -> int:
    """The format version of ``data`` (a parsed JSON file), after checking it is a ``kind`` file of
    one of ``versions``; version 0 (accepted only if listed) is a file without stamps.

    Raises:
        InputError: not a JSON object, another kind of file, or a version not in ``versions``.
    """
    known = sorted(set(int(v) for v in versions))
    if not isinstance(data, Mapping):
        raise InputError(f"{source}: not a {kind} file (a JSON object expected, got {type(data).__name__})")
    if "format" not in data:
        if 0 in known:
            return 0
        raise InputError(f"{source}: not a {kind} file (no 'format' stamp)")
    if data.get("format") != kind:
        raise InputError(f"{source}: a {data.get('format')!r} file, not a {kind} file")
    v = data.get("format_version")
    if isinstance(v, bool) or not isinstance(v, int) or v not in known:
        by = data.get("project_version", "an unknown version")
        raise InputError(f"{source}: {kind} format version {v!r} (written by elegant-stepping {by}) is not one "
                         f"this version reads ({', '.join(map(str, known))}); use a matching elegant-stepping")
    return v


STAMP_KEYS = ("format", "format_version", "project_version")
"""The keys :func:`stamp` adds: not part of a file's content (``compare`` leaves them out)."""


def read_stamped_json(path: str | Path, kind: str, versions: Iterable[int], *, strip: bool = True) -> dict[str, Any]:
    """The JSON object at ``path``, checked by :func:`check_stamp`; without the stamp keys if ``strip``.

    Raises:
        InputError: not JSON (or not UTF-8), another kind of file or an unknown version (one line).
        OSError: the file cannot be read (the command line names the path).
    """
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except ValueError as exc:  # JSONDecodeError and UnicodeDecodeError are ValueErrors
        raise InputError(f"{path}: not a {kind} file (not JSON: {' '.join(str(exc).split())})") from None
    check_stamp(data, kind, versions, str(path))
    return {k: v for k, v in data.items() if k not in STAMP_KEYS} if strip else dict(data)
