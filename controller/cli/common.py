"""What every command line here shares: the verb registry's shape, the bus arguments, JSON output.

Both console scripts, the leg's ``elegant-stepping-leg`` (:mod:`controller.cli`) and the
harness's ``elegant-stepping`` (:mod:`hil.cli`), are a list of :class:`Verb` run by :func:`main`.
A verb is one module with two functions, ``add_arguments(parser)`` and ``run(args) -> int``; the
module imports only the standard library at its top (what it needs is imported inside ``run``),
so building the parser imports no simulation, plotting or cluster library. A verb names the
extras it needs (:data:`EXTRAS`); where one is not installed, :func:`main` says which to install,
in one line, before importing anything of it.

Exit codes shared by every verb are :mod:`controller.errors`' table: 0 done, 1 the job ran and
failed, 2 usage, 3 input (a file, folder or configuration), 4 bus, 5 safety stop, 6 a missing
extra, 70 a bug (the only case with a traceback, and a line saying so), 130 interrupted. A verb
raises one of :mod:`controller.errors`' classes for an expected failure; :func:`main` prints it as
one line, ``PROG VERB: error: MESSAGE``, and returns its code.
The bus arguments (:func:`add_bus_args`) and their precedence (command line over the
configuration file over python-can's own configuration: :func:`controller.settings.daemon.bus_kwargs`)
are defined once, here and there, for every verb that opens a bus; every verb opens it with
:func:`controller.daemon.openbus.open_bus`, which turns python-can's failures (an unknown
interface, a channel that does not exist, a kernel without SocketCAN) into one
:class:`controller.errors.BusError` line (exit 4).

Options are checked before any work starts: numbers by the argparse types here (:func:`positive`,
:func:`non_negative`, :func:`bounded`: argparse names the option, exit 2), output paths by
:func:`check_output_file` and :func:`check_output_folder` (an empty path, a path under a file, a
folder where a file is wanted or the other way round, a folder that cannot be written: one
:class:`controller.errors.InputError` line naming the option, exit 3), so that a run is never lost
at its end to a mistake in its command line.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import importlib.util
import json
import logging
import math
import os
import signal
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterator, Sequence

EXTRAS: dict[str, tuple[str, ...]] = {
    "sim": ("pybullet",),
    "research": ("matplotlib", "tqdm", "dask", "gymnasium"),
}
"""Each optional extra of the package (``pip install 'elegant-stepping[NAME]'``) and the top-level
modules it brings; the core install (the leg) has none of them."""


@dataclass(frozen=True)
class Verb:
    """One command of a command line.

    Attributes:
        name: the verb as typed (``run``, ``learn``, ``config``).
        module: the module with ``add_arguments(parser)`` and ``run(args) -> int``.
        help: one line for ``--help``.
        needs: the extras (keys of :data:`EXTRAS`) the verb cannot run without; default none.
    """

    name: str
    module: str
    help: str
    needs: tuple[str, ...] = ()


def missing_modules(needs: Sequence[str]) -> dict[str, list[str]]:
    """The extras among ``needs`` with a module that cannot be imported here, and those modules."""
    out = {}
    for extra in needs:
        absent = [m for m in EXTRAS[extra] if importlib.util.find_spec(m) is None]
        if absent:
            out[extra] = absent
    return out


def missing_extras(needs: Sequence[str]) -> list[str]:
    """The extras among ``needs`` with a module that cannot be imported here."""
    return list(missing_modules(needs))


def positive(kind: Callable[[str], Any]) -> Callable[[str], Any]:
    """An argparse type: a finite number above zero."""

    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be a positive number, got {text!r}") from None
        if not (math.isfinite(value) and value > 0):
            raise argparse.ArgumentTypeError(f"must be a positive number, got {text!r}")
        return value

    return parse


def non_negative(kind: Callable[[str], Any] = int) -> Callable[[str], Any]:
    """An argparse type: a finite number at or above zero (argparse names the option in its error)."""

    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be a non-negative number, got {text!r}") from None
        if not (math.isfinite(value) and value >= 0):
            raise argparse.ArgumentTypeError(f"must be a non-negative number, got {text!r}")
        return value

    return parse


def bounded(kind: Callable[[str], Any], low: float, high: float) -> Callable[[str], Any]:
    """An argparse type: a finite number in ``[low, high]`` (argparse names the option in its error)."""

    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be a number in [{low:g}, {high:g}], got {text!r}") from None
        if not (math.isfinite(value) and low <= value <= high):
            raise argparse.ArgumentTypeError(f"must be a number in [{low:g}, {high:g}], got {text!r}")
        return value

    return parse


def _nearest_existing(path: Path) -> Path:
    """``path`` itself or its nearest ancestor that exists (``.`` at worst, for a relative path)."""
    for candidate in (path, *path.parents):
        if candidate.exists():
            return candidate
    return Path(".")


def _check_output(path: str | None, option: str, want_folder: bool) -> None:
    from controller.errors import InputError

    if path is None:
        return
    what = "folder" if want_folder else "file"
    if not str(path).strip():
        raise InputError(f"{option}: an empty path; give the {what} to write")
    p = Path(path)
    found = _nearest_existing(p)
    if found != p:  # some of the path is still to be made: the nearest existing part must be a folder
        if not found.is_dir():
            raise InputError(f"{option} {path}: {found} is a file, not a folder, so nothing can be written under it")
        if not os.access(found, os.W_OK | os.X_OK):
            raise InputError(f"{option} {path}: the folder {found} is not writable")
        return
    if want_folder and not p.is_dir():
        raise InputError(f"{option} {path}: a file, not a folder")
    if not want_folder and p.is_dir():
        raise InputError(f"{option} {path}: a folder, not a file")
    writable = p if want_folder else (p.parent if str(p.parent) else Path("."))
    if not os.access(writable, os.W_OK | os.X_OK) or (not want_folder and not os.access(p, os.W_OK)):
        raise InputError(f"{option} {path}: not writable")


def check_output_file(path: str | None, option: str) -> None:
    """Refuse, in one :class:`controller.errors.InputError` line naming ``option``, a file to write
    that cannot be: an empty path, a path under a file, an existing folder, a place not writable.
    None and ``-`` (stdout) pass. Call it before any work, so a run is not lost at its end."""
    if path != "-":
        _check_output(path, option, want_folder=False)


def check_output_folder(path: str | None, option: str) -> None:
    """Refuse, in one :class:`controller.errors.InputError` line naming ``option``, a folder to
    write into that cannot be: an empty path (it would be the current folder), a path under a
    file, an existing file, a place not writable. None passes."""
    _check_output(path, option, want_folder=True)


def add_bus_args(p: argparse.ArgumentParser) -> None:
    """``--interface``, ``--channel``, ``--bitrate``: each given one overrides the configuration
    file's ``[bus]``; without a file, what is not given comes from python-can's own configuration."""
    p.add_argument("--interface", default=None,
                   help="python-can interface (default: the configuration file's, else python-can's, else socketcan)")
    p.add_argument("--channel", default=None,
                   help="bus channel, e.g. can0 or vcan0 (default: the configuration file's, else python-can's)")
    p.add_argument("--bitrate", type=int, default=None, help="bit rate [bit/s] (ignored by vcan)")


def _raise_interrupt(signum, frame) -> None:  # noqa: ARG001
    raise KeyboardInterrupt


@contextlib.contextmanager
def sigterm_as_sigint() -> Iterator[None]:
    """Within the block SIGTERM stops the verb as Ctrl-C does (a ``KeyboardInterrupt``), so a run
    killed politely keeps what finished and resumes like an interrupted one; the previous handler
    is put back after."""
    previous = signal.signal(signal.SIGTERM, _raise_interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def write_json(path: str | None, data: Any, option: str = "--json") -> None:
    """``data`` as indented JSON to ``path`` (atomically, creating its folder), or stdout for None or
    ``-``. A path that cannot be written is an :class:`controller.errors.InputError` naming
    ``option`` (the verb should have checked it before its work with :func:`check_output_file`)."""
    from controller.atomic import write_json_atomic
    from controller.errors import InputError

    if path in (None, "-"):
        print(json.dumps(data, indent=2))
        return
    check_output_file(path, option)
    out = Path(path)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        write_json_atomic(out, data)
    except OSError as exc:
        raise InputError(f"{option} {path}: cannot write it: {exc.strerror or _one_line(exc)}") from None
    logging.getLogger("elegant_stepping").info("wrote %s", out)


def warn(args: argparse.Namespace, text: str) -> None:
    """One warning line on stderr, ``PROG VERB: warning: TEXT`` (a partial read, a fallback)."""
    verb = getattr(args, "_verb", None)
    prog = getattr(args, "_prog", "elegant-stepping")
    print(f"{prog}{'' if verb is None else ' ' + verb.name}: warning: {' '.join(text.split())}", file=sys.stderr)


def build_parser(prog: str, description: str, verbs: Sequence[Verb]) -> argparse.ArgumentParser:
    """The parser with one sub-parser per verb (each verb module imported, nothing heavy)."""
    parser = argparse.ArgumentParser(prog=prog, description=description)
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-vv for debug)")
    sub = parser.add_subparsers(dest="command", required=True, metavar="VERB")
    for verb in verbs:
        module = importlib.import_module(verb.module)
        p = sub.add_parser(verb.name, help=verb.help, description=verb.help)
        module.add_arguments(p)
        p.set_defaults(_verb=verb)
    return parser


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


def _file_error(exc: OSError) -> str:
    """An OSError about a path as one line naming the path and the reason."""
    where = exc.filename if exc.filename is not None else ""
    why = exc.strerror or _one_line(exc)
    return f"{where}: {why}" if where else why


BLAS_THREADS_ENV = "OPENBLAS_NUM_THREADS"


def single_threaded_blas() -> None:
    """One BLAS thread unless the environment says otherwise (``OPENBLAS_NUM_THREADS``, which
    numpy's OpenBLAS reads when numpy is first imported, so this runs before any verb imports it).

    The stack's only matrices are the range filter's 2x2 and 1x1 (filterpy): a BLAS thread pool
    never helps them and costs: OpenBLAS's idle workers spin after each call (about 1.3% of a
    learning run's CPU on a 2-core machine, issue 17), on the leg's computer a thread beside the
    control loop; sweep workers inherit the setting (no oversubscription). Results are the same
    (matrices this small are never split across threads)."""
    os.environ.setdefault(BLAS_THREADS_ENV, "1")


def main(prog: str, description: str, verbs: Sequence[Verb], argv: Sequence[str] | None = None) -> int:
    """Parse ``argv``, set up logging, check the verb's extras, run it; its exit code
    (:mod:`controller.errors`). An expected failure is one line on stderr; a bug is a traceback
    and a line saying so.

    The mapping: a :class:`controller.errors.CliError` -> its own code; ``ValueError`` (a library's
    validation) -> 3; an ``OSError`` about a path (it names the file: missing, a folder, not
    writable, a full disk) -> 3; ``KeyboardInterrupt`` (SIGINT, at start-up too: the parser is
    built and the verb's modules imported inside) -> 130; ``BrokenPipeError`` (stdout piped into a
    reader that stopped) -> 0, quietly; a missing extra -> 6; argparse's own errors -> 2 (it exits
    itself); anything else, an ``OSError`` about no path included -> 70 with the traceback."""
    code = _main(prog, description, verbs, argv)
    _forget_handled_interrupts()
    return code


def _forget_handled_interrupts() -> None:
    """Make a ``KeyboardInterrupt`` this process handled stay handled at exit.

    CPython 3.11 notes "an unhandled KeyboardInterrupt" in a flag whenever code run from a
    *string* ends in one (``run_eval_code_obj``), even code run inside a ``try`` that then handles
    it, and at exit a process with the flag set kills itself with SIGINT (return code -2, no
    traceback) instead of returning its exit code. ``dataclasses`` builds each frozen class's
    ``__setattr__`` with ``exec`` of a string, so a SIGTERM that lands while a lazily imported
    module defines one (``learn`` imports as it runs) turned a clean "stopped ... exit 130" into
    a death by SIGINT, about one stop in twenty (seen with gdb watching the flag). Every such eval
    clears the flag first, so evaluating a string that raises nothing clears it: done once, as
    the command line returns its own exit code."""
    exec("None")  # noqa: S102 - a constant string; its only effect is the flag's reset


def _main(prog: str, description: str, verbs: Sequence[Verb], argv: Sequence[str] | None) -> int:
    from controller.errors import EXIT_INPUT, EXIT_INTERRUPTED, EXIT_MISSING, EXIT_OK, CliError

    single_threaded_blas()
    name = prog
    try:
        parser = build_parser(prog, description, verbs)
        args = parser.parse_args(argv)
        verb: Verb = args._verb
        args._prog = prog
        name = f"{prog} {verb.name}"
        level = logging.WARNING - 10 * min(args.verbose, 2)
        logging.basicConfig(level=level, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
        missing = missing_modules(verb.needs)
        if missing:
            mods = ", ".join(m for absent in missing.values() for m in absent)
            print(f"{name}: needs {mods}, not installed here: pip install "
                  f"'elegant-stepping[{','.join(missing)}]' (or '.[{','.join(missing)}]' in a clone)", file=sys.stderr)
            return EXIT_MISSING
        return importlib.import_module(verb.module).run(args)
    except KeyboardInterrupt:
        print(f"{name}: interrupted; what was finished is kept", file=sys.stderr)
        return EXIT_INTERRUPTED
    except CliError as exc:
        print(f"{name}: error: {_one_line(exc)}", file=sys.stderr)
        return exc.exit_code
    except ValueError as exc:  # a library's validation (a configuration, a value out of range)
        print(f"{name}: error: {_one_line(exc)}", file=sys.stderr)
        return EXIT_INPUT
    except (FileNotFoundError, NotADirectoryError, IsADirectoryError, FileExistsError, PermissionError) as exc:
        print(f"{name}: error: {_file_error(exc)}", file=sys.stderr)
        return EXIT_INPUT
    except BrokenPipeError:  # stdout piped into a reader that stopped (``| head``): not an error
        try:
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        except (OSError, ValueError):
            pass
        return EXIT_OK
    except OSError as exc:
        if exc.filename is None:  # not about a path: a bug, or a verb that should have said more
            return _bug(name)
        print(f"{name}: error: {_file_error(exc)}", file=sys.stderr)  # a full disk, a read-only folder, ...
        return EXIT_INPUT
    except Exception:  # noqa: BLE001 - a bug: say so, with the traceback to report
        return _bug(name)


def _bug(name: str) -> int:
    """The one path with a traceback: the exception being handled, and a line saying it is a bug."""
    import traceback

    from controller.errors import EXIT_BUG

    traceback.print_exc()
    print(f"{name}: this is a bug in elegant-stepping (the traceback above); please report it", file=sys.stderr)
    return EXIT_BUG
