"""Same records? Two runs of one experiment compared field for field, wall-clock figures aside.

The house rule "a refactor proves itself by identical records before and after" is checked with
this: run the experiment on the old commit (a ``git worktree``) and on the new one with the same
seed, then ``elegant-stepping compare OLD NEW``. A learn output folder (or its ``metrics.json``) is
compared trial by trial (every field of every trial, traces included) and by its summary; any other
JSON (``walk --json``, ``bench``) as a whole. Fields that measure the host rather than the run
(:data:`WALL_CLOCK`) are left out everywhere; so is the ``config`` section of a learn run (a new
field with its default is not a new behaviour; the records say whether behaviour changed), and so
are the format stamps (:data:`STAMP_KEYS`: which version wrote a file is not what it recorded), so a
stamped ``metrics.json`` compares with one written before stamps.

Reading: a learn folder's ``metrics.json`` (or a file stamped as one) is checked for its stamp
and structure (:func:`hil.analysis.metrics.check_metrics`); any other JSON is read as it is. A
file that is missing is a ``FileNotFoundError``; one that is not JSON, of an unknown
``learn-metrics`` version or of the wrong structure is an :class:`controller.errors.InputError`
naming it. Numbers compare as JSON writes them: NaN equals NaN (the same record), 0.0 and -0.0
differ.

Additions: a field that the second (newer) run records and the first does not (a trial field a
later version added) is an *addition*, listed in ``added_fields`` (paths with ``[*]`` for list
indices), not a difference: the fields both record decide "same". A field only in the first is
a difference (the newer run lost it).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

from controller.errors import STAMP_KEYS as _STAMP_KEYS
from controller.errors import InputError

WALL_CLOCK = frozenset({"wall_s", "trials_per_minute", "elapsed_s", "cpu_s", "timing"})
"""Keys whose values depend on the host's speed and load, not on the run."""
STAMP_KEYS = frozenset(_STAMP_KEYS)
"""The file stamp's keys (:func:`controller.errors.stamp`), left out of a comparison."""


def _strip(x: Any, top: bool = True) -> Any:
    if isinstance(x, dict):
        return {k: _strip(v, False) for k, v in x.items() if k not in WALL_CLOCK and not (top and k in STAMP_KEYS)}
    if isinstance(x, list):
        return [_strip(v, False) for v in x]
    return x


def _same(a: Any, b: Any) -> bool:
    """Equal as JSON records: the same types (bool is not int), NaN equal to NaN."""
    return first_difference(a, b) is None


def read(path: str | Path) -> Any:
    """The JSON of a run: ``path`` itself, or ``path/metrics.json`` for a folder (which must be a
    learn run's metrics, stamped or of before stamps)."""
    from hil.analysis.metrics import METRICS_FORMAT, check_metrics

    path = Path(path)
    folder = path.is_dir()
    file = path / "metrics.json" if folder else path
    try:
        data = json.loads(file.read_bytes())
    except FileNotFoundError:
        raise FileNotFoundError(f"{file}: no such file (give a learn output folder or a JSON file)") from None
    except IsADirectoryError:
        raise InputError(f"{file}: a folder, not a JSON file") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"{file}: not valid JSON ({exc})") from None
    if folder or (isinstance(data, dict) and (data.get("format") == METRICS_FORMAT or file.name == "metrics.json")):
        check_metrics(data, file)
    elif isinstance(data, dict) and "trials" in data and not isinstance(data["trials"], list):
        raise InputError(f"{file}: 'trials' is a {type(data['trials']).__name__}, not a list of trial records")
    return data


def first_difference(a: Any, b: Any, where: str = "") -> str | None:
    """Where two JSON values first differ (``.key[3].field: A vs B``), None if they are the same
    record: equal values of the same JSON type, NaN equal to NaN, 0.0 and -0.0 different."""
    if type(a) is not type(b):
        return f"{where or 'top'}: {type(a).__name__} vs {type(b).__name__}"
    if isinstance(a, dict):
        for key in [*a, *(k for k in b if k not in a)]:
            if key not in a or key not in b:
                return f"{where}.{key}: only in {'the second' if key not in a else 'the first'}"
            found = first_difference(a[key], b[key], f"{where}.{key}")
            if found:
                return found
        return None
    if isinstance(a, list):
        if len(a) != len(b):
            return f"{where}: {len(a)} vs {len(b)} items"
        for i, (x, y) in enumerate(zip(a, b)):
            found = first_difference(x, y, f"{where}[{i}]")
            if found:
                return found
        return None
    if isinstance(a, float):
        if (math.isnan(a) and math.isnan(b)) or (a == b and math.copysign(1.0, a) == math.copysign(1.0, b)):
            return None
        return f"{where}: {a!r} vs {b!r}"
    return None if a == b else f"{where}: {a!r} vs {b!r}"


_first_difference = first_difference  # the older private name


def split_additions(old: Any, new: Any, where: str = "", found: list[str] | None = None) -> tuple[Any, list[str]]:
    """``new`` without the dict keys that ``old`` lacks at the same place, and those keys' paths
    (``.trials[*].field``, each once, in order of first sight); lists are walked item by item."""
    found = [] if found is None else found
    if isinstance(old, dict) and isinstance(new, dict):
        kept = {}
        for key, value in new.items():
            if key not in old:
                path = f"{where}.{key}"
                if path not in found:
                    found.append(path)
                continue
            kept[key] = split_additions(old[key], value, f"{where}.{key}", found)[0]
        return kept, found
    if isinstance(old, list) and isinstance(new, list):
        items = [split_additions(x, y, f"{where}[*]", found)[0] for x, y in zip(old, new)]
        return items + new[len(old):], found
    return new, found


def compare(first: Any, second: Any) -> dict[str, Any]:
    """``{"kind", "same", "trials", "differing_trials", "first_difference", "added_fields"}`` of
    two runs' JSON (``second`` the newer: its additions are listed, not differences)."""
    if (isinstance(first, dict) and isinstance(second, dict) and isinstance(first.get("trials"), list)
            and isinstance(second.get("trials"), list)):
        added: list[str] = []
        a = first["trials"]
        b = split_additions(a, second["trials"], ".trials", added)[0]
        second = {**second, "summary": split_additions(first.get("summary"), second.get("summary"), ".summary",
                                                       added)[0]}
        differing = [i for i, (x, y) in enumerate(zip(a, b)) if not _same(_strip(x, False), _strip(y, False))]
        if len(a) != len(b):
            differing.append(min(len(a), len(b)))
        summary = _same(_strip(first.get("summary"), False), _strip(second.get("summary"), False))
        diff = first_difference(_strip({"trials": a, "summary": first.get("summary")}),
                                _strip({"trials": b, "summary": second.get("summary")}))
        return {"kind": "learn", "same": not differing and summary, "trials": [len(a), len(b)],
                "differing_trials": differing, "summary_same": summary, "first_difference": diff,
                "added_fields": added}
    older = _strip(first)
    newer, added = split_additions(older, _strip(second))
    diff = first_difference(older, newer)
    return {"kind": "json", "same": diff is None, "first_difference": diff, "added_fields": added}
