"""Tuning the improved learner: its settings tried on the tuning seeds, never on the held-out ones.

The project's held-out discipline (docs/improved.md): settings are chosen on seeds 0-99 only and
every figure reported on seeds 1000-1019, which no tuning run may touch. This module is how the
improved learner's defaults were chosen, and it refuses any seed outside 0-99::

    python -m hil.experiments.tuning --seeds 20-39 --set spread_fade=5 --set weight_limit_s=0.5

runs 150 trials (``--trials``) of the ``improved`` method for each seed with those
:class:`controller.stepping.improved.ImprovedConfig` settings (the rest its defaults), on
``--workers`` processes, and prints one line per seed (trials to criterion, success over all
trials, mistakes after trial 50 and after trial 100, the failed trials, the contacts no reflex
heard) and a summary line.
``--heights`` mixes heights per trial (the last 50 trials' success per height is printed).
``--controller SECTION.NAME=VALUE`` changes a setting of the controller the learner runs in (for
example ``encoder.cell_width_m=0.02``: finer range cells; the sensor board is not changed).
Each seed's line ends with its successes per 50 trials (``per 50``) and how many step cycles
rule 13 read blended (``blended``: 0 means the run's records are those of the one-hot readout).
``--condition NAME=VALUE`` changes a condition of the run (a :class:`hil.experiments.learn.LearnConfig`
field: ``rail_speed_m_s``, ``believed_rail_speed_m_s``, ``range_noise_m``, ``range_dropout_prob``,
``start_min_m``, ``start_max_m``, ``obstacle_depth_m``), to tune under the changed conditions
issue 18 names without touching the held-out seeds.
``--failures-after N`` also prints each failed trial from trial N on: its obstacle's height, its
last four gates (cell, gated range, the weight each cell held as the trial began), its last three
footfalls (relative to the obstacle's near face), its first reflex (kind, cause, phase, in the
swing or not), and how often its path (its last three gated cells) and its last gated cell were
met in the trials before it: what docs/improved.md's account of the late mistakes was read from.

May import what :mod:`hil.experiments` may.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
from collections import defaultdict
from typing import Any

TUNING_SEEDS = range(0, 100)
"""The only seeds a tuning run may use (1000-1019 are for reporting)."""


def parse_seeds(text: str) -> list[int]:
    """``0-9``, ``3,5,7`` or a mix; every seed must be a tuning seed."""
    seeds: list[int] = []
    for part in text.split(","):
        lo, _, hi = part.strip().partition("-")
        seeds.extend(range(int(lo), int(hi) + 1) if hi else [int(lo)])
    outside = [s for s in seeds if s not in TUNING_SEEDS]
    if outside or not seeds:
        raise ValueError(f"tuning takes seeds 0-99 only (held-out seeds are for reporting): got {outside or text!r}")
    return seeds


def parse_settings(items: list[str]) -> dict[str, Any]:
    """``name=value`` pairs (values as JSON: numbers, true/false), checked by ImprovedConfig."""
    from controller.stepping.improved import ImprovedConfig

    settings: dict[str, Any] = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep:
            raise ValueError(f"--set {item!r}: give name=value")
        try:
            settings[name.strip()] = json.loads(value)
        except json.JSONDecodeError:
            raise ValueError(f"--set {item!r}: the value must be a number, true or false") from None
    ImprovedConfig(**settings)  # unknown names (TypeError) and out-of-range values (ValueError)
    return settings


def parse_controller(items: list[str]) -> dict[str, dict[str, Any]]:
    """``section.name=value`` pairs (values as JSON) for the controller's configuration, checked
    by building it (:func:`controller_config`)."""
    changes: dict[str, dict[str, Any]] = defaultdict(dict)
    for item in items:
        path, sep, value = item.partition("=")
        section, dot, name = path.strip().partition(".")
        if not (sep and dot and section and name):
            raise ValueError(f"--controller {item!r}: give section.name=value (e.g. encoder.cell_width_m=0.02)")
        try:
            changes[section][name] = json.loads(value)
        except json.JSONDecodeError:
            raise ValueError(f"--controller {item!r}: the value must be a number, true or false") from None
    controller_config(dict(changes))
    return dict(changes)


CONDITIONS = ("rail_speed_m_s", "believed_rail_speed_m_s", "range_noise_m", "range_dropout_prob",
              "start_min_m", "start_max_m", "obstacle_depth_m")
"""The run's conditions ``--condition`` may change (the rest of LearnConfig is the tuning's own)."""


def parse_conditions(items: list[str]) -> dict[str, float]:
    """``name=value`` pairs for :data:`CONDITIONS`, checked by building a LearnConfig."""
    from hil.experiments.learn import LearnConfig

    conditions: dict[str, float] = {}
    for item in items:
        name, sep, value = item.partition("=")
        name = name.strip()
        if not sep or name not in CONDITIONS:
            raise ValueError(f"--condition {item!r}: give name=value, name one of {', '.join(CONDITIONS)}")
        try:
            conditions[name] = float(value)
        except ValueError:
            raise ValueError(f"--condition {item!r}: the value must be a number") from None
    LearnConfig(**conditions)  # out-of-range values (ValueError)
    return conditions


def controller_config(changes: dict[str, dict[str, Any]]):
    """The default controller configuration with ``changes`` ({section: {name: value}}); an unknown
    section or name, or a value its section refuses, is a ValueError naming it."""
    from dataclasses import fields, is_dataclass, replace

    from controller.config import ControllerConfig

    config = ControllerConfig()
    for section, values in changes.items():
        part = getattr(config, section, None)
        if not is_dataclass(part):
            raise ValueError(f"--controller: no controller section {section!r}")
        known = {f.name for f in fields(part)}
        unknown = sorted(set(values) - known)
        if unknown:
            raise ValueError(f"--controller: {section} has no setting {unknown[0]!r}")
        config = replace(config, **{section: replace(part, **values)})
    return config


def run_seed(seed: int, trials: int, settings: dict[str, Any], heights: tuple[float, ...],
             failures_after: int | None = None, controller: dict[str, dict[str, Any]] | None = None,
             conditions: dict[str, float] | None = None) -> dict[str, Any]:
    """One tuning run: the ``improved`` method with ``settings`` in a controller with
    ``controller``'s changes, under ``conditions`` (LearnConfig fields); with ``failures_after``,
    the failed trials from that index on as lines (see the module docstring)."""
    from hil.analysis.stats import trials_to_criterion
    from hil.experiments.learn import LearningRun, learn_config, one_or_mixed
    from hil.experiments.methods import build_improved

    config = learn_config("improved", seed=seed, trials=trials, obstacle_height_m=one_or_mixed(heights),
                          controller=controller_config(controller or {}), **(conditions or {}))
    premotor = build_improved(config.controller, **settings)
    run = LearningRun(config, premotor=premotor)
    failures: list[str] = []
    held: list[Any] = [None]  # the weights the current trial began with

    def keep_weights(i: int) -> None:
        held[0] = premotor.weights.copy()

    met: list[tuple[tuple[int, ...], bool]] = []  # each trial's path (its gated cells) and success

    def read_failure(i: int, trial: dict[str, Any]) -> None:
        if failures_after is not None and i >= failures_after and not trial["success"]:
            failures.append(describe_failure(seed, trial, held[0], met))
        met.append((path_of(trial), bool(trial["success"])))

    try:
        records = run.run(before_trial=keep_weights, after_trial=read_failure)
    finally:
        run.close()
    success = [t["success"] for t in records]
    return {"seed": seed, "trials_to_criterion": trials_to_criterion(success),
            "success": sum(success) / len(success), "mistakes_after_50": success[50:].count(False),
            "mistakes_after_100": success[100:].count(False),
            "failed": [i for i, ok in enumerate(success) if not ok],
            "per_50": [sum(success[k:k + 50]) for k in range(0, len(success), 50)], "n_cells": premotor.n_cells,
            "late_by_height": [(t["obstacle_height_m"], t["success"]) for t in records[-50:]],
            "contact_misses": sum(t["contact_misses"] for t in records), "failures": failures,
            "blended_steps": premotor.blended_steps,
            "conditions": {name: getattr(config, name) for name in CONDITIONS}}


def path_of(trial: dict[str, Any]) -> tuple[int, ...]:
    """A trial's path: its last three gated cells (those that held one), in order."""
    return tuple(c for c in trial["gated_cells"] if c is not None)[-3:]


def describe_failure(seed: int, trial: dict[str, Any], weights: Any,
                     met: list[tuple[tuple[int, ...], bool]] | None = None) -> str:
    """One line for a failed trial: its obstacle's height, its last four gates (cell, gated range
    [m], the weight the cell held as the trial began [s]), last three footfalls [m] and first
    reflex; with ``met`` (the earlier trials' paths and successes), how often its path
    (:func:`path_of`) and its last gated cell were met before, and how many of those trials
    succeeded."""
    def num(x: float | None) -> str:
        return "-" if x is None else f"{x:.3f}"

    gates = []
    for cell, row, range_m in list(zip(trial["gated_cells"], trial["gated_contexts"], trial["gated_range_m"]))[-4:]:
        held = None if cell is None or row is None else float(weights[row, cell])
        gates.append(f"{'-' if cell is None else cell}@{num(range_m)}:{num(held)}")
    first = trial["reflexes"][0] if trial["reflexes"] else None
    reflex = "none" if first is None else (f"{first['kind']} {first['cause']} phase {first['phase']:.2f} "
                                           f"{'swing' if first['swing'] else 'stance'}")
    line = (f"seed {seed} trial {trial['index']} ({trial['obstacle_height_m']:g} m): gates (cell@range:weight) "
            f"{' '.join(gates)}; footfalls "
            f"{' '.join(num(x) for x in trial['footfalls_m'][-3:])}; reflex {reflex}")
    if met is None:
        return line
    path = path_of(trial)
    same = [ok for p, ok in met if p == path]
    last = [ok for p, ok in met if p and path and p[-1] == path[-1]]
    return (f"{line}; path met before {len(same)} ({sum(same)} ok), "
            f"last cell {len(last)} ({sum(last)} ok)")


def _one(args: tuple[int, int, dict[str, Any], tuple[float, ...], int | None, dict[str, dict[str, Any]],
                    dict[str, float]]) -> dict[str, Any]:
    return run_seed(*args)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m hil.experiments.tuning", description=__doc__.split("\n")[0])
    p.add_argument("--seeds", default="0-9", help="tuning seeds (0-99 only), e.g. 20-39")
    p.add_argument("--trials", type=int, default=150)
    p.add_argument("--set", action="append", default=[], metavar="NAME=VALUE", help="an ImprovedConfig setting")
    p.add_argument("--heights", default="0.08", help="obstacle heights [m], comma list (several: mixed per trial)")
    p.add_argument("--controller", action="append", default=[], metavar="SECTION.NAME=VALUE",
                   help="a setting of the controller the learner runs in, e.g. encoder.cell_width_m=0.02")
    p.add_argument("--condition", action="append", default=[], metavar="NAME=VALUE",
                   help="a condition of the run, e.g. rail_speed_m_s=0.45 (one of: " + ", ".join(CONDITIONS) + ")")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--failures-after", type=int, default=None, metavar="N",
                   help="also print each failed trial from trial N on (its last gates, footfalls, reflex)")
    args = p.parse_args(argv)
    from hil.experiments.sweep import parse_heights

    try:
        seeds = parse_seeds(args.seeds)
        settings = parse_settings(args.set)
        controller = parse_controller(args.controller)
        conditions = parse_conditions(args.condition)
        heights = parse_heights(args.heights)
        from hil.experiments.methods import build_improved

        build_improved(controller_config(controller), **settings)  # settings the gait cannot follow
    except (ValueError, TypeError) as exc:
        print(f"tuning: error: {exc}", file=sys.stderr)
        return 2
    from multiprocessing import Pool

    with Pool(args.workers) as pool:
        results = pool.map(_one, [(s, args.trials, settings, heights, args.failures_after, controller, conditions)
                                          for s in seeds])
    late: dict[float, list[bool]] = defaultdict(list)
    for r in results:
        print(r["seed"], r["trials_to_criterion"], f"{r['success']:.3f}", r["mistakes_after_50"],
              r["mistakes_after_100"], r["failed"][:15], f"misses {r['contact_misses']}", f"per 50 {r['per_50']}",
              f"blended {r['blended_steps']}")
        for line in r["failures"]:
            print("  " + line)
        for h, ok in r["late_by_height"]:
            late[h].append(ok)
    ttc = [r["trials_to_criterion"] if r["trials_to_criterion"] is not None else math.inf for r in results]
    never = sum(t == math.inf for t in ttc)
    median = statistics.median_low(ttc) if never else statistics.median(ttc)  # a seed that never did sorts last
    n = len(results)
    changed = (f" controller {controller}" if controller else "") + (f" conditions {conditions}" if conditions else "")
    print(f"SUMMARY {settings}{changed} trials to criterion median "
          f"{'never' if median == math.inf else median}{f' ({never} never)' if never else ''}, mean success "
          f"{statistics.mean(r['success'] for r in results):.3f}, no mistake after 100 on "
          f"{sum(r['mistakes_after_100'] == 0 for r in results)}/{n}, after 50 on "
          f"{sum(r['mistakes_after_50'] == 0 for r in results)}/{n}, contact misses "
          f"{sum(r['contact_misses'] for r in results)}, blended steps {sum(r['blended_steps'] for r in results)}")
    if len(heights) > 1:
        for h in sorted(late):
            print(f"  height {h:g} m: last 50 trials {sum(late[h])}/{len(late[h])}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
