"""Same records? Two runs of one experiment compared field for field, wall-clock figures aside.

The house rule "a refactor proves itself by identical records before and after" is checked with
this: run the experiment on the old commit (a ``git worktree``) and on the new one with the same
seed, then ``elegant-stepping compare OLD NEW``. A learn output folder (or its ``metrics.json``) is
compared trial by trial (every field of every trial, traces included) and by its summary; any other
JSON (``walk --json``, ``bench``) as a whole. Fields that measure the host rather than the run
(:data:`WALL_CLOCK`) are left out everywhere; so is the ``config`` section of a learn run (a new
field with its default is not a new behaviour; the records say whether behaviour changed).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

WALL_CLOCK = frozenset({"wall_s", "trials_per_minute", "elapsed_s", "cpu_s", "timing"})
"""Keys whose values depend on the host's speed and load, not on the run."""


def _strip(x: Any) -> Any:
    if isinstance(x, dict):
        return {k: _strip(v) for k, v in x.items() if k not in WALL_CLOCK}
    if isinstance(x, list):
        return [_strip(v) for v in x]
    return x


def read(path: str | Path) -> Any:
    """The JSON of a run: ``path`` itself, or ``path/metrics.json`` for a folder."""
    path = Path(path)
    file = path / "metrics.json" if path.is_dir() else path
    try:
        return json.loads(file.read_text())
    except FileNotFoundError:
        raise FileNotFoundError(f"{file}: no such file (give a learn output folder or a JSON file)") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"{file}: not valid JSON ({exc})") from None


def _first_difference(a: Any, b: Any, where: str = "") -> str | None:
    if type(a) is not type(b):
        return f"{where or 'top'}: {type(a).__name__} vs {type(b).__name__}"
    if isinstance(a, dict):
        for key in [*a, *(k for k in b if k not in a)]:
            if key not in a or key not in b:
                return f"{where}.{key}: only in {'the second' if key not in a else 'the first'}"
            found = _first_difference(a[key], b[key], f"{where}.{key}")
            if found:
                return found
        return None
    if isinstance(a, list):
        if len(a) != len(b):
            return f"{where}: {len(a)} vs {len(b)} items"
        for i, (x, y) in enumerate(zip(a, b)):
            found = _first_difference(x, y, f"{where}[{i}]")
            if found:
                return found
        return None
    return None if a == b else f"{where}: {a!r} vs {b!r}"


def compare(first: Any, second: Any) -> dict[str, Any]:
    """``{"kind", "same", "trials", "differing_trials", "first_difference"}`` of two runs' JSON."""
    if isinstance(first, dict) and isinstance(second, dict) and "trials" in first and "trials" in second:
        a, b = first["trials"], second["trials"]
        differing = [i for i, (x, y) in enumerate(zip(a, b)) if _strip(x) != _strip(y)]
        if len(a) != len(b):
            differing.append(min(len(a), len(b)))
        summary = _strip(first.get("summary")) == _strip(second.get("summary"))
        diff = _first_difference(_strip({"trials": a, "summary": first.get("summary")}),
                                 _strip({"trials": b, "summary": second.get("summary")}))
        return {"kind": "learn", "same": not differing and summary, "trials": [len(a), len(b)],
                "differing_trials": differing, "summary_same": summary, "first_difference": diff}
    diff = _first_difference(_strip(first), _strip(second))
    return {"kind": "json", "same": diff is None, "first_difference": diff}
