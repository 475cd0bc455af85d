"""The per-seed table of a sweep, methods side by side, with 95% intervals (issue 18's report).

For each method of a sweep folder (its ``cells/*/metrics.json``) and each seed: trials to
criterion (:func:`hil.analysis.stats.trials_to_criterion`), mistakes after trial 50 and after
trial 100, success over all trials, the contacts no reflex heard (``contact_misses``, where the
records have them) and, for mixed heights, success over the last 50 trials per height. Below the
seeds, per method:

- the median trials to criterion, with a percentile bootstrap 95% interval (10,000 resamples of
  the seeds, seeded: the same table every time); a seed that never reached the criterion counts
  as the number of trials;
- the mean success, with a t interval over the seeds (cut to [0, 1]);
- the share of seeds with no mistake after trial 100 and after trial 50, with Wilson 95% intervals;
- per height (mixed heights): the success over the last 50 trials, pooled over the seeds, with a
  Wilson interval.

Run as ``python -m hil.analysis.heldout SWEEP_FOLDER`` (markdown on stdout).

May import what :mod:`hil.analysis` may.
"""

from __future__ import annotations

import json
import math
import sys
from collections import defaultdict
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from hil.analysis.stats import mean_ci95, trials_to_criterion

Z95 = 1.959964


def wilson95(successes: int, n: int) -> tuple[float, float]:
    """Wilson score 95% interval of a proportion (0, 1 for no observations)."""
    if n == 0:
        return 0.0, 1.0
    p = successes / n
    denom = 1.0 + Z95 ** 2 / n
    centre = (p + Z95 ** 2 / (2 * n)) / denom
    half = Z95 * math.sqrt(p * (1 - p) / n + Z95 ** 2 / (4 * n * n)) / denom
    return max(0.0, centre - half), min(1.0, centre + half)


def median_ci95(values: Sequence[float], resamples: int = 10000, seed: int = 0) -> tuple[float, float, float]:
    """Median and percentile bootstrap 95% interval (seeded)."""
    a = np.asarray(values, dtype=float)
    rng = np.random.default_rng(seed)
    medians = np.median(a[rng.integers(0, len(a), size=(resamples, len(a)))], axis=1)
    return float(np.median(a)), float(np.percentile(medians, 2.5)), float(np.percentile(medians, 97.5))


def seed_rows(sweep: str | Path) -> dict[str, list[dict[str, Any]]]:
    """Per method, one row per seed (in seed order) from the sweep's finished cells."""
    rows: dict[str, list[dict[str, Any]]] = defaultdict(list)
    for path in sorted(Path(sweep, "cells").glob("*/metrics.json")):
        m = json.loads(path.read_text())
        trials = m["trials"]
        ok = [bool(t["success"]) for t in trials]
        ttc = trials_to_criterion(ok)
        by_height: dict[float, list[bool]] = defaultdict(list)
        for t in trials[-50:]:
            by_height[t["obstacle_height_m"]].append(bool(t["success"]))
        rows[m["config"]["method"]].append({
            "seed": m["config"]["seed"], "trials": len(ok), "ttc": ttc,
            "ttc_value": ttc if ttc is not None else len(ok), "after_50": ok[50:].count(False),
            "after_100": ok[100:].count(False), "success": sum(ok) / len(ok),
            "contact_misses": sum(t.get("contact_misses", 0) for t in trials),
            "stalled": sum(1 for t in trials if t.get("stalled")),
            "late_by_height": {h: (sum(v), len(v)) for h, v in by_height.items()}})
    for method in rows:
        rows[method].sort(key=lambda r: r["seed"])
    return dict(rows)


def summary(rows: list[dict[str, Any]]) -> dict[str, Any]:
    n = len(rows)
    med, med_lo, med_hi = median_ci95([r["ttc_value"] for r in rows])
    mean, lo, hi = mean_ci95([[r["success"]] for r in rows])
    lo[0], hi[0] = max(0.0, lo[0]), min(1.0, hi[0])  # a success rate's t interval, cut to [0, 1]
    clean_100 = sum(r["after_100"] == 0 for r in rows)
    clean_50 = sum(r["after_50"] == 0 for r in rows)
    heights: dict[float, list[int]] = defaultdict(lambda: [0, 0])
    for r in rows:
        for h, (s, k) in r["late_by_height"].items():
            heights[h][0] += s
            heights[h][1] += k
    return {"seeds": n, "ttc_median": med, "ttc_ci95": (med_lo, med_hi),
            "never": sum(r["ttc"] is None for r in rows),
            "success_mean": mean[0], "success_ci95": (lo[0], hi[0]),
            "clean_after_100": clean_100, "clean_after_100_ci95": wilson95(clean_100, n),
            "clean_after_50": clean_50, "clean_after_50_ci95": wilson95(clean_50, n),
            "contact_misses": sum(r["contact_misses"] for r in rows), "stalled": sum(r["stalled"] for r in rows),
            "late_by_height": {h: (s, k, wilson95(s, k)) for h, (s, k) in sorted(heights.items())}}


def markdown(sweep: str | Path) -> str:
    rows = seed_rows(sweep)
    if not rows:
        raise ValueError(f"{sweep}: no finished cells (cells/*/metrics.json)")
    methods = list(rows)
    lines = ["| seed | " + " | ".join(f"{m}: ttc, after 50, after 100, success" for m in methods) + " |",
             "|---|" + "---|" * len(methods)]
    seeds = sorted({r["seed"] for m in methods for r in rows[m]})
    for seed in seeds:
        cells = []
        for m in methods:
            r = next((r for r in rows[m] if r["seed"] == seed), None)
            cells.append("-" if r is None else
                         f"{'never' if r['ttc'] is None else r['ttc']}, {r['after_50']}, {r['after_100']}, "
                         f"{r['success']:.3f}")
        lines.append(f"| {seed} | " + " | ".join(cells) + " |")
    lines += ["", "| method | seeds | trials to criterion, median [95%] | mean success [95%] | "
              "no mistake after 100 [95%] | no mistake after 50 [95%] | contacts no reflex heard | stalled |",
              "|---|---|---|---|---|---|---|---|"]
    sums = {m: summary(rows[m]) for m in methods}
    for m, s in sums.items():
        lines.append(
            f"| {m} | {s['seeds']} | {s['ttc_median']:g} [{s['ttc_ci95'][0]:g}, {s['ttc_ci95'][1]:g}]"
            f"{' (' + str(s['never']) + ' never)' if s['never'] else ''} | "
            f"{s['success_mean']:.3f} [{s['success_ci95'][0]:.3f}, {s['success_ci95'][1]:.3f}] | "
            f"{s['clean_after_100']}/{s['seeds']} [{s['clean_after_100_ci95'][0]:.2f}, "
            f"{s['clean_after_100_ci95'][1]:.2f}] | {s['clean_after_50']}/{s['seeds']} "
            f"[{s['clean_after_50_ci95'][0]:.2f}, {s['clean_after_50_ci95'][1]:.2f}] | {s['contact_misses']} | "
            f"{s['stalled']} |")
    if any(len(s["late_by_height"]) > 1 for s in sums.values()):
        heights = sorted({h for s in sums.values() for h in s["late_by_height"]})
        lines += ["", "Success over the last 50 trials by height, pooled over the seeds [Wilson 95%]:", "",
                  "| method | " + " | ".join(f"{h:g} m" for h in heights) + " |",
                  "|---|" + "---|" * len(heights)]
        for m, s in sums.items():
            cells = []
            for h in heights:
                if h not in s["late_by_height"]:
                    cells.append("-")
                    continue
                k, n, (lo, hi) = s["late_by_height"][h]
                cells.append(f"{k}/{n} = {k / n:.3f} [{lo:.3f}, {hi:.3f}]")
            lines.append(f"| {m} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) != 1:
        print("usage: python -m hil.analysis.heldout SWEEP_FOLDER", file=sys.stderr)
        return 2
    try:
        sys.stdout.write(markdown(argv[0]))
    except (OSError, ValueError, KeyError) as exc:
        print(f"heldout: error: {argv[0]}: {exc}", file=sys.stderr)
        return 3
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
