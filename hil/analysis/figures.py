"""Figures of learning runs (matplotlib, Agg backend: no display needed), PNG and SVG.

Each plotting function takes the numbers it draws and returns them too, so tests check the data
behind every axis rather than pixels. The paper's figures: Fig. 2 :func:`foot_trajectories`,
Fig. 3 :func:`footfall_spread` / :func:`footfall_spread_by_size`, Fig. 4 :func:`weights_by_distance`
with :func:`weights_autocorrelation` (and :func:`weights_by_context` for a learner with a row per
obstacle height); besides them the learning curves over seeds
(:func:`success_curves`) and the burst length over one approach (:func:`burst_over_approach`).
:func:`paper_figures` draws all the data allows from ``learn`` output folders.

Figures are drawn with matplotlib's object-oriented API (:func:`subplots`: a
:class:`matplotlib.figure.Figure` on its own Agg canvas), never with pyplot: pyplot's import (its
backend machinery, about 0.2-0.5 s of CPU) is not needed to write files, pyplot's figure registry
is not needed either (a figure is freed when it is no longer referenced, no ``close``), and the
process's pyplot backend is left as the caller set it. The files are the same as pyplot's Agg
backend writes, byte for byte.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any, Sequence

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle

from hil.analysis.metrics import autocorrelation_peak, footfall_std_by_step, late_window, load_run
from hil.analysis.stats import mean_ci95, running_success
from hil.experiments.methods import CONTROLLER_METHOD, DEFAULT_METHOD, resolve

log = logging.getLogger(__name__)


def subplots(nrows: int = 1, ncols: int = 1, *, figsize: tuple[float, float], **kwargs: Any) -> tuple[Figure, Any]:
    """A new figure on its own Agg canvas and its axes, as ``pyplot.subplots`` gives them (the same
    arguments; ``kwargs`` go to :meth:`matplotlib.figure.Figure.subplots`), without pyplot."""
    fig = Figure(figsize=figsize)
    FigureCanvasAgg(fig)
    return fig, fig.subplots(nrows, ncols, **kwargs)


def _save(fig: Figure, out: Path, name: str) -> list[Path]:
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / f"{name}.png", out / f"{name}.svg"]
    for p in paths:
        fig.savefig(p, dpi=120, bbox_inches="tight")
    return paths


def learning_curve(trials: list[dict[str, Any]], out: Path, window: int = 10) -> dict[str, list[float]]:
    """Success per trial of one run and its running mean over ``window`` trials
    (:func:`hil.analysis.stats.running_success`, as in :func:`success_curves`)."""
    success = np.array([1.0 if t["success"] else 0.0 for t in trials])
    running = running_success(success, window)
    fig, ax = subplots(figsize=(6, 3.2))
    ax.plot(np.arange(1, len(success) + 1), success, ".", color="0.6", label="trial")
    ax.plot(np.arange(1, len(success) + 1), running, "-", color="C0", label=f"mean of last {window}")
    ax.set(xlabel="trial", ylabel="success", ylim=(-0.05, 1.05), title="Learning to step over the obstacle")
    ax.legend(loc="lower right")
    _save(fig, out, "learning_curve")
    return {"success": success.tolist(), "running_mean": running}


def weights_by_distance(weights: np.ndarray, cell_width_m: float, out: Path,
                        name: str = "weights") -> dict[str, list[float]]:
    """The learned weight of each range cell against the cell's distance (the paper's Fig. 4)."""
    distance = ((np.arange(len(weights)) + 0.5) * cell_width_m).tolist()
    fig, ax = subplots(figsize=(6, 3.2))
    _weight_bars(ax, distance, weights, cell_width_m)
    ax.set(xlabel="range cell (distance from the sensor) [m]", ylabel="weight [s of burst]",
           title="Learned weights (ordered by distance for display only)")
    _save(fig, out, name)
    return {"distance_m": distance, "weight_s": [float(w) for w in weights]}


def _weight_bars(ax: Any, distance_m: list[float], weights: Any, cell_width_m: float) -> None:
    """One row of weights as bars against the cells' distances, lengthening orange, shortening blue."""
    ax.bar(distance_m, weights, width=cell_width_m * 0.9, color=np.where(np.asarray(weights) >= 0, "C1", "C0"))
    ax.axhline(0.0, color="k", lw=0.6)


def _context_bounds_m(beam_heights_m: Sequence[float]) -> list[tuple[float, float]]:
    """The obstacle heights each height context stands for [m], (lower, upper), lowest first: as the
    controller's estimator bounds them (:meth:`controller.stepping.height.HeightEstimator.bounds_m`)."""
    from controller.stepping.height import HeightEstimator, HeightEstimatorConfig

    estimator = HeightEstimator(HeightEstimatorConfig(beam_heights_m=tuple(beam_heights_m)))
    return [estimator.bounds_m(k) for k in range(estimator.n_contexts)]


def weights_by_context(weights: np.ndarray, cell_width_m: float, beam_heights_m: Sequence[float], out: Path,
                       name: str = "weights") -> dict[str, Any]:
    """A context learner's weights (``improved``, ``context``): one panel per height context, its
    weight of each range cell against the cell's distance, as :func:`weights_by_distance` draws
    one row. ``beam_heights_m``: the profile beams that bound the contexts (the controller's
    ``height.beam_heights_m``); a row has a context per gap between them and one at each end."""
    weights = np.atleast_2d(np.asarray(weights, dtype=float))
    bounds = _context_bounds_m(beam_heights_m)
    if len(bounds) != weights.shape[0]:
        raise ValueError(f"{weights.shape[0]} rows of weights but {len(bounds)} height contexts "
                         f"from beams {list(beam_heights_m)}")
    distance = ((np.arange(weights.shape[1]) + 0.5) * cell_width_m).tolist()
    labels = [f"obstacle below {hi:g} m" if lo == 0.0 else f"obstacle above {lo:g} m" if hi == float("inf")
              else f"obstacle {lo:g}-{hi:g} m" for lo, hi in bounds]
    fig, axes = subplots(weights.shape[0], 1, figsize=(6, 1.6 * weights.shape[0] + 0.6), sharex=True,
                         sharey=True, squeeze=False)
    limit = max(float(np.abs(weights).max()), 1e-3)
    for ax, row, label in zip(axes[:, 0], weights, labels):
        _weight_bars(ax, distance, row, cell_width_m)
        ax.set_ylim(-1.1 * limit, 1.1 * limit)
        ax.set_title(label, fontsize="small", loc="left")
    axes[-1, 0].set_xlabel("range cell (distance from the sensor) [m]")
    axes[len(axes) // 2, 0].set_ylabel("weight [s of burst]")
    fig.suptitle("Learned weights per height context")
    _save(fig, out, name)
    return {"distance_m": distance, "context": labels, "weight_s": weights.tolist()}


def footfall_spread(std_by_step: list[float | None], out: Path, name: str = "footfall_spread") -> dict[str, list]:
    """Footfall standard deviation against steps before the obstacle (the paper's Fig. 3)."""
    steps = list(range(1, len(std_by_step) + 1))
    fig, ax = subplots(figsize=(4.5, 3.2))
    ax.plot(steps, [np.nan if s is None else s * 100 for s in std_by_step], "o-")
    ax.set(xlabel="steps before the obstacle", ylabel="footfall s.d. [cm]", title="Footfall spread")
    ax.invert_xaxis()
    _save(fig, out, name)
    return {"steps_before": steps, "std_m": std_by_step}


# -- learning curves over seeds ----------------------------------------------------------------


SUCCESS_CURVES_TITLE = "Learning to step over the obstacle (mean, 95% interval over seeds)"


def success_curves(curves: dict[str, Sequence[Sequence[bool]]], out: Path, name: str = "learning_curve_seeds",
                   window: int = 10, title: str = SUCCESS_CURVES_TITLE) -> dict[str, dict[str, Any]]:
    """Running ``window``-trial success of each seed, and per label its mean over the seeds with
    a 95% t-interval (shaded, clipped to [0, 1] as plotted and returned). ``curves`` maps a label
    (e.g. "learning", "no learning", or a sweep's methods) to one list of per-trial successes per
    seed; seeds are cut to the shortest. The one success-curve plot: ``figures`` and the sweep's
    report (:mod:`hil.analysis.report`) both draw with it. Returns, per label, ``trial``
    (1-based), ``mean``, ``ci95_low``, ``ci95_high`` and ``seeds``."""
    if not curves:
        raise ValueError("success_curves needs at least one label")
    if window < 1:
        raise ValueError(f"window must be at least 1 trial, got {window}")
    data: dict[str, dict[str, Any]] = {}
    fig, ax = subplots(figsize=(6.5, 3.5))
    for i, (label, seeds) in enumerate(curves.items()):
        if not seeds or any(len(s) == 0 for s in seeds):
            raise ValueError(f"label {label!r}: need at least one seed with at least one trial")
        rows = [running_success(s, window) for s in seeds]
        mean, lo, hi = mean_ci95(rows)
        lo, hi = [max(0.0, v) for v in lo], [min(1.0, v) for v in hi]
        trial = list(range(1, len(mean) + 1))
        colour = f"C{i % 10}"
        ax.fill_between(trial, lo, hi, color=colour, alpha=0.2, lw=0)
        ax.plot(trial, mean, "-", color=colour, label=f"{label} ({len(seeds)} seed{'s' if len(seeds) != 1 else ''})")
        data[label] = {"trial": trial, "mean": mean, "ci95_low": lo, "ci95_high": hi, "seeds": len(seeds)}
    ax.set(xlabel="trial", ylabel=f"success, last {window} trials", ylim=(-0.05, 1.05), title=title)
    ax.legend(loc="lower right", fontsize="small")
    _save(fig, out, name)
    return data


# -- Fig. 2: the foot's path before and after learning -----------------------------------------

_TRACE_KEYS = ("t_s", "foot_x_m", "foot_z_m")


def _check_trace(trace: dict[str, Sequence[float]], what: str, keys: Sequence[str] = _TRACE_KEYS) -> int:
    missing = [k for k in keys if k not in trace]
    if missing:
        raise ValueError(f"{what}: the trace has no {', '.join(missing)} (is it a traced trial's 'trace'?)")
    lengths = {len(trace[k]) for k in keys}
    if len(lengths) != 1 or 0 in lengths:
        raise ValueError(f"{what}: the trace's {', '.join(keys)} must be non-empty and of equal length")
    return lengths.pop()


def trace_touchdowns(trace: dict[str, Sequence[float]], obstacle_height_m: float = 0.0,
                     obstacle_depth_m: float = 0.0, lift_m: float = 0.02, land_m: float = 0.005) -> list[int]:
    """Indices of the trace samples at which the foot lands: its lowest point comes within
    ``land_m`` of the surface under it (the ground, or the obstacle's top at x in [0, depth])
    after having been more than ``lift_m`` above it. A trace that begins in stance has no
    touchdown until the foot has lifted."""
    n = _check_trace(trace, "trace_touchdowns", ("foot_x_m", "foot_z_m"))
    out: list[int] = []
    lifted = False
    for i in range(n):
        x, z = trace["foot_x_m"][i], trace["foot_z_m"][i]
        surface = obstacle_height_m if 0.0 <= x <= obstacle_depth_m else 0.0
        height = z - surface
        if height > lift_m:
            lifted = True
        elif lifted and height <= land_m:
            out.append(i)
            lifted = False
    return out


def _first_contact(trace: dict[str, Sequence[Any]]) -> int | None:
    return next((i for i, c in enumerate(trace.get("contact", [])) if c), None)


def foot_trajectories(before: dict[str, Sequence[float]], after: dict[str, Sequence[float]],
                      obstacle_height_m: float, obstacle_depth_m: float, out: Path, *,
                      before_touchdowns_x_m: Sequence[float] | None = None,
                      after_touchdowns_x_m: Sequence[float] | None = None,
                      labels: tuple[str, str] = ("before learning", "after learning"),
                      name: str = "foot_trajectories") -> dict[str, dict[str, list]]:
    """Foot height against foot x (0 = the obstacle's near edge) over one approach before and one
    after learning, one panel each (the paper's Fig. 2). Touchdowns are marked on the ground: the
    given x positions (e.g. a trial's ``footfalls_m``), else those found in the trace by
    :func:`trace_touchdowns`. A cross marks the first obstacle contact, if the trace has one."""
    if not (obstacle_height_m > 0 and obstacle_depth_m > 0):
        raise ValueError(f"obstacle height and depth must be positive, got {obstacle_height_m}, {obstacle_depth_m}")
    data: dict[str, dict[str, list]] = {}
    fig, axes = subplots(2, 1, figsize=(8, 5), sharex=True, sharey=True)
    for ax, key, trace, given, label, colour in zip(axes, ("before", "after"), (before, after),
                                                    (before_touchdowns_x_m, after_touchdowns_x_m), labels, ("C3", "C0")):
        _check_trace(trace, f"foot_trajectories({key})")
        x = [float(v) for v in trace["foot_x_m"]]
        z = [float(v) for v in trace["foot_z_m"]]
        if given is not None:
            td_x = [float(v) for v in given]
            td_z = [0.0] * len(td_x)
        else:
            idx = trace_touchdowns(trace, obstacle_height_m, obstacle_depth_m)
            td_x, td_z = [x[i] for i in idx], [z[i] for i in idx]
        hit = _first_contact(trace)
        ax.add_patch(Rectangle((0.0, 0.0), obstacle_depth_m, obstacle_height_m, color="0.45", zorder=1))
        ax.axhline(0.0, color="0.3", lw=0.8)
        ax.plot(x, z, "-", color=colour, lw=1.2, zorder=2, label="foot path")
        ax.plot(td_x, td_z, "v", color="k", ms=6, zorder=3, label="touchdown")
        if hit is not None:
            ax.plot([x[hit]], [z[hit]], "x", color="r", ms=10, mew=2, zorder=4, label="obstacle contact")
        outcome = "hit the obstacle" if hit is not None else "cleared"
        ax.set(ylabel="foot height [m]", title=f"{label}: {outcome}" if "contact" in trace else label)
        ax.legend(loc="upper left", fontsize="small")
        data[key] = {"x_m": x, "z_m": z, "touchdown_x_m": td_x, "touchdown_z_m": td_z,
                     "contact_x_m": None if hit is None else x[hit]}
    axes[-1].set_xlabel("foot x from the obstacle's near edge [m]")
    fig.suptitle("Foot trajectories before and after learning")
    _save(fig, out, name)
    return data


# -- Fig. 3 by obstacle size ------------------------------------------------------------------


def footfall_spread_by_size(groups: dict[float, list[dict[str, Any]]], out: Path, first: int, last: int,
                            steps: int = 4, name: str = "footfall_spread_by_size") -> dict[str, Any]:
    """Footfall s.d. k steps before the obstacle (k = 1: the last footfall before it) over trials
    ``first..last`` of each run, one line per obstacle height (the paper's Fig. 3). ``groups``
    maps an obstacle height [m] to its runs (``learn`` metrics). Fewer than 3 heights are drawn
    with a warning: the paper's comparison of sizes needs at least 3."""
    if not groups:
        raise ValueError("footfall_spread_by_size needs runs at one obstacle height at least")
    if not 1 <= first <= last:
        raise ValueError(f"need 1 <= first <= last, got {first}, {last}")
    if steps < 1:
        raise ValueError(f"steps must be at least 1, got {steps}")
    if len(groups) < 3:
        log.warning("footfall spread by size: runs at %d obstacle height(s) only; the paper compares 3 or more",
                    len(groups))
    heights = sorted(groups)
    std_m = {h: footfall_std_by_step(groups[h], first, last, steps) for h in heights}
    k = list(range(1, steps + 1))
    fig, ax = subplots(figsize=(5, 3.5))
    for h in heights:
        n = len(groups[h])
        ax.plot(k, [np.nan if s is None else s * 100 for s in std_m[h]], "o-",
                label=f"{h * 100:g} cm ({n} run{'s' if n != 1 else ''})")
    ax.set(xlabel="steps before the obstacle", ylabel="footfall s.d. [cm]",
           title=f"Footfall spread by obstacle height (trials {first}-{last})")
    ax.set_xticks(k)
    ax.invert_xaxis()
    ax.legend(title="obstacle height", fontsize="small")
    _save(fig, out, name)
    return {"steps_before": k, "heights_m": heights, "std_m": std_m, "runs": {h: len(groups[h]) for h in heights},
            "trials": [first, last]}


# -- Fig. 4: the weights' period ----------------------------------------------------------------


def weights_autocorrelation(weights: np.ndarray, cell_width_m: float, out: Path, max_range_m: float = 1.5,
                            name: str = "weights_autocorrelation") -> dict[str, Any]:
    """Autocorrelation of the learned weights (cells within ``max_range_m``) against the lag in
    metres, with its first peak after the first zero crossing marked: the weights' period
    (see :func:`hil.analysis.metrics.autocorrelation_peak`)."""
    if not cell_width_m > 0:
        raise ValueError(f"cell_width_m must be positive, got {cell_width_m}")
    peak = autocorrelation_peak(np.asarray(weights, dtype=float), cell_width_m, max_range_m)
    ac = peak["autocorrelation"]
    lag_m = [k * cell_width_m for k in range(len(ac))]
    fig, ax = subplots(figsize=(6, 3.2))
    ax.plot(lag_m, ac, "o-", ms=3)
    ax.axhline(0.0, color="k", lw=0.6)
    if peak["period_m"] is not None:
        ax.axvline(peak["period_m"], color="C1", ls="--")
        ax.annotate(f"peak at {peak['period_m']:.2f} m", (peak["period_m"], peak["peak"]),
                    xytext=(8, 8), textcoords="offset points", color="C1")
    ax.set(xlabel="lag [m]", ylabel="autocorrelation",
           title="Autocorrelation of the learned weights" + ("" if peak["period_m"] is not None else " (no peak)"))
    _save(fig, out, name)
    return {"lag_m": lag_m, "autocorrelation": ac, "peak_lag_m": peak["period_m"], "peak": peak["peak"]}


# -- burst length over one approach -------------------------------------------------------------


def burst_over_approach(trace: dict[str, Sequence[float]], out: Path, *,
                        before: dict[str, Sequence[float]] | None = None,
                        obstacle_height_m: float = 0.0, obstacle_depth_m: float = 0.0,
                        name: str = "burst_over_approach") -> dict[str, Any]:
    """The CPG's burst length against time over one approach, touchdowns (found in the trace)
    marked, and the moment the foot first passes over the obstacle's near edge. ``before``, if
    given, is drawn in grey for comparison (e.g. the first trial, before learning)."""
    _check_trace(trace, "burst_over_approach", ("t_s", "burst_s", "foot_x_m", "foot_z_m"))
    t = [float(v) for v in trace["t_s"]]
    burst = [float(v) for v in trace["burst_s"]]
    td = trace_touchdowns(trace, obstacle_height_m, obstacle_depth_m)
    over = next((t[i] for i, x in enumerate(trace["foot_x_m"]) if x >= 0.0), None)
    fig, ax = subplots(figsize=(6.5, 3.2))
    data: dict[str, Any] = {"t_s": t, "burst_s": burst, "touchdown_t_s": [t[i] for i in td],
                            "touchdown_burst_s": [burst[i] for i in td], "over_edge_t_s": over}
    if before is not None:
        _check_trace(before, "burst_over_approach(before)", ("t_s", "burst_s"))
        data["before_t_s"] = [float(v) for v in before["t_s"]]
        data["before_burst_s"] = [float(v) for v in before["burst_s"]]
        ax.plot(data["before_t_s"], data["before_burst_s"], "-", color="0.6", label="before learning")
    ax.plot(t, burst, "-", color="C0", label="burst length")
    ax.plot(data["touchdown_t_s"], data["touchdown_burst_s"], "v", color="k", label="touchdown")
    if over is not None:
        ax.axvline(over, color="C3", ls="--", label="foot over the near edge")
    ax.set(xlabel="time since the obstacle was placed [s]", ylabel="burst length [s]",
           title="Burst length over one approach")
    ax.legend(loc="best", fontsize="small")
    _save(fig, out, name)
    return data


# -- all of them from learn output folders -------------------------------------------------------


def run_label(config: dict[str, Any]) -> str:
    """How a run is named in a legend: "learning" (the paper's learner), "no learning" or its
    method's registry name (an old run's ``learner`` is the paper's)."""
    if not config.get("learning", True):
        return "no learning"
    name = config.get("method", CONTROLLER_METHOD)
    try:
        name = resolve(name).name
    except ValueError:  # a method no longer registered: its own name
        return str(name)
    return "learning" if name == CONTROLLER_METHOD else name


def _weights_at(run: dict[str, Any], height_m: float) -> np.ndarray:
    """A run's weights for an obstacle of ``height_m``: all of them for the paper's learner, the
    row of the height context it falls in for a learner with a row per context (``improved``,
    ``context``; the contexts bounded by the run's ``height.beam_heights_m``)."""
    weights = np.asarray(run["weights"], dtype=float)
    if weights.ndim == 1:
        return weights
    bounds = _context_bounds_m(run["config"]["controller"]["height"]["beam_heights_m"])
    row = next(k for k, (lo, hi) in enumerate(bounds) if lo <= height_m < hi)
    return weights[min(row, weights.shape[0] - 1)]


def _height_of(config: dict[str, Any]) -> float | None:
    """The run's obstacle height [m], or None for a run of mixed heights."""
    return None if config.get("obstacle_heights_m") else float(config["obstacle_height_m"])


def _late_window(runs: list[dict[str, Any]]) -> tuple[int, int]:
    return late_window(min(len(r["trials"]) for r in runs))


def _traced_pair(run: dict[str, Any]) -> tuple[dict[str, Any], dict[str, Any]] | None:
    traced = [t for t in run["trials"] if "trace" in t]
    return (traced[0], traced[-1]) if len(traced) >= 2 else None


def paper_figures(folders: Sequence[str | Path], out: str | Path) -> dict[str, list[Path]]:
    """Load ``learn`` output folders and write every figure their data allows into ``out``:

    - ``learning_curve_seeds``: running success, mean and 95% interval over seeds, one band per
      method and obstacle height;
    - ``footfall_spread_by_size`` (Fig. 3): learning runs grouped by obstacle height (a warning
      if fewer than 3 heights);
    - ``weights_h{H}cm`` and ``weights_autocorrelation_h{H}cm`` (Fig. 4): the lowest seed with
      weights at each height;
    - ``foot_trajectories`` (Fig. 2) and ``burst_over_approach``: the first and last traced trial
      of one learning run (the first whose traced first trial failed and last succeeded, else the
      first with two traced trials).

    Figs. 2-4 ("learning runs") are drawn from one method's runs: the paper's learner's where the
    folders hold some (the paper's figures of the paper's model), else ``learn``'s default's
    (``improved``; its weights at a height are the row of that height's context).

    Returns each written figure's name and its files.
    """
    if not folders:
        raise ValueError("paper_figures needs at least one learn output folder")
    out = Path(out)
    runs = [load_run(f) for f in folders]
    runs.sort(key=lambda r: (run_label(r["config"]), _height_of(r["config"]) or -1.0, r["config"].get("seed", 0)))
    written: dict[str, list[Path]] = {}

    def wrote(name: str) -> None:
        written[name] = [out / f"{name}.png", out / f"{name}.svg"]

    curves: dict[str, list[list[bool]]] = {}
    for r in runs:
        h = _height_of(r["config"])
        key = f"{run_label(r['config'])}, {'mixed heights' if h is None else f'{h * 100:g} cm'}"
        curves.setdefault(key, []).append([bool(t["success"]) for t in r["trials"]])
    success_curves(curves, out)
    wrote("learning_curve_seeds")

    learning: list[dict[str, Any]] = []
    for label in ("learning", DEFAULT_METHOD):  # the paper's learner's runs, else learn's default's
        learning = [r for r in runs if run_label(r["config"]) == label]
        if learning:
            break
    by_height: dict[float, list[dict[str, Any]]] = {}
    for r in learning:
        h = _height_of(r["config"])
        if h is not None:
            by_height.setdefault(h, []).append(r)
    if by_height:
        first, last = _late_window([r for g in by_height.values() for r in g])
        footfall_spread_by_size(by_height, out, first, last)
        wrote("footfall_spread_by_size")
    else:
        log.warning("no learning run at a single obstacle height: no footfall spread by size")

    for h, group in sorted(by_height.items()):
        with_weights = [r for r in group if "weights" in r]
        if not with_weights:
            continue
        r = with_weights[0]
        tag = f"h{h * 100:g}cm"
        weights = _weights_at(r, h)
        weights_by_distance(weights, r["cell_width_m"], out, name=f"weights_{tag}")
        weights_autocorrelation(weights, r["cell_width_m"], out, name=f"weights_autocorrelation_{tag}")
        wrote(f"weights_{tag}")
        wrote(f"weights_autocorrelation_{tag}")

    pairs = [(r, p) for g in by_height.values() for r in g if (p := _traced_pair(r)) is not None]
    if pairs:
        run, (before, after) = next(((r, p) for r, p in pairs if not p[0]["success"] and p[1]["success"]), pairs[0])
        cfg = run["config"]
        depth = float(cfg["obstacle_depth_m"])
        foot_trajectories(before["trace"], after["trace"], float(after["obstacle_height_m"]), depth, out,
                          labels=(f"before learning (trial {before['index'] + 1})",
                                  f"after {after['index']} trials (trial {after['index'] + 1})"))
        wrote("foot_trajectories")
        burst_over_approach(after["trace"], out, before=before["trace"],
                            obstacle_height_m=float(after["obstacle_height_m"]), obstacle_depth_m=depth)
        wrote("burst_over_approach")
        log.info("Fig. 2 from seed %s, trials %d and %d", cfg.get("seed"), before["index"] + 1, after["index"] + 1)
    else:
        log.warning("no learning run at one obstacle height with two traced trials (learn records trials 1 and N): "
                    "no foot trajectories")
    return written
