"""The house rules of the design card, checked over every package and sub-package:

- who may import whom (``controller`` and ``firmware_sim`` never each other, nor ``hil``);
- the leg's install: every module of ``controller`` imports, in a fresh interpreter, nothing of
  ``hil``, ``firmware_sim``, pybullet, matplotlib, tqdm or dask;
- no import cycles, deferred imports included;
- every package says in its docstring what it is for and what it may import;
- at most five modules at the top of ``controller/`` and ``hil/`` (the rest in sub-packages by
  role), no module beside a folder of the same name;
- the tests mirror the packages.
"""

from __future__ import annotations

import ast
import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ["protocol", "urdf", "firmware_sim", "controller", "hil"]
FORBIDDEN = {
    "controller": {"firmware_sim", "hil", "pybullet", "matplotlib", "tqdm", "dask"},
    "firmware_sim": {"controller", "hil"},
    "protocol": {"controller", "firmware_sim", "hil"},
    "urdf": {"controller", "firmware_sim", "hil", "protocol"},
}
LEG_NEVER = ("hil", "firmware_sim", "pybullet", "matplotlib", "tqdm", "dask", "distributed")


def modules(package: str) -> dict[str, Path]:
    """Every module of ``package`` by dotted name (``__init__`` as the package's own name)."""
    out = {}
    for path in sorted((ROOT / package).rglob("*.py")):
        parts = list(path.relative_to(ROOT).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        if "__pycache__" not in parts:
            out[".".join(parts)] = path
    return out


def imports(path: Path, module: str, top_level_only: bool = False) -> set[str]:
    """The module names ``path`` imports (``from x import y``: ``x`` and ``x.y``); at module level
    only (what runs on import, ``if TYPE_CHECKING`` blocks aside) with ``top_level_only``."""
    tree = ast.parse(path.read_text(), filename=str(path))
    nodes = tree.body if top_level_only else list(ast.walk(tree))
    found = set()
    for node in nodes:
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            assert node.level == 0, f"{module}: relative import (the house uses absolute imports only)"
            base = node.module or ""
            found.add(base)
            found.update(f"{base}.{alias.name}" for alias in node.names)
    return found


@pytest.mark.parametrize("package", sorted(FORBIDDEN))
def test_package_imports_stay_inside_their_boundary(package):
    mods = modules(package)
    assert mods, f"{package}/ has no modules"
    for name, path in mods.items():
        bad = {i.split(".")[0] for i in imports(path, name)} & FORBIDDEN[package]
        assert not bad, f"{path.relative_to(ROOT)} imports {sorted(bad)}"


def test_the_leg_install_imports_nothing_of_the_harness_or_the_research_extras():
    """Every module of controller/ (the daemon, every leg verb, bring-up, settings), the leg's
    console script's parser, imported in a fresh interpreter: sys.modules holds none of them."""
    names = sorted(m for m in modules("controller") if not m.endswith("__main__"))
    code = (
        "import importlib, json, sys\n"
        f"for name in {names!r}:\n"
        "    importlib.import_module(name)\n"
        "from controller.cli import VERBS\n"
        "from controller.cli.common import build_parser\n"
        "build_parser('elegant-stepping-leg', '', VERBS).parse_args(['config', 'show'])\n"
        "print(json.dumps(sorted(sys.modules)))\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    loaded = json.loads(done.stdout.strip().splitlines()[-1])
    bad = sorted(m for m in loaded if m.split(".")[0] in LEG_NEVER)
    assert not bad, f"the leg's code path imports {bad}"
    assert "controller.daemon.run" in loaded and "controller.cli.run" in loaded


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in graph:
        if v not in index:
            visit(v)
    return out


def test_no_import_cycles():
    """Not at module level, nor through imports deferred into functions or ``if TYPE_CHECKING``
    blocks: a cycle of deferred imports is still two modules that need each other."""
    every = {}
    for package in PACKAGES:
        every.update(modules(package))
    graph = {}
    for name, path in every.items():
        deps = set()
        for imported in imports(path, name):
            if imported in every and imported != name:
                deps.add(imported)
        graph[name] = deps
    assert _cycles(graph) == []


@pytest.mark.parametrize("package", PACKAGES + sorted(
    str(p.parent.relative_to(ROOT)).replace("/", ".") for pkg in ("controller", "hil", "firmware_sim", "protocol")
    for p in (ROOT / pkg).rglob("__init__.py") if p.parent != ROOT / pkg))
def test_each_package_says_what_it_is_for_and_what_it_may_import(package):
    path = ROOT / package.replace(".", "/") / "__init__.py"
    doc = ast.get_docstring(ast.parse(path.read_text()))
    assert doc and "import" in doc.lower() and "to be described" not in doc, f"{path.relative_to(ROOT)}"


@pytest.mark.parametrize("package", ["controller", "hil"])
def test_few_modules_at_the_top_and_none_beside_a_folder_of_its_name(package):
    top = [p for p in (ROOT / package).glob("*.py") if p.name != "__init__.py"]
    assert len(top) <= 5, sorted(p.name for p in top)
    for path in (ROOT / package).rglob("*.py"):
        assert not (path.with_suffix("")).is_dir(), f"{path.relative_to(ROOT)} stands beside a folder of its name"


def test_the_tests_mirror_the_packages():
    for folder in sorted(p for p in (ROOT / "tests").rglob("*") if p.is_dir() and p.name != "__pycache__"):
        rel = folder.relative_to(ROOT / "tests")
        if rel.parts[0] == "vcan" or not any(folder.glob("*.py")):  # a data folder (e.g. golden records)
            continue
        assert (ROOT / rel / "__init__.py").exists(), f"tests/{rel} mirrors no package ({rel} is not one)"
