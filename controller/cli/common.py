"""What every command line here shares: the verb registry's shape, the bus arguments, JSON output.

Both console scripts, the leg's ``elegant-stepping-leg`` (:mod:`controller.cli`) and the
harness's ``elegant-stepping`` (:mod:`hil.cli`), are a list of :class:`Verb` run by :func:`main`.
A verb is one module with two functions, ``add_arguments(parser)`` and ``run(args) -> int``; the
module imports only the standard library at its top (what it needs is imported inside ``run``),
so building the parser imports no simulation, plotting or cluster library. A verb names the
extras it needs (:data:`EXTRAS`); where one is not installed, :func:`main` says which to install,
in one line, before importing anything of it.

Exit codes shared by every verb: 0 done, 1 the job ran and failed (a check failed, a fault), 2 bad
input (an option, a configuration, a file) or a missing extra, each with one line on stderr.
The bus arguments (:func:`add_bus_args`) and their precedence (command line over the
configuration file over python-can's own configuration: :func:`controller.settings.daemon.bus_kwargs`)
are defined once, here and there, for every verb that opens a bus.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import json
import logging
import math
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Sequence

EXTRAS: dict[str, tuple[str, ...]] = {
    "sim": ("pybullet",),
    "research": ("matplotlib", "tqdm", "dask"),
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


def add_bus_args(p: argparse.ArgumentParser) -> None:
    """``--interface``, ``--channel``, ``--bitrate``: each given one overrides the configuration
    file's ``[bus]``; without a file, what is not given comes from python-can's own configuration."""
    p.add_argument("--interface", default=None,
                   help="python-can interface (default: the configuration file's, else python-can's, else socketcan)")
    p.add_argument("--channel", default=None,
                   help="bus channel, e.g. can0 or vcan0 (default: the configuration file's, else python-can's)")
    p.add_argument("--bitrate", type=int, default=None, help="bit rate [bit/s] (ignored by vcan)")


def write_json(path: str | None, data: Any) -> None:
    """``data`` as indented JSON to ``path`` (atomically, creating its folder), or stdout for None or ``-``."""
    from controller.atomic import write_json_atomic

    if path in (None, "-"):
        print(json.dumps(data, indent=2))
        return
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    write_json_atomic(out, data)
    logging.getLogger("elegant_stepping").info("wrote %s", out)


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


def main(prog: str, description: str, verbs: Sequence[Verb], argv: Sequence[str] | None = None) -> int:
    """Parse ``argv``, set up logging, check the verb's extras, run it; its exit code."""
    parser = build_parser(prog, description, verbs)
    args = parser.parse_args(argv)
    verb: Verb = args._verb
    level = logging.WARNING - 10 * min(args.verbose, 2)
    logging.basicConfig(level=level, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    missing = missing_modules(verb.needs)
    if missing:
        mods = ", ".join(m for absent in missing.values() for m in absent)
        print(f"{prog} {verb.name}: needs {mods}, not installed here: pip install "
              f"'elegant-stepping[{','.join(missing)}]' (or '.[{','.join(missing)}]' in a clone)", file=sys.stderr)
        return 2
    try:
        return importlib.import_module(verb.module).run(args)
    except (ValueError, FileNotFoundError) as exc:
        print(f"{prog} {verb.name}: error: {exc}", file=sys.stderr)
        return 2
