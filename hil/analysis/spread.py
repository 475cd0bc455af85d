"""The paper's claim R3 with statistics: footfall spread against the steps before the obstacle and
against the obstacle's size (the paper's Fig. 3, with intervals and a test of the trend).

The paper: "the variance in footfalls decreases as the robotic leg approaches the obstacle" and
"the variance in footsteps also decreases with increasing object size". Here, from the cells of
a ``sweep`` run on a grid of heights (one learn run per seed and height):

- **the statistic**: for each run, the s.d. of the footfall position ``k`` steps before the
  obstacle (``k`` = 1: the last footfall before it) over its late trials (default 101-150, when
  the weights have settled); one run is one leg learning, so the s.d. is taken within a run and
  then averaged over the seeds at each height. (Pooling every seed's footfalls, as
  :func:`hil.analysis.metrics.footfall_std_by_step` does for the plain Fig. 3, adds the spread
  between the seeds' own sweet spots; it is given too, as ``pooled_sd_m``.)
- **the intervals**: percentile bootstrap 95% intervals of that mean, resampling the seeds with
  replacement (the seed is the unit that repeats; the trials of one run are not independent).
- **the size trend**: the least-squares slope of the per-run s.d. against the height, and a
  permutation test of it: the height labels are shuffled among the runs (exchangeable if size
  does not matter), the slope recomputed each time; ``p_decrease`` is the share of shuffles with
  a slope at most the observed one (one-sided, the paper's direction), ``p_two_sided`` the share
  with an absolute slope at least the observed one's.
- **the approach trend**: per run, the s.d. 4 steps before minus at the last step, averaged over
  all runs, with a bootstrap interval over the runs, and the share of runs in which it narrows.

The random draws are seeded (``--seed``): the same folder gives the same numbers every time.

Run as ``python -m hil.analysis.spread SWEEP_FOLDER --out DIR``: writes ``DIR/spread.json``,
``DIR/fig3_spread.png`` and ``.svg`` (captioned "Fig. 3") and prints a markdown table.

May import what :mod:`hil.analysis` may.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from controller.errors import InputError
from hil.analysis.metrics import footfall_std_by_step

STEPS = 4
"""Footfalls before the obstacle the paper's Fig. 3 shows."""


def run_sd_by_step(trials: Sequence[dict[str, Any]], first: int, last: int, steps: int = STEPS) -> list[float]:
    """The s.d. [m] of the footfall ``k`` steps before the obstacle (k = 1..steps) over trials
    ``first..last`` (1-based, inclusive) of one run; NaN where fewer than 2 trials had that step."""
    out = []
    for k in range(1, steps + 1):
        xs = [t["footfalls_m"][-k] for t in trials[first - 1 : last] if len(t["footfalls_m"]) >= k]
        out.append(statistics.pstdev(xs) if len(xs) > 1 else float("nan"))
    return out


def bootstrap_mean_ci(values: np.ndarray, rng: np.random.Generator, n: int = 10_000) -> tuple[float, float]:
    """Percentile bootstrap 95% interval of the mean of ``values`` (rows resampled; NaN-free)."""
    values = np.asarray(values, dtype=float)
    if len(values) < 2:
        v = float(values.mean()) if len(values) else float("nan")
        return v, v
    idx = rng.integers(0, len(values), size=(n, len(values)))
    means = values[idx].mean(axis=1)
    lo, hi = np.percentile(means, [2.5, 97.5])
    return float(lo), float(hi)


def slope(x: np.ndarray, y: np.ndarray) -> float:
    """Least-squares slope of ``y`` against ``x``."""
    xc = x - x.mean()
    return float((xc * (y - y.mean())).sum() / (xc * xc).sum())


def permutation_slope_test(x: np.ndarray, y: np.ndarray, rng: np.random.Generator,
                           n: int = 10_000) -> dict[str, float]:
    """The observed slope of ``y`` on ``x`` and its permutation p-values (labels ``x`` shuffled):
    one-sided for a decrease and two-sided. The observed labelling counts as one permutation, so no
    p-value is 0."""
    observed = slope(x, y)
    xc = x - x.mean()
    denom = float((xc * xc).sum())
    perms = np.array([rng.permutation(xc) for _ in range(n)])
    slopes = perms @ (y - y.mean()) / denom
    p_dec = (1 + int((slopes <= observed + 1e-15).sum())) / (n + 1)
    p_two = (1 + int((np.abs(slopes) >= abs(observed) - 1e-15).sum())) / (n + 1)
    return {"slope": observed, "p_decrease": p_dec, "p_two_sided": p_two, "permutations": n}


def load_sweep_runs(folder: Path, method: str) -> dict[float, list[dict[str, Any]]]:
    """The ``method``'s cells of a sweep folder, grouped by obstacle height [m]: each a dict with
    ``seed`` and ``trials``. Cells of mixed heights are refused (this is a grid question)."""
    from hil.analysis.metrics import load_run
    from hil.experiments.methods import CONTROLLER_METHOD, resolve

    cells = folder / "cells"
    if not cells.is_dir():
        raise InputError(f"{folder}: no cells/ folder (give a sweep's output folder)")
    groups: dict[float, list[dict[str, Any]]] = {}
    for cell in sorted(p for p in cells.iterdir() if p.is_dir()):
        run = load_run(cell)
        config = run["config"]
        if resolve(config.get("method", CONTROLLER_METHOD)).name != method:
            continue
        if config.get("obstacle_heights_m"):
            raise InputError(f"{cell}: a run of mixed heights; R3 compares runs at one height each")
        groups.setdefault(float(config["obstacle_height_m"]), []).append(
            {"seed": int(config["seed"]), "trials": run["trials"]})
    if not groups:
        raise InputError(f"{folder}: no {method} cells")
    return groups


def analyse(groups: dict[float, list[dict[str, Any]]], first: int, last: int, *, seed: int = 0,
            resamples: int = 10_000) -> dict[str, Any]:
    """Every figure of R3 from runs grouped by height (see the module's docstring)."""
    if len(groups) < 2:
        raise InputError(f"R3 needs runs at 2 heights at least, got {len(groups)}")
    rng = np.random.default_rng(seed)
    heights = sorted(groups)
    by_height: dict[str, Any] = {}
    xs, ys_by_k = [], [[] for _ in range(STEPS)]
    narrowing = []
    for h in heights:
        runs = groups[h]
        sd = np.array([run_sd_by_step(r["trials"], first, last) for r in runs])  # runs x steps
        row: dict[str, Any] = {"seeds": sorted(r["seed"] for r in runs), "mean_sd_m": [], "ci95_m": [],
                               "pooled_sd_m": footfall_std_by_step(runs, first, last, STEPS)}
        for k in range(STEPS):
            col = sd[:, k][~np.isnan(sd[:, k])]
            row["mean_sd_m"].append(float(col.mean()) if len(col) else None)
            row["ci95_m"].append(list(bootstrap_mean_ci(col, rng, resamples)) if len(col) else None)
        for r_sd in sd:
            xs.append(h)
            for k in range(STEPS):
                ys_by_k[k].append(r_sd[k])
            if not np.isnan(r_sd[STEPS - 1]) and not np.isnan(r_sd[0]):
                narrowing.append(r_sd[STEPS - 1] - r_sd[0])
        by_height[f"{h:g}"] = row
    x = np.array(xs)
    trend = []
    for k in range(STEPS):
        y = np.array(ys_by_k[k])
        ok = ~np.isnan(y)
        trend.append({"steps_before": k + 1, **permutation_slope_test(x[ok], y[ok], rng, resamples)})
    narrow = np.array(narrowing)
    return {
        "trials": [first, last],
        "heights_m": heights,
        "runs": sum(len(g) for g in groups.values()),
        "by_height": by_height,
        "size_trend": trend,
        "approach_narrowing": {
            "mean_sd4_minus_sd1_m": float(narrow.mean()),
            "ci95_m": list(bootstrap_mean_ci(narrow, rng, resamples)),
            "runs_narrowing": int((narrow > 0).sum()),
            "runs": int(len(narrow)),
        },
        "resamples": resamples,
        "seed": seed,
    }


def figure(result: dict[str, Any], out: Path, name: str = "fig3_spread", method: str = "paper") -> list[Path]:
    """Fig. 3 with the intervals: mean within-run footfall s.d. against the steps before the
    obstacle, one line per height, bootstrap 95% intervals as error bars."""
    from hil.analysis.figures import _save, subplots

    fig, ax = subplots(figsize=(5.5, 3.8))
    k = np.arange(1, STEPS + 1)
    heights = result["heights_m"]
    for i, h in enumerate(heights):
        row = result["by_height"][f"{h:g}"]
        mean = np.array([np.nan if v is None else v * 100 for v in row["mean_sd_m"]])
        lo = np.array([np.nan if c is None else c[0] * 100 for c in row["ci95_m"]])
        hi = np.array([np.nan if c is None else c[1] * 100 for c in row["ci95_m"]])
        dx = (i - (len(heights) - 1) / 2) * 0.05  # side by side, so the bars do not hide each other
        ax.errorbar(k + dx, mean, yerr=[mean - lo, hi - mean], fmt="o-", capsize=3,
                    label=f"{h * 100:g} cm ({len(row['seeds'])} seeds)")
    t1 = result["size_trend"][0]
    first, last = result["trials"]
    ax.set(xlabel="steps before the obstacle", ylabel="footfall s.d. within a run [cm]",
           title=f"Fig. 3: footfall spread by obstacle size ({method}, trials {first}-{last})")
    ax.set_xticks(k)
    ax.invert_xaxis()
    ax.legend(title="obstacle height", fontsize="small")
    fig.text(0.01, 0.005, f"last step: slope {t1['slope'] * 100:+.2f} cm per m of height, permutation "
             f"p(decrease) = {t1['p_decrease']:.3f}; bars: bootstrap 95% over seeds", fontsize=7)
    fig.subplots_adjust(bottom=0.2)
    return _save(fig, out, name)


def markdown(result: dict[str, Any]) -> str:
    """The table of R3: one row per height, the s.d. at each step with its interval; the tests."""
    lines = ["| height | seeds | " + " | ".join(f"{k} step{'s' if k > 1 else ''} before [cm]"
                                                 for k in range(STEPS, 0, -1)) + " |",
             "|---|---|" + "---|" * STEPS]
    for h in result["heights_m"]:
        row = result["by_height"][f"{h:g}"]
        cells = []
        for k in range(STEPS - 1, -1, -1):
            m, ci = row["mean_sd_m"][k], row["ci95_m"][k]
            cells.append("-" if m is None else f"{m * 100:.2f} [{ci[0] * 100:.2f}, {ci[1] * 100:.2f}]")
        lines.append(f"| {h:g} m | {len(row['seeds'])} | " + " | ".join(cells) + " |")
    lines += ["", "| steps before | slope of s.d. on height [cm per cm] | permutation p, decrease | p, two-sided |",
              "|---|---|---|---|"]
    for t in result["size_trend"]:
        lines.append(f"| {t['steps_before']} | {t['slope']:+.3f} | {t['p_decrease']:.4f} | {t['p_two_sided']:.4f} |")
    n = result["approach_narrowing"]
    lines += ["", f"Approach: s.d. 4 steps before minus at the last step, mean over {n['runs']} runs "
              f"{n['mean_sd4_minus_sd1_m'] * 100:.2f} cm [{n['ci95_m'][0] * 100:.2f}, {n['ci95_m'][1] * 100:.2f}]; "
              f"narrower at the last step in {n['runs_narrowing']} of {n['runs']} runs."]
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m hil.analysis.spread", description=__doc__.split("\n\n")[0])
    p.add_argument("folder", type=Path, help="a sweep's output folder (cells of one height each)")
    p.add_argument("--out", type=Path, required=True, help="where spread.json and the figure go")
    p.add_argument("--method", default="paper", help="whose cells (default paper)")
    p.add_argument("--first", type=int, default=101, help="first trial of the late window (default 101)")
    p.add_argument("--last", type=int, default=150, help="last trial of the late window (default 150)")
    p.add_argument("--resamples", type=int, default=10_000, help="bootstrap and permutation draws (default 10000)")
    p.add_argument("--seed", type=int, default=0, help="seed of the draws (default 0)")
    args = p.parse_args(argv)
    try:
        if not 1 <= args.first <= args.last:
            raise InputError(f"need 1 <= --first <= --last, got {args.first}, {args.last}")
        if args.resamples < 100:
            raise InputError(f"--resamples must be at least 100, got {args.resamples}")
        result = analyse(load_sweep_runs(args.folder, args.method), args.first, args.last, seed=args.seed,
                         resamples=args.resamples)
    except (InputError, FileNotFoundError) as exc:
        print(f"spread: {exc}", file=sys.stderr)
        return 3
    args.out.mkdir(parents=True, exist_ok=True)
    result["method"] = args.method
    (args.out / "spread.json").write_text(json.dumps(result, indent=1) + "\n")
    figure(result, args.out, method=args.method)
    print(markdown(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
