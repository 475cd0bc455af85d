"""Figures of a learning run (matplotlib, Agg backend: no display needed), PNG and SVG.

Each plotting function takes the numbers it draws and returns them too, so tests check the data
behind every axis rather than pixels.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402


def _save(fig, out: Path, name: str) -> list[Path]:
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / f"{name}.png", out / f"{name}.svg"]
    for p in paths:
        fig.savefig(p, dpi=120, bbox_inches="tight")
    plt.close(fig)
    return paths


def learning_curve(trials: list[dict[str, Any]], out: Path, window: int = 10) -> dict[str, list[float]]:
    """Success per trial and its running mean over ``window`` trials."""
    success = np.array([1.0 if t["success"] else 0.0 for t in trials])
    running = [float(success[max(0, i - window + 1) : i + 1].mean()) for i in range(len(success))]
    fig, ax = plt.subplots(figsize=(6, 3.2))
    ax.plot(np.arange(1, len(success) + 1), success, ".", color="0.6", label="trial")
    ax.plot(np.arange(1, len(success) + 1), running, "-", color="C0", label=f"mean of last {window}")
    ax.set(xlabel="trial", ylabel="success", ylim=(-0.05, 1.05), title="Learning to step over the obstacle")
    ax.legend(loc="lower right")
    _save(fig, out, "learning_curve")
    return {"success": success.tolist(), "running_mean": running}


def weights_by_distance(weights: np.ndarray, cell_width_m: float, out: Path) -> dict[str, list[float]]:
    """The learned weight of each range cell against the cell's distance (the paper's Fig. 4)."""
    distance = ((np.arange(len(weights)) + 0.5) * cell_width_m).tolist()
    fig, ax = plt.subplots(figsize=(6, 3.2))
    ax.bar(distance, weights, width=cell_width_m * 0.9, color=np.where(np.asarray(weights) >= 0, "C1", "C0"))
    ax.axhline(0.0, color="k", lw=0.6)
    ax.set(xlabel="range cell (distance from the sensor) [m]", ylabel="weight [s of burst]",
           title="Learned weights (ordered by distance for display only)")
    _save(fig, out, "weights")
    return {"distance_m": distance, "weight_s": [float(w) for w in weights]}


def footfall_spread(std_by_step: list[float | None], out: Path) -> dict[str, list]:
    """Footfall standard deviation against steps before the obstacle (the paper's Fig. 3)."""
    steps = list(range(1, len(std_by_step) + 1))
    fig, ax = plt.subplots(figsize=(4.5, 3.2))
    ax.plot(steps, [np.nan if s is None else s * 100 for s in std_by_step], "o-")
    ax.set(xlabel="steps before the obstacle", ylabel="footfall s.d. [cm]", title="Footfall spread")
    ax.invert_xaxis()
    _save(fig, out, "footfall_spread")
    return {"steps_before": steps, "std_m": std_by_step}
