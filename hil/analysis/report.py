"""The sweep's report: ``DIR/figures/`` and ``DIR/report.md`` from a sweep folder.

Everything is computed from ``summary.json``'s rows (and, for the success curves, from the cells'
``metrics.json``); no figure in the text is hard-coded. :func:`write_report` works on any finished
or partly finished sweep folder (``elegant-stepping sweep --out DIR --report-only``);
:func:`headline_table` returns the report's table as data. The plot functions return the numbers
they draw, so tests check data rather than pixels.
"""

from __future__ import annotations

import json
import logging
import statistics
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from controller.atomic import write_text_atomic
from controller.errors import InputError, check_stamp
from hil.analysis.figures import _save, subplots, success_curves  # one way to draw and write PNG + SVG; one curve plot
from hil.analysis.metrics import read_metrics
from hil.experiments.conditions import changed_options
from hil.experiments.methods import resolve
from hil.experiments.sweep import cells_from_json, height_tag, read_sweep_config

log = logging.getLogger(__name__)

CRITERION = "10 consecutive trials at least 90% successful"
WINDOW = 10  # trials in the running success of the curves


def _key(height: Any) -> float | tuple[float, ...]:
    return tuple(height) if isinstance(height, list) else height


def height_label(height: Any) -> str:
    """``0.06 m``, or ``mixed 0.06/0.1 m`` for a scenario whose trials draw from several heights."""
    if isinstance(height, (list, tuple)):
        return "mixed " + "/".join(f"{h:g}" for h in height) + " m"
    return f"{height:g} m"


SWEEP_SUMMARY_FORMAT = "sweep-summary"
"""``summary.json``: version 1 is stamped, an object with ``rows``; version 0 (before stamps) was a
bare list of rows. ``config.json`` is read by :func:`hil.experiments.sweep.read_sweep_config`."""
ROW_KEYS = ("method", "obstacle_height_m", "seed", "trials", "trials_to_criterion", "mistakes_after_100",
            "success_last_50", "success_rate", "cell")


def _read_json(path: Path) -> Any:
    try:
        return json.loads(path.read_bytes())
    except FileNotFoundError:
        raise FileNotFoundError(f"{path}: not found (is {path.parent} a sweep folder?)") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: not valid JSON ({exc})") from None


def read_summary_rows(path: str | Path) -> list[dict[str, Any]]:
    """A sweep's ``summary.json`` rows: version 1 ``{stamp..., "rows": [...]}``, version 0 a bare list.

    Raises:
        FileNotFoundError: no such file.
        InputError: not JSON, an unknown version, or rows of the wrong structure.
    """
    path = Path(path)
    data = _read_json(path)
    if isinstance(data, list):
        rows = data  # version 0
    else:
        check_stamp(data, SWEEP_SUMMARY_FORMAT, (1,), str(path))
        rows = data.get("rows")
        if not isinstance(rows, list):
            raise InputError(f"{path}: 'rows' is not a list of rows")
    for k, row in enumerate(rows):
        if not isinstance(row, dict) or any(key not in row for key in ROW_KEYS):
            raise InputError(f"{path}: row {k} is not a sweep summary row (it needs {', '.join(ROW_KEYS)})")
    return rows


def load_sweep(out_dir: str | Path) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """A sweep folder's ``config.json`` (without its stamp) and ``summary.json`` rows, either version."""
    out = Path(out_dir)
    return read_sweep_config(out / "config.json"), read_summary_rows(out / "summary.json")


def _mean(values: Sequence[float | None]) -> float | None:
    values = [v for v in values if v is not None]
    return statistics.fmean(values) if values else None


def headline_table(rows: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """One entry per (height, method), heights in row order, methods in row order.

    Each: ``obstacle_height_m``, ``method``, ``seeds``, ``trials``; trials to criterion over the
    seeds that reached it (``trials_to_criterion_mean``, ``_min``, ``_max``) and ``never_reached``
    (seeds that did not); ``mistakes_after_100_mean`` and ``seeds_without_mistakes_after_100``
    (None if the runs have no trial after 100); ``success_last_50_mean``; ``success_rate_mean``.
    """
    groups: dict[Any, dict[str, list[dict[str, Any]]]] = {}
    for r in rows:
        groups.setdefault(_key(r["obstacle_height_m"]), {}).setdefault(r["method"], []).append(r)
    table = []
    for height in sorted(groups, key=lambda h: (isinstance(h, tuple), h)):
        for method, group in groups[height].items():
            ttc = [r["trials_to_criterion"] for r in group if r["trials_to_criterion"] is not None]
            mistakes = [r["mistakes_after_100"] for r in group if r["mistakes_after_100"] is not None]
            table.append({
                "obstacle_height_m": group[0]["obstacle_height_m"],
                "method": method,
                "seeds": len(group),
                "trials": sorted({r["trials"] for r in group}),
                "trials_to_criterion_mean": _mean(ttc),
                "trials_to_criterion_min": min(ttc) if ttc else None,
                "trials_to_criterion_max": max(ttc) if ttc else None,
                "never_reached": len(group) - len(ttc),
                "mistakes_after_100_mean": _mean(mistakes),
                "seeds_without_mistakes_after_100": sum(m == 0 for m in mistakes) if mistakes else None,
                "success_last_50_mean": _mean([r["success_last_50"] for r in group]),
                "success_rate_mean": _mean([r["success_rate"] for r in group]),
            })
    return table


def criterion_bars(table: Sequence[dict[str, Any]], out: Path, name: str = "criterion_bars") -> dict[str, Any]:
    """Bars by method, one per height: mean trials to criterion (over the seeds that reached it)
    and mean success over the last 50 trials. Returns ``methods``, ``heights`` (labels) and, per
    quantity, one list per height in method order (None where there is nothing to draw)."""
    methods = list(dict.fromkeys(e["method"] for e in table))
    heights = list(dict.fromkeys(height_label(e["obstacle_height_m"]) for e in table))
    cell = {(height_label(e["obstacle_height_m"]), e["method"]): e for e in table}
    data: dict[str, Any] = {"methods": methods, "heights": heights}
    fig, axes = subplots(1, 2, figsize=(10, 3.6))
    width = 0.8 / len(heights)
    x = np.arange(len(methods))
    for ax, key, ylabel in ((axes[0], "trials_to_criterion_mean", "trials to criterion (mean of seeds reaching it)"),
                            (axes[1], "success_last_50_mean", "success, last 50 trials")):
        data[key] = []
        for j, h in enumerate(heights):
            values = [cell[(h, m)][key] if (h, m) in cell else None for m in methods]
            data[key].append(values)
            ax.bar(x + (j - (len(heights) - 1) / 2) * width, [np.nan if v is None else v for v in values],
                   width=width * 0.95, color=f"C{j}", label=h)
            if key == "trials_to_criterion_mean":
                for i, m in enumerate(methods):
                    never = cell[(h, m)]["never_reached"] if (h, m) in cell else 0
                    if never:
                        ax.annotate(f"{never} never", (x[i] + (j - (len(heights) - 1) / 2) * width, 0),
                                    ha="center", va="bottom", fontsize="x-small", rotation=90)
        ax.set_xticks(x, methods)
        ax.set(ylabel=ylabel)
    axes[1].set_ylim(0, 1.05)
    axes[0].legend(title="obstacle", fontsize="small")
    _save(fig, out, name)
    return data


def _fmt(value: float | None, digits: int = 1) -> str:
    return "–" if value is None else f"{value:.{digits}f}"


def _pct(value: float | None) -> str:
    return "–" if value is None else f"{value:.0%}"


def _ttc_text(e: dict[str, Any]) -> str:
    n = e["seeds"]
    if e["trials_to_criterion_mean"] is None:
        return f"never reached the criterion on any of its {n} seeds"
    text = (f"reached the criterion after {e['trials_to_criterion_mean']:.1f} trials on average "
            f"(range {e['trials_to_criterion_min']}–{e['trials_to_criterion_max']} over {n - e['never_reached']} seeds")
    return text + (f"; {e['never_reached']} of {n} seeds never reached it)" if e["never_reached"] else ")")


def _mistakes_text(e: dict[str, Any]) -> str:
    if e["mistakes_after_100_mean"] is None:
        return f"mistakes after trial 100 are not measured (runs of {'/'.join(map(str, e['trials']))} trials)"
    return (f"made {e['mistakes_after_100_mean']:.2f} mistakes after trial 100 on average "
            f"({e['seeds_without_mistakes_after_100']} of {e['seeds']} seeds made none)")


def headline_sentences(table: Sequence[dict[str, Any]]) -> dict[str, list[str]]:
    """Per height label, one sentence per method in the sweep, as its registry entry says
    (:attr:`hil.experiments.methods.Method.sentence`): trials to criterion and mistakes after 100
    (the paper's learner, rl, none), or the success rate (the oracle)."""
    out: dict[str, list[str]] = {}
    for e in table:
        lines = out.setdefault(height_label(e["obstacle_height_m"]), [])
        method = resolve(e["method"])
        if method.sentence == "criterion":
            lines.append(f"{method.label} {_ttc_text(e)}, and {_mistakes_text(e)}.")
        elif method.sentence == "success":
            lines.append(f"{method.label} succeeded in {_pct(e['success_rate_mean'])} of all trials "
                         f"({_pct(e['success_last_50_mean'])} over the last 50; mean of {e['seeds']} seeds).")
    return out


def _table_markdown(entries: Sequence[dict[str, Any]]) -> list[str]:
    lines = ["| method | seeds | trials to criterion: mean (range) | seeds never reaching it "
             "| mistakes after 100: mean | seeds with none | success, last 50 trials |",
             "|---|---|---|---|---|---|---|"]
    for e in entries:
        ttc = "–" if e["trials_to_criterion_mean"] is None else (
            f"{e['trials_to_criterion_mean']:.1f} ({e['trials_to_criterion_min']}–{e['trials_to_criterion_max']})")
        none = e["seeds_without_mistakes_after_100"]
        lines.append(f"| {e['method']} | {e['seeds']} | {ttc} | {e['never_reached']} "
                     f"| {_fmt(e['mistakes_after_100_mean'], 2)} | {'–' if none is None else none} "
                     f"| {_pct(e['success_last_50_mean'])} |")
    return lines


def _seeds_text(seeds: Sequence[int]) -> str:
    seeds = sorted(seeds)
    if len(seeds) > 2 and seeds == list(range(seeds[0], seeds[-1] + 1)):
        return f"{seeds[0]}-{seeds[-1]}"
    return ",".join(map(str, seeds))


def write_report(out_dir: str | Path) -> dict[str, Any]:
    """Write ``figures/`` and ``report.md`` for the sweep folder ``out_dir``; return the table,
    the sentences, the plotted data and the missing cells."""
    out = Path(out_dir)
    config, rows = load_sweep(out)
    if not rows:
        raise InputError(f"{out / 'summary.json'}: no finished cell to report on")
    done = {r["cell"] for r in rows}
    missing = [c.name for c in cells_from_json(config) if c.name not in done]
    table = headline_table(rows)
    sentences = headline_sentences(table)
    fig_dir = out / "figures"

    curves: dict[str, dict[str, Any]] = {}
    by_height: dict[Any, dict[str, list[list[bool]]]] = {}
    for r in rows:
        metrics = read_metrics(out / "cells" / str(r["cell"]) / "metrics.json", parts=("trials",))
        by_height.setdefault(_key(r["obstacle_height_m"]), {}).setdefault(r["method"], []).append(
            [bool(t["success"]) for t in metrics["trials"]])
    figure_files: list[tuple[str, str]] = []
    for height in sorted(by_height, key=lambda h: (isinstance(h, tuple), h)):
        label, name = height_label(height), f"success_curves_{height_tag(height)}"
        curves[label] = success_curves(by_height[height], fig_dir, name, window=WINDOW,
                                       title=f"Running success ({WINDOW} trials), obstacle {label}")
        figure_files.append((f"Success curves, obstacle {label}", f"figures/{name}.png"))
    bars = criterion_bars(table, fig_dir)
    figure_files.append(("Trials to criterion and success over the last 50 trials", "figures/criterion_bars.png"))

    cmd = (f"elegant-stepping sweep --out {out} --seeds {_seeds_text(config['seeds'])} "
           f"--obstacle-heights-m {','.join(f'{h:g}' for h in config['obstacle_heights_m'])} "
           f"--methods {','.join(resolve(m).name for m in config['methods'])} --trials {config['trials']}"
           + (" --mixed-heights" if config["mixed_heights"] else "")
           + "".join(f" {w}" for w in changed_options(config.get("conditions", {}))))
    md = ["# Sweep report", "",
          "## Configuration", "",
          f"- methods: {', '.join(config['methods'])}",
          f"- obstacle heights: {', '.join(f'{h:g}' for h in config['obstacle_heights_m'])} m"
          + (" (mixed: each trial draws its height from the list)" if config["mixed_heights"] else ""),
          f"- seeds: {_seeds_text(config['seeds'])} ({len(config['seeds'])})",
          f"- trials per run: {config['trials']}",
          f"- criterion: {CRITERION} (trials to criterion = trials run before the first such window)",
          f"- reproduce: `{cmd}`", ""]
    if missing:
        md += [f"**Incomplete: {len(missing)} cells have no result** ({', '.join(missing)}); "
               "see `timing.json`.", ""]
    for label in dict.fromkeys(height_label(e["obstacle_height_m"]) for e in table):
        md += [f"## Obstacle {label}", ""]
        md += _table_markdown([e for e in table if height_label(e["obstacle_height_m"]) == label])
        md += [""] + [f"- {s}" for s in sentences.get(label, [])] + [""]
    md += ["## Figures", ""]
    for caption, path in figure_files:
        md += [f"![{caption}]({path})", ""]
    write_text_atomic(out / "report.md", "\n".join(md))
    log.info("wrote %s", out / "report.md")
    return {"table": table, "sentences": sentences, "curves": curves, "bars": bars, "missing": missing,
            "report": out / "report.md"}
