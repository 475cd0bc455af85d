"""filterpy's ``KalmanFilter`` without the rest of filterpy, and without scipy, at import.

**Why.** ``from filterpy.kalman import KalmanFilter`` runs ``filterpy/__init__.py``, which imports
every filterpy subpackage (the EKF, UKF, IMM, discrete Bayes, ...) and with them scipy.stats,
scipy.linalg, scipy.sparse and scipy.ndimage: about 1 s of CPU, two thirds of importing
:mod:`hil.experiments.learn` (issue 17), paid by every ``learn``, every sweep worker process and
the leg's controller. The range filter needs only the ``KalmanFilter`` class, whose module imports
numpy and two things from filterpy: ``pretty_str`` and ``reshape_z`` (``filterpy/common/helpers.py``,
numpy only) and ``logpdf`` (``filterpy.stats``, scipy), the latter used only by the likelihood
properties (``log_likelihood``, ``likelihood``, ``log_likelihood_of``), never by predict or update.

**How.** The installed filterpy is located with :func:`importlib.util.find_spec` (which finds the
package without running it). Its own ``kalman/kalman_filter.py`` and ``common/helpers.py`` are
read, parsed, checked (below), compiled under their real file names (so tracebacks, cProfile and
py-spy name filterpy's files and lines, and ``bench --profile`` counts them as the range filter)
and executed each in a private namespace, with the two ``from filterpy... import`` statements of
``kalman_filter.py`` replaced by a ``pass`` on the same line and their names given instead:
``pretty_str`` and ``reshape_z`` from the helpers just loaded, and ``logpdf`` as :func:`_logpdf`,
which imports ``filterpy.stats`` (and so scipy) on its first call and hands over to filterpy's.
Nothing else is changed: every line of the class is filterpy's, so are its numbers (a test
compares it with ``filterpy.kalman.KalmanFilter`` bit for bit).

**Checks, and what happens when they fail.** Every import statement of the two files, at any
depth, must be of the standard library, numpy or ``__future__``, except exactly those two of
``kalman_filter.py`` (at its top level, importing no name but ``logpdf`` from ``filterpy.stats``
and ``pretty_str``/``reshape_z`` from ``filterpy.common``); no relative imports; the result must
define a class ``KalmanFilter``. If anything differs (a filterpy release that moved or added an
import, a missing file, a syntax this Python cannot compile, an error running either file), this
module does the ordinary ``from filterpy.kalman import KalmanFilter`` instead and logs a WARNING
giving the reason: the numbers are the same either way, only the import costs what it did. :data:`LIGHT` tells which
was done; the tests assert the light one with the filterpy that ``constraints.txt`` pins, so an
upgrade that breaks it fails CI rather than quietly costing a second per process.

**Consequences.** The class is not the object ``filterpy.kalman.KalmanFilter`` (an ``isinstance``
against filterpy's class is False); it pickles as ``controller.stepping.filterpy_kf.KalmanFilter``.
:data:`sys.modules` is not touched: code that imports filterpy gets the whole package as always.
"""

from __future__ import annotations

import ast
import builtins
import importlib.util
import logging
import sys
from pathlib import Path
from typing import Any, Callable

log = logging.getLogger(__name__)

_REPLACED: dict[str, frozenset[str]] = {
    "filterpy.stats": frozenset({"logpdf"}),
    "filterpy.common": frozenset({"pretty_str", "reshape_z"}),
}
"""The imports from filterpy that ``kalman/kalman_filter.py`` may make, module -> names; each is
replaced by names this module provides."""

_FREE = frozenset({"__future__", "numpy"}) | frozenset(sys.stdlib_module_names)
"""Top-level packages the two files may import as they are: cheap, and nothing of filterpy's."""


class _Unexpected(Exception):
    """The installed filterpy is not shaped as this module expects."""


def _logpdf(*args: Any, **kwargs: Any) -> Any:
    """``filterpy.stats.logpdf``, imported on the first call (it imports scipy.stats): only the
    likelihood properties of the filter call it."""
    from filterpy.stats import logpdf

    return logpdf(*args, **kwargs)


def _imports(tree: ast.Module, path: Path) -> list[tuple[ast.stmt, str, frozenset[str]]]:
    """Every import statement of ``tree`` as (node, module, names imported); raises
    :class:`_Unexpected` for a relative import."""
    found: list[tuple[ast.stmt, str, frozenset[str]]] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                found.append((node, alias.name, frozenset()))
        elif isinstance(node, ast.ImportFrom):
            if node.level or node.module is None:
                raise _Unexpected(f"{path} has a relative import (line {node.lineno})")
            found.append((node, node.module, frozenset(a.name for a in node.names)))
    return found


def _execute(path: Path, tree: ast.Module, namespace: dict[str, Any]) -> dict[str, Any]:
    namespace.setdefault("__name__", __name__)
    namespace.update({"__file__": str(path), "__builtins__": builtins})
    try:
        exec(compile(tree, str(path), "exec", dont_inherit=True), namespace)  # noqa: S102 (filterpy's own code)
    except Exception as e:  # noqa: BLE001 (whatever it is, the ordinary import is tried next and says it again)
        raise _Unexpected(f"running {path} failed: {type(e).__name__}: {e}") from e
    return namespace


def _parse(path: Path) -> ast.Module:
    try:
        return ast.parse(path.read_bytes(), str(path))
    except (OSError, SyntaxError, ValueError) as e:
        raise _Unexpected(f"cannot read {path}: {e}") from None


def _package_dir() -> Path:
    """The installed filterpy's directory, found without running its ``__init__``."""
    spec = importlib.util.find_spec("filterpy")
    if spec is None:
        raise ModuleNotFoundError("No module named 'filterpy'", name="filterpy")
    if not spec.submodule_search_locations:
        raise _Unexpected(f"filterpy at {spec.origin} is not a package directory")
    return Path(next(iter(spec.submodule_search_locations)))


def _load_light() -> type:
    """filterpy's ``KalmanFilter`` class, loaded as the module docstring says; raises
    :class:`_Unexpected` where the installed filterpy differs from what that needs."""
    root = _package_dir()
    helpers_path = root / "common" / "helpers.py"
    helpers_tree = _parse(helpers_path)
    for node, module, _ in _imports(helpers_tree, helpers_path):
        if module.partition(".")[0] not in _FREE:
            raise _Unexpected(f"{helpers_path} line {node.lineno} imports {module}")
    helpers = _execute(helpers_path, helpers_tree, {})

    kf_path = root / "kalman" / "kalman_filter.py"
    kf_tree = _parse(kf_path)
    given: dict[str, Callable[..., Any]] = {"logpdf": _logpdf}
    replaced: set[str] = set()
    for node, module, names in _imports(kf_tree, kf_path):
        if module.partition(".")[0] in _FREE:
            continue
        if module not in _REPLACED or not names <= _REPLACED[module] or node not in kf_tree.body:
            raise _Unexpected(f"{kf_path} line {node.lineno} imports {module} ({', '.join(sorted(names)) or 'whole'})")
        kf_tree.body[kf_tree.body.index(node)] = ast.copy_location(ast.Pass(), node)
        for name in names:
            if name != "logpdf":
                if name not in helpers:
                    raise _Unexpected(f"{helpers_path} defines no {name}")
                given[name] = helpers[name]
            replaced.add(name)
    namespace = _execute(kf_path, kf_tree, {name: given[name] for name in replaced})
    cls = namespace.get("KalmanFilter")
    if not isinstance(cls, type):
        raise _Unexpected(f"{kf_path} defines no class KalmanFilter")
    return cls  # its __module__ is this module's (the namespace's __name__): it pickles as found here


def _load() -> tuple[type, bool]:
    try:
        return _load_light(), True
    except _Unexpected as e:
        log.warning("filterpy's KalmanFilter is imported with all of filterpy and scipy (about 1 s of CPU) "
                    "because the installed filterpy is not as controller.stepping.filterpy_kf expects: %s", e)
    from filterpy.kalman import KalmanFilter as full

    return full, False


KalmanFilter, LIGHT = _load()
"""``KalmanFilter``: filterpy's class. ``LIGHT``: True where it was loaded without the rest of
filterpy (the usual case), False where the whole package was imported (a WARNING says why)."""

__all__ = ["KalmanFilter", "LIGHT"]
