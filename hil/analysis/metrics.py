"""The learning run's figures, computed from ``learn`` output folders (``metrics.json``,
``weights.npz``): what the acceptance criteria and the paper's Figs. 3 and 4 are measured on.
"""

from __future__ import annotations

import json
import statistics
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from controller.errors import InputError, check_stamp
from controller.stepping.weights import WeightsError, read_weights

METRICS_FILE = "metrics.json"
METRICS_FORMAT = "learn-metrics"
METRICS_VERSIONS = (0, 1)
"""A learn run's ``metrics.json``: version 1 is stamped (:func:`controller.errors.stamp`); version 0
is a file written before stamps (the same keys without them), still read for old folders."""


def check_metrics(metrics: Any, source: str | Path, *, trial_keys: Sequence[str] = (),
                  parts: Sequence[str] = ("config", "trials", "summary")) -> dict[str, Any]:
    """``metrics`` (a parsed ``metrics.json``) after checking its stamp and its structure: the
    ``parts`` it must have (by default all three: a ``config`` object, a ``trials`` list of objects
    each with a boolean ``success`` and the ``trial_keys``, a ``summary`` object).

    Raises:
        InputError: another kind of file, an unknown format version, or a wrong structure; the
            message names ``source``.
    """
    check_stamp(metrics, METRICS_FORMAT, METRICS_VERSIONS, str(source))
    for key, kind in (("config", dict), ("trials", list), ("summary", dict)):
        if key not in parts and key != "trials":
            continue
        if not isinstance(metrics.get(key), kind):
            got = "missing" if key not in metrics else f"a {type(metrics[key]).__name__}"
            raise InputError(f"{source}: not a learn run's metrics ('{key}' is {got}, "
                             f"{'an object' if kind is dict else 'a list'} expected)")
    for k, trial in enumerate(metrics["trials"]):
        if not isinstance(trial, dict) or not isinstance(trial.get("success"), bool):
            raise InputError(f"{source}: trial {k} is not a trial record (an object with a boolean 'success' expected)")
        for key in trial_keys:
            if key not in trial:
                raise InputError(f"{source}: trial {k} has no '{key}' (not a learn run's trial record)")
    return metrics


def read_metrics(path: str | Path, *, trial_keys: Sequence[str] = (),
                 parts: Sequence[str] = ("config", "trials", "summary")) -> dict[str, Any]:
    """A ``metrics.json`` (stamped, or of before stamps), checked by :func:`check_metrics`.

    Raises:
        FileNotFoundError: no such file.
        InputError: not JSON, or not a learn run's metrics of a known version.
    """
    path = Path(path)
    try:
        data = json.loads(path.read_bytes())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: not valid JSON ({exc})") from None
    return check_metrics(data, path, trial_keys=trial_keys, parts=parts)


def load_run(folder: str | Path) -> dict[str, Any]:
    """A learn output folder: its ``metrics.json`` (:func:`read_metrics`) and, if the folder has one,
    its ``weights.npz`` as ``weights`` and ``cell_width_m``; the figures need each trial's
    ``footfalls_m`` and the configuration's ``seed`` and ``learning``.

    Raises:
        FileNotFoundError: not a folder, or no ``metrics.json`` in it.
        InputError: a damaged or wrong-structure ``metrics.json`` (or weights file), or one of an
            unknown format version.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"{folder}: not a folder, so no metrics.json (give learn output folders)")
    metrics_path = folder / METRICS_FILE
    try:
        metrics = read_metrics(metrics_path, trial_keys=("footfalls_m",))
    except FileNotFoundError:
        raise FileNotFoundError(f"{metrics_path}: no metrics.json (is {folder} a learn output folder?)") from None
    for key in ("seed", "learning"):
        if key not in metrics["config"]:
            raise InputError(f"{metrics_path}: config has no '{key}' (not a learn run's metrics)")
    weights_path = folder / "weights.npz"
    if weights_path.exists():
        try:
            metrics["weights"], metrics["cell_width_m"] = read_weights(weights_path)
        except WeightsError as exc:
            raise InputError(str(exc)) from None
        controller = metrics["config"].get("controller")
        height = controller.get("height") if isinstance(controller, dict) else None
        if metrics["weights"].ndim == 2 and not (isinstance(height, dict) and "beam_heights_m" in height):
            raise InputError(f"{metrics_path}: config has no 'controller.height.beam_heights_m', which bound the "
                             f"height contexts its weights have a row for")
    return metrics


def window_success(trials: list[dict], first: int, last: int) -> float | None:
    """Mean success over trials numbered ``first..last`` (1-based, inclusive)."""
    window = trials[first - 1 : last]
    return sum(t["success"] for t in window) / len(window) if window else None


def _succeeded(trial: Any) -> bool:
    return bool(trial["success"] if isinstance(trial, dict) else trial)


def success_last(trials: Sequence[Any], n: int = 50) -> float | None:
    """Success rate over the last ``n`` trials (``success_last_50`` is ``n`` = 50).

    The one rule for a run of fewer than ``n`` trials: the rate over all of them (a run stopped
    early or a short HIL session still reports how it did); None for a run without trials.
    ``trials``: trial dicts (their ``success``) or the outcomes as booleans.
    """
    if n < 1:
        raise ValueError(f"n must be at least 1 trial, got {n}")
    last = list(trials)[-n:]
    return sum(_succeeded(t) for t in last) / len(last) if last else None


def last_window(n_trials: int, size: int = 50) -> tuple[int, int]:
    """The last ``size`` trials of a run of ``n_trials`` as (first, last), 1-based, inclusive
    (all of them if fewer)."""
    return max(1, n_trials - size + 1), n_trials


def late_window(n_trials: int) -> tuple[int, int]:
    """The window where learning is judged finished: trials 101-150 if the run has them, else
    its last 50 trials (:func:`last_window`)."""
    return (101, 150) if n_trials >= 150 else last_window(n_trials)


def mistakes_101_150(trials: list[dict]) -> int | None:
    """Failed trials among 101-150 (None for a run shorter than 150 trials)."""
    return sum(not t["success"] for t in trials[100:150]) if len(trials) >= 150 else None


def footfall_std_by_step(runs: list[dict], first: int, last: int, steps: int = 4) -> list[float | None]:
    """Std of the footfall position k steps before the obstacle (k = 1 is the last), pooled."""
    out = []
    for k in range(1, steps + 1):
        xs = [t["footfalls_m"][-k] for r in runs for t in r["trials"][first - 1 : last] if len(t["footfalls_m"]) >= k]
        out.append(statistics.pstdev(xs) if len(xs) > 1 else None)
    return out


def modulation_by_gate(runs: list[dict], first: int, last: int, gates: int = 6) -> list[float | None]:
    """Mean |burst change asked for| at the k-th last gate before the crossing (k = 1: the gate at
    the last footfall, which modulates the crossing swing itself)."""
    out = []
    for k in range(1, gates + 1):
        vals = [abs(t["modulation_s"][-k]) for r in runs for t in r["trials"][first - 1 : last]
                if len(t.get("modulation_s", [])) >= k]
        out.append(statistics.fmean(vals) if vals else None)
    return out


def modulation_share_last_gates(by_gate: list[float | None], last: int = 3) -> float | None:
    """Share of the mean |modulation| (summed over gates) asked for at the last ``last`` gates."""
    vals = [v or 0.0 for v in by_gate]
    total = sum(vals)
    return None if total == 0.0 else sum(vals[:last]) / total


def autocorrelation(weights: np.ndarray, max_lag: int) -> np.ndarray:
    w = np.asarray(weights, dtype=float)
    w = w - w.mean()
    denom = float(np.dot(w, w))
    if denom == 0.0:
        return np.zeros(max_lag + 1)
    return np.array([float(np.dot(w[: len(w) - lag], w[lag:])) / denom for lag in range(max_lag + 1)])


def autocorrelation_peak(weights: np.ndarray, cell_width_m: float, max_range_m: float = 1.5) -> dict[str, Any]:
    """The autocorrelation's first local maximum after it first drops below zero, over the cells
    within ``max_range_m`` (where the obstacle is approached step by step)."""
    n = min(len(weights), int(round(max_range_m / cell_width_m)))
    ac = autocorrelation(weights[:n], n // 2)
    lag = None
    crossed = False
    for k in range(1, len(ac) - 1):
        crossed = crossed or ac[k] < 0.0
        if crossed and ac[k] >= ac[k - 1] and ac[k] >= ac[k + 1] and ac[k] > 0.0:
            lag = k
            break
    return {
        "lag_cells": lag,
        "period_m": None if lag is None else lag * cell_width_m,
        "peak": None if lag is None else float(ac[lag]),
        "autocorrelation": [float(a) for a in ac],
    }


def _mean(values) -> float | None:
    values = [v for v in values if v is not None]
    return statistics.fmean(values) if values else None


def analyze(folders: list[str | Path]) -> dict[str, Any]:
    runs = [load_run(f) for f in folders]
    per_seed = []
    for folder, r in zip(folders, runs):
        t = r["trials"]
        row = {
            "folder": str(folder),
            "seed": r["config"]["seed"],
            "learning": r["config"]["learning"],
            "trials": len(t),
            "success_rate": window_success(t, 1, len(t)),
            "success_21_40": window_success(t, 21, 40),
            "mistakes_101_150": mistakes_101_150(t),
            "wall_s": r["summary"].get("wall_s"),
            "sim_s": r["summary"].get("sim_s"),
        }
        if "weights" in r and r["weights"].ndim == 1:  # one context (the context learner's are 2-D)
            peak = autocorrelation_peak(r["weights"], r["cell_width_m"])
            row["weights_period_m"] = peak["period_m"]
            row["weights_autocorrelation_peak"] = peak["peak"]
        per_seed.append(row)
    n_trials = min(len(r["trials"]) for r in runs)
    late = late_window(n_trials)
    strides = [s for r in runs for t in r["trials"] for s in np.diff(t["footfalls_m"][:-1]).tolist()[:2]]
    return {
        "runs": per_seed,
        "mean_success_21_40": _mean(r["success_21_40"] for r in per_seed),
        "mean_success_rate": _mean(r["success_rate"] for r in per_seed),
        "seeds_without_mistakes_101_150": sum(1 for r in per_seed if r["mistakes_101_150"] == 0),
        "late_window": list(late),
        "footfall_std_m_by_steps_before": footfall_std_by_step(runs, *late),
        "abs_modulation_s_by_gate_before_crossing": (mod := modulation_by_gate(runs, *late)),
        "modulation_share_last_three_gates": modulation_share_last_gates(mod),
        "approach_stride_m": _mean(strides),
        "mean_wall_s": _mean(r["wall_s"] for r in per_seed),
    }
