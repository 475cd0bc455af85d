"""Build: the hot modules compiled with mypyc, or pure Python when that cannot be done.

Everything else about the package is in ``pyproject.toml``; this file only adds the extension
modules. The list of modules, the digest and its file are :mod:`protocol.compiled`'s (loaded from
its file, not imported as ``protocol``: the build environment has none of the project's
dependencies, and that module needs none). mypy (which
holds mypyc) is pinned in ``pyproject.toml``'s ``[build-system] requires``, so pip installs it into
the isolated build environment; the C compiler and Python's headers come from the machine.

Rules:

- ``ELEGANT_STEPPING_NO_COMPILE=1`` at install time: a pure-Python install, no mypyc at all.
- mypyc cannot be imported, or it refuses the sources (a type error), or the C compiler fails:
  the install still succeeds, pure Python, with one warning line on stderr beginning
  ``elegant-stepping: WARNING:`` (pip shows a build's output with ``-v`` only). No half-compiled
  install: either every extension is built or none is kept.
- A successful build writes protocol/compiled_sources.sha256 (the digest of the compiled sources):
  at run time, sources that differ from it (an edited editable install) run as pure Python, with
  a warning, instead of the old extensions (:func:`protocol.compiled.stale`).
- The results never depend on it: ``ELEGANT_STEPPING_PURE_PYTHON=1`` at run time imports the
  ``.py`` files of a compiled install (:mod:`protocol.compiled`), and a test compares both.
"""

from __future__ import annotations

import importlib.util
import os
import sys
from pathlib import Path

from setuptools import setup
from setuptools.command.build_ext import build_ext

HERE = Path(__file__).resolve().parent
WARNING = "elegant-stepping: WARNING: installing pure Python (slower, same results): "


def _load_compiled_rules():
    """protocol/compiled.py, loaded from its file (it imports the standard library only, so it
    runs in the build environment, which has none of the project's dependencies): the one place
    that lists the hot modules, names the digest file and computes the digest."""
    spec = importlib.util.spec_from_file_location("_elegant_stepping_compiled", HERE / "protocol" / "compiled.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


RULES = _load_compiled_rules()


def _warn(why: str) -> None:
    print(WARNING + " ".join(str(why).split())[:300], file=sys.stderr, flush=True)


def ext_modules() -> list:
    if os.environ.get("ELEGANT_STEPPING_NO_COMPILE", "") == "1":
        return []
    paths = [m.replace(".", "/") + ".py" for m in RULES.HOT_MODULES]
    old_cwd = os.getcwd()
    try:
        os.chdir(HERE)  # mypyc names the modules after the paths it is given
        from mypyc.build import mypycify

        return mypycify(["--ignore-missing-imports", "--follow-imports=silent", *paths],
                        opt_level="3", debug_level="0")
    except BaseException as exc:  # noqa: BLE001 - mypyc reports type errors with SystemExit
        if isinstance(exc, KeyboardInterrupt):
            raise
        _warn(f"mypyc could not compile the hot modules ({type(exc).__name__}: {exc})")
        return []
    finally:
        os.chdir(old_cwd)


PACKAGES = ("protocol", "firmware_sim", "controller", "hil")


def _remove_old_extensions() -> None:
    """Delete the extensions an earlier build left in the source tree (an editable install builds
    in place): a module dropped from HOT_MODULES would otherwise still import compiled, linked to
    the old build's shared library (and so to its own copies of the other modules' classes)."""
    old = [*HERE.glob("*__mypyc.*.so")]
    for package in PACKAGES:
        old += (HERE / package).rglob("*.cpython-*.so")
    for path in old:
        path.unlink()


class BuildExtOrPure(build_ext):
    """build_ext that falls back to no extensions when the C compiler fails (never half of them),
    and writes the digest of the compiled sources beside protocol/compiled.py when it succeeds."""

    def _digest_path(self) -> Path:
        return (HERE if self.inplace else Path(self.build_lib)) / "protocol" / RULES.DIGEST_FILE

    def run(self) -> None:
        _remove_old_extensions()
        if not self.extensions:
            return
        try:
            super().run()
        except Exception as exc:  # noqa: BLE001 - CompileError, LinkError, a missing compiler
            _warn(f"the C compiler failed on the mypyc output ({type(exc).__name__}: {exc})")
            for ext in self.extensions:
                for where in (self.get_ext_fullpath(ext.name),):
                    if os.path.exists(where):
                        os.remove(where)
            self.extensions = []
            return
        where = self._digest_path()
        where.parent.mkdir(parents=True, exist_ok=True)
        where.write_text(RULES.sources_digest(HERE) + "\n", encoding="ascii")

    def get_outputs(self) -> list[str]:
        return [*super().get_outputs(), str(self._digest_path())] if self.extensions else []


setup(ext_modules=ext_modules(), cmdclass={"build_ext": BuildExtOrPure})
