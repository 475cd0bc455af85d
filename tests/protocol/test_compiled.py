"""The compiled hot modules (mypyc) and their pure-Python fallback (:mod:`protocol.compiled`).

The rule for "compiled or not": an install compiles every module of ``HOT_MODULES`` or none (the
build falls back to pure Python whole when mypyc or the C compiler fails), so a test here fails on
a half-compiled install. Whether the install MUST be compiled is not guessed from the machine:
``ELEGANT_STEPPING_EXPECT_COMPILED=1`` (set by CI, where mypy comes from the registry and gcc is
present) makes a pure install fail :func:`test_install_is_compiled_when_expected` loudly; without it
that test checks only the all-or-none rule. Either way the two modes must give identical records:
each run happens in its own process (the mode is chosen at import), ``ELEGANT_STEPPING_PURE_PYTHON=1``
in one of them.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from protocol.compiled import HOT_MODULES, PURE_PYTHON_ENV, expected_compiled, sources_digest, stale

ROOT = Path(__file__).resolve().parents[2]
_REPORT = "import json; from protocol.compiled import compiled_modules; print(json.dumps(compiled_modules()))"


def _env(pure: bool) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k != PURE_PYTHON_ENV}
    if pure:
        env[PURE_PYTHON_ENV] = "1"
    return env


def _compiled_in_child(pure: bool) -> list[str]:
    done = subprocess.run([sys.executable, "-c", _REPORT], capture_output=True, text=True, cwd=ROOT,
                          env=_env(pure), timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_every_hot_module_has_its_source_beside_it() -> None:
    for name in HOT_MODULES:
        assert (ROOT / (name.replace(".", "/") + ".py")).is_file(), name


def test_stale_when_a_source_differs_from_the_compiled_digest(tmp_path: Path) -> None:
    for name in HOT_MODULES:
        source = tmp_path / (name.replace(".", "/") + ".py")
        source.parent.mkdir(parents=True, exist_ok=True)
        source.write_text(f"X = {name!r}\n")
    digest = tmp_path / "digest"
    assert not stale(digest, tmp_path)  # no digest: a pure install, nothing to compare
    digest.write_text(sources_digest(tmp_path) + "\n")
    assert not stale(digest, tmp_path)
    (tmp_path / (HOT_MODULES[-1].replace(".", "/") + ".py")).write_text("X = 'edited'\n")
    assert stale(digest, tmp_path)
    (tmp_path / (HOT_MODULES[0].replace(".", "/") + ".py")).unlink()
    assert stale(digest, tmp_path)  # a source gone: never run the old extension


def test_every_class_of_a_hot_module_keeps_its_bases() -> None:
    """mypyc drops a base class it cannot resolve at build time (an import it did not find is Any),
    silently: a compiled ``LocalBus`` was once no ``BusABC`` at all. Every class a hot module
    defines must have each base its source names in its MRO, compiled or not."""
    import ast
    import importlib

    checked = 0
    for name in HOT_MODULES:
        module = importlib.import_module(name)
        tree = ast.parse((ROOT / (name.replace(".", "/") + ".py")).read_text())
        for node in ast.walk(tree):
            if not isinstance(node, ast.ClassDef) or not hasattr(module, node.name):
                continue
            cls = getattr(module, node.name)
            for expr in node.bases:
                base = eval(ast.unparse(expr), vars(module))  # noqa: S307 - the module's own source
                if isinstance(base, type):  # (typing.NamedTuple is a function: its class is a tuple)
                    assert base in cls.__mro__, (f"{name}.{node.name} lost its base {ast.unparse(expr)} "
                                                 f"(MRO {cls.__mro__}): was the install compiled without it?")
                    checked += 1
    assert checked >= 8  # LocalBus, Frame, Tally, Phase, Lockstep, the Protocols


def test_pure_python_switch_imports_only_sources() -> None:
    assert _compiled_in_child(pure=True) == []


def test_install_is_compiled_when_expected() -> None:
    compiled = _compiled_in_child(pure=False)
    if expected_compiled():
        assert compiled == list(HOT_MODULES), (
            "ELEGANT_STEPPING_EXPECT_COMPILED=1 but the install runs these hot modules as pure Python: "
            f"{sorted(set(HOT_MODULES) - set(compiled))} (did mypyc or gcc fail at install? look for "
            "'elegant-stepping: WARNING:' in the pip output)")
    else:
        assert compiled in ([], list(HOT_MODULES)), f"half-compiled install: {compiled}"


@pytest.mark.slow
def test_learning_records_identical_compiled_and_pure(tmp_path: Path) -> None:
    from hil.analysis.records import compare

    runs = {}
    for mode in ("compiled", "pure"):
        out = tmp_path / mode
        done = subprocess.run(
            [sys.executable, "-m", "hil.cli", "learn", "--trials", "3", "--seed", "2", "--no-figures", "--quiet",
             "--out", str(out)],
            capture_output=True, text=True, cwd=ROOT, env=_env(mode == "pure"), timeout=600)
        assert done.returncode == 0, done.stderr[-2000:]
        runs[mode] = json.loads((out / "metrics.json").read_text())
    result = compare(runs["compiled"], runs["pure"])
    assert result["trials"] == [3, 3]
    assert result["same"], result
