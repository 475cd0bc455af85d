"""The course's figure: success against distance walked, every method on one figure (PNG and SVG).

House style of :mod:`hil.analysis.figures` (matplotlib's object-oriented API on an Agg canvas, no
pyplot); the function returns the numbers it draws.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

from hil.analysis.figures import _save, subplots
from hil.analysis.stats import running_success
from hil.experiments.methods import REGISTRY

COLORS = {"paper": "C0", "improved": "C2", "none": "0.45", "oracle": "C3", "context": "C1", "rl": "C4"}


def success_by_distance(runs: dict[str, Sequence[dict[str, Any]]], out: Path, *, window: int = 20,
                        layout: Sequence[Any] = (), name: str = "course") -> dict[str, dict[str, list[float]]]:
    """Top: each method's success over its last ``window`` obstacles against the distance its hip
    had walked when each obstacle's trial ended [m] (fewer than ``window`` at the start, drawn
    thinner); bottom: the course, each obstacle's height at its near edge. ``runs``: the trial
    records of each method (:mod:`hil.experiments.course`); ``layout``: its obstacles."""
    fig, (ax, ax_c) = subplots(2, 1, figsize=(8, 4.8), sharex=True, gridspec_kw={"height_ratios": [3, 1]})
    drawn: dict[str, dict[str, list[float]]] = {}
    for method, trials in runs.items():
        x = [float(t["walked_m"]) for t in trials]
        y = running_success([bool(t["success"]) for t in trials], window)
        color = COLORS.get(method, None)
        w = min(window, len(x))
        ax.plot(x[:w], y[:w], "-", lw=0.8, color=color, alpha=0.6)
        total = sum(1 for t in trials if t["success"])
        ax.plot(x[w - 1:], y[w - 1:], "-", lw=1.8, color=color,
                label=f"{method} ({total}/{len(trials)})" if method in REGISTRY else method)
        drawn[method] = {"walked_m": x, "success": y}
    ax.set(ylabel=f"success, last {window} obstacles", ylim=(-0.03, 1.03),
           title="The course: success against distance walked (learning online)")
    ax.grid(alpha=0.3)
    ax.legend(loc="lower right", fontsize=8, ncol=2)
    if layout:
        near = [float(o.near_m) for o in layout]
        height = [float(o.height_m) * 100 for o in layout]
        ax_c.vlines(near, 0, height, color="0.3", lw=1.2)
        ax_c.set(ylim=(0, max(height) * 1.15))
        drawn["layout"] = {"near_m": near, "height_cm": height}
    ax_c.set(xlabel="distance walked by the hip from the course's start [m]", ylabel="height [cm]")
    _save(fig, out, name)
    return drawn
