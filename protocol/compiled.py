"""Which hot modules run compiled (mypyc), and the switch that runs them all as pure Python.

**What is compiled.** An install (``pip install .`` or ``pip install -e .``) compiles the modules
of :data:`HOT_MODULES` with mypyc (``setup.py`` reads the list from this file), each to an
extension module (``.so``) beside its ``.py``; Python's import system prefers the extension, so
every process runs them compiled. The ``.py`` files are kept: they are the source and the
fallback. The other modules are never compiled. An install whose compiler or mypyc fails is
pure Python (``setup.py`` prints one warning line, which pip shows with ``-v``; the test of the
compiled build fails loudly where CI expects it compiled); results are the same either way, only slower.

**The switch.** With ``ELEGANT_STEPPING_PURE_PYTHON=1`` in the environment every process imports
the ``.py`` of each hot module instead of its extension: :func:`install_pure_python_finder` puts a
finder at the front of ``sys.meta_path`` that, for exactly the names in :data:`HOT_MODULES`, returns
the ``.py`` beside the extension. Each top-level package (``protocol``, ``firmware_sim``,
``controller``, ``hil``) calls it first thing in its ``__init__``, and Python always runs a
package's ``__init__`` before any of its modules, so no hot module can be imported compiled before
the finder is in place; child processes (the process pool, Dask workers) inherit the variable and
do the same. Any other value (or none) leaves the import system alone, unless the extensions
are stale (:func:`stale`: a hot module's ``.py`` changed since the install compiled it, as an
editable install's sources do): then the finder is installed too, with one warning, so an edit is
never silently shadowed by the old extension.

:func:`compiled_modules` says which hot modules this process runs compiled (for ``bench`` to write
beside its figures); :func:`expected_compiled` is the rule the test of the compiled build uses.

May import: the standard library only (it runs before anything else of the project, and
``setup.py`` loads it in the build environment).
"""

from __future__ import annotations

import hashlib
import importlib.abc
import importlib.machinery
import importlib.util
import logging
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Sequence, TypeVar

_C = TypeVar("_C", bound=type)

#: The environment variable that makes every process run the hot modules as pure Python.
PURE_PYTHON_ENV = "ELEGANT_STEPPING_PURE_PYTHON"

#: Written by ``setup.py`` beside this file when it compiles: :func:`sources_digest` of the sources
#: it compiled (git-ignored; absent in a pure install).
DIGEST_FILE = "compiled_sources.sha256"

#: The modules an install compiles with mypyc: the hot path of a lockstep run, less those that
#: gain little. A class of one of them that code outside subclasses (``Lockstep``, ``RigPlant``)
#: carries :func:`mypyc_attr` ``(allow_interpreted_subclasses=True)``; a class that must stay a
#: Python class (a configuration, ``protocol.frame.Frame``: a ``can.Message``) carries
#: :func:`interpreted`.
HOT_MODULES: tuple[str, ...] = (
    "firmware_sim.odrive_axis",
    "firmware_sim.node_host",
    "firmware_sim.sensor_board",
    "firmware_sim.motor",
    "firmware_sim.thermal",
    "firmware_sim.leg",
    "controller.loop",
    "controller.io.bus",
    "controller.io.axis",
    "controller.io.sensors",
    "controller.supervisor",
    "controller.motion.cpg",
    "controller.motion.kinematics",
    "controller.stepping.encoder",
    "controller.stepping.learner",
    "controller.stepping.range_filter",
    "controller.stepping.reflexes",
    "controller.stepping.height",
    "controller.stepping.context",
    "protocol.contract",
    "hil.lockstep.localbus",
    "hil.lockstep.groundtruth",
    "hil.lockstep.harness",
    "firmware_sim.plant",
    "controller.motion.gait",
    "controller.motion.muscle",
    "controller.io.health",
    "protocol.frame",
)


def interpreted(cls: _C) -> _C:
    """Class decorator (identity): keep a class of a compiled module an ordinary Python class.

    mypyc compiles a class with any decorator other than ``dataclass`` as a plain Python class;
    this is that decorator. Every configuration dataclass of a hot module carries it, because a
    native class checks and converts field types in its constructor (a ``str`` given for a
    ``float`` raises TypeError before ``__post_init__`` can refuse it with the ValueError, and exit
    code, the project promises; an ``int`` becomes a ``float``): configurations then behave exactly
    as in pure Python. Per-tick records stay native (they are what compiling speeds up)."""
    return cls


if TYPE_CHECKING:
    from mypy_extensions import mypyc_attr
else:
    def mypyc_attr(*attrs: str, **kwattrs: Any) -> Callable[[_C], _C]:
        """``mypy_extensions.mypyc_attr`` for the runtime (identity): mypyc reads the decorator from
        the source when it compiles (it knows it by that name, which is what type checkers see
        here) and never calls it; pure Python calls this one, so ``mypy_extensions`` (a build
        requirement, not a dependency) need not be installed. The hot modules use it for
        ``allow_interpreted_subclasses=True``: a native class refuses Python subclasses without it."""
        return lambda cls: cls


def pure_python_requested() -> bool:
    """True when ``ELEGANT_STEPPING_PURE_PYTHON`` is ``1``."""
    return os.environ.get(PURE_PYTHON_ENV, "") == "1"


class _PurePythonFinder(importlib.abc.MetaPathFinder):
    """Finds the ``.py`` of a hot module (never its extension); defers every other name."""

    def find_spec(self, fullname: str, path: Sequence[str] | None = None, target: object = None):
        if fullname not in HOT_MODULES:
            return None
        leaf = fullname.rpartition(".")[2] + ".py"
        for entry in path if path is not None else sys.path:
            candidate = os.path.join(entry or ".", leaf)
            if os.path.isfile(candidate):
                return importlib.util.spec_from_file_location(
                    fullname, candidate, loader=importlib.machinery.SourceFileLoader(fullname, candidate))
        return None


def sources_digest(root: Path | None = None) -> str:
    """SHA-256 over the sources of :data:`HOT_MODULES` (names and bytes) under ``root`` (the folder
    holding the packages; default: where this file's package is). ``setup.py`` writes it at build time."""
    root = Path(__file__).resolve().parents[1] if root is None else root
    h = hashlib.sha256()
    for name in HOT_MODULES:
        h.update(name.encode() + b"\0")
        h.update((root / (name.replace(".", "/") + ".py")).read_bytes())
    return h.hexdigest()


def stale(digest_file: Path | None = None, root: Path | None = None) -> bool:
    """True when the extensions were built from other sources than the ``.py`` files now beside
    them (an editable install whose hot module was edited, or a checkout of another commit): the
    digest ``setup.py`` wrote at build time (:data:`DIGEST_FILE`) differs from the sources'. No
    digest file (a pure install): False. ``digest_file`` and ``root``: another install's (tests)."""
    recorded = Path(__file__).resolve().parent / DIGEST_FILE if digest_file is None else digest_file
    try:
        expected = recorded.read_text(encoding="ascii").strip()
    except OSError:
        return False
    try:
        return sources_digest(root) != expected
    except OSError:
        return True


_decided_pure: bool | None = None
"""What :func:`install_pure_python_finder` decided in this process (None: not asked yet)."""


def install_pure_python_finder() -> bool:
    """Put the pure-Python finder first on ``sys.meta_path`` (once per process) with
    ``ELEGANT_STEPPING_PURE_PYTHON=1``, or when the compiled modules are :func:`stale` (then with
    one warning: the ``.py`` files are what the user means to run, and a mix of old compiled and
    new pure modules is never run); returns whether it is installed."""
    global _decided_pure
    if _decided_pure is not None:  # decided once per process: each package's __init__ asks, and
        return _decided_pure      # stale() reads and hashes every hot source
    if not pure_python_requested():
        if not stale():
            _decided_pure = False
            return False
        logging.getLogger(__name__).warning(
            "the compiled hot modules were built from other sources than these: running pure Python "
            "(reinstall, e.g. pip install -e ., to compile them again)")
    sys.meta_path.insert(0, _PurePythonFinder())
    _decided_pure = True
    return True


def _is_compiled(module: object) -> bool:
    return isinstance(getattr(module, "__loader__", None), importlib.machinery.ExtensionFileLoader) or str(
        getattr(module, "__file__", "") or "").endswith(tuple(importlib.machinery.EXTENSION_SUFFIXES))


def compiled_modules() -> list[str]:
    """The hot modules this process runs compiled (imports each to find out; [] when pure)."""
    out = []
    for name in HOT_MODULES:
        module = importlib.import_module(name)
        if _is_compiled(module):
            out.append(name)
    return out


def expected_compiled() -> bool:
    """Whether this install must be compiled: ``ELEGANT_STEPPING_EXPECT_COMPILED=1`` (set by CI,
    whose machine has a C compiler and reaches the package registry for mypy) says so."""
    return os.environ.get("ELEGANT_STEPPING_EXPECT_COMPILED", "") == "1"
