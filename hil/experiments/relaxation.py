"""The paper's claim R5: "After passing the obstacle, the burst length gradually relaxes to its
former value."

What the model does by default: at each step onset the gate replaces the short-term memory with
the encoder's active cell, and a gate with no target in view clears it. The obstacle leaves the
range sensor's view as the leg crosses it, so the first gate after the crossing clears the memory
and the burst drops at once to its base value (``docs/figures/burst_over_approach.png``). Between
two gates the burst already relaxes, as ``base + w * exp(-t / stm_tau_s)``; what the paper
describes after the obstacle is that same decay, continued.

The design that does so (:attr:`controller.stepping.learner.LearnerConfig.relax_out_of_view`): a
gate with nothing in view leaves the held cell in memory, decaying on, instead of clearing it,
until its activity is below :data:`controller.stepping.learner.RELAX_FLOOR` (then the gate clears
it as before). Nothing else changes: the next target in view replaces the memory as any gate does,
no trace is activated by a gate that sees nothing, and the learning rule is the same. It is off by
default, so the paper learner's records stay those of the reproduction.

This module runs the paper learner both ways on the same seeds (the last trial traced) and
measures:

- the burst after the crossing: its excess over the base [s] at 0, 0.5, 1, 2 and 3 s after the
  foot first passes over the near edge, in the last trial of each run (mean over the seeds);
- whether the option costs learning: success over all trials and in the last 50, per seed.

Run as ``python -m hil.experiments.relaxation --seeds 1000-1004 --out DIR`` (2 worker
processes): ``DIR/relaxation.json``, ``DIR/r5_relaxation.png`` and ``.svg``, and a markdown table
on stdout.

May import what :mod:`hil.experiments` may.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from controller.errors import InputError

log = logging.getLogger(__name__)

PAPER = ("As the robotic leg moves toward the obstacle, the burst length [...] is gradually altered. "
         "After passing the obstacle, the burst length gradually relaxes to its former value.")
AFTER_S = (0.0, 0.5, 1.0, 2.0, 3.0)
"""Times after the foot first passes over the near edge at which the burst's excess is read [s]."""


def run_one(seed: int, trials: int, relax: bool) -> dict[str, Any]:
    """One paper-learner run (the last trial traced): its success and the last trial's trace."""
    from controller.config import ControllerConfig
    from hil.experiments.learn import LearnConfig, run_learning

    controller = ControllerConfig()
    controller = replace(controller, learner=replace(controller.learner, relax_out_of_view=relax))
    config = LearnConfig(trials=trials, seed=seed, method="paper", trace_trials=(-1,), controller=controller)
    metrics = run_learning(config)
    ok = [t["success"] for t in metrics["trials"]]
    trace = metrics["trials"][-1]["trace"]
    return {"seed": seed, "relax": relax, "success": float(np.mean(ok)), "success_last50": float(np.mean(ok[-50:])),
            "last_success": ok[-1], "base_burst_s": controller.cpg.burst_s, "trace": trace}


def excess_after_crossing(trace: dict[str, Sequence[float]], base_s: float,
                          after_s: Sequence[float] = AFTER_S) -> list[float | None]:
    """The burst's excess over ``base_s`` [s] at each of ``after_s`` after the foot first passes
    over the near edge (None: the trace ends before that, or the foot never passed)."""
    t = np.asarray(trace["t_s"], dtype=float)
    x = np.asarray(trace["foot_x_m"], dtype=float)
    burst = np.asarray(trace["burst_s"], dtype=float)
    over = np.flatnonzero(x >= 0.0)
    if not len(over):
        return [None for _ in after_s]
    t0 = t[over[0]]
    out: list[float | None] = []
    for a in after_s:
        i = int(np.searchsorted(t, t0 + a))
        out.append(None if i >= len(t) else float(burst[i] - base_s))
    return out


def figure(runs: list[dict[str, Any]], out: Path, seed: int, name: str = "r5_relaxation") -> list[Path]:
    """The last trial's burst against time from the crossing, both ways, for one seed; the
    paper's words beside it."""
    from hil.analysis.figures import _save, subplots

    fig, ax = subplots(figsize=(7.0, 3.8))
    for run, style, label in ((r, "-" if r["relax"] else "--", "relaxing (relax_out_of_view)" if r["relax"]
                               else "default (the gate clears the memory)") for r in runs if r["seed"] == seed):
        tr = run["trace"]
        t = np.asarray(tr["t_s"], dtype=float)
        x = np.asarray(tr["foot_x_m"], dtype=float)
        over = np.flatnonzero(x >= 0.0)
        t0 = t[over[0]] if len(over) else 0.0
        ax.plot(t - t0, tr["burst_s"], style, label=label)
        base = run["base_burst_s"]
    ax.axvline(0.0, color="C3", ls=":", label="foot over the near edge")
    ax.axhline(base, color="0.6", lw=0.8, label="base burst")
    ax.set(xlabel="time from the crossing [s]", ylabel="burst length [s]",
           title=f"R5: the burst after the obstacle (paper learner, seed {seed}, last trial)")
    ax.legend(loc="upper left", fontsize="small")
    fig.text(0.01, 0.01, "Paper: \"" + PAPER + "\"", fontsize=6.5, wrap=True)
    fig.subplots_adjust(bottom=0.25)
    return _save(fig, out, name)


def summarize(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """Per variant: the mean excess after the crossing and the success figures, per seed."""
    out: dict[str, Any] = {"after_s": list(AFTER_S), "paper": PAPER, "variants": {}}
    for relax in (False, True):
        rows = [r for r in runs if r["relax"] is relax]
        excess = [excess_after_crossing(r["trace"], r["base_burst_s"]) for r in rows]
        mean_excess = []
        for j in range(len(AFTER_S)):
            vals = [e[j] for e in excess if e[j] is not None]
            mean_excess.append(float(np.mean(vals)) if vals else None)
        out["variants"]["relax" if relax else "default"] = {
            "seeds": [r["seed"] for r in rows],
            "success": [r["success"] for r in rows],
            "success_last50": [r["success_last50"] for r in rows],
            "mean_success": float(np.mean([r["success"] for r in rows])),
            "mean_success_last50": float(np.mean([r["success_last50"] for r in rows])),
            "excess_after_crossing_s": excess,
            "mean_excess_after_crossing_s": mean_excess,
        }
    return out


def markdown(summary: dict[str, Any]) -> str:
    head = " | ".join(f"{a:g} s" for a in summary["after_s"])
    lines = [f"| variant | burst above base after the crossing: {head} | mean success | last 50 |",
             "|---|" + "---|" * len(summary["after_s"]) + "---|---|"]
    for name, v in summary["variants"].items():
        cells = " | ".join("-" if e is None else f"{e * 1000:.0f} ms" for e in v["mean_excess_after_crossing_s"])
        lines.append(f"| {name} | {cells} | {v['mean_success']:.3f} | {v['mean_success_last50']:.3f} |")
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    from hil.experiments.sweep import parse_seeds

    p = argparse.ArgumentParser(prog="python -m hil.experiments.relaxation", description=__doc__.split("\n\n")[0])
    p.add_argument("--seeds", default="1000-1004", help="seeds, e.g. 1000-1004 (default)")
    p.add_argument("--trials", type=int, default=150, help="trials per run (default 150)")
    p.add_argument("--out", type=Path, required=True, help="where relaxation.json and the figure go")
    p.add_argument("--workers", type=int, default=2, help="worker processes (default 2)")
    args = p.parse_args(argv)
    try:
        seeds = parse_seeds(args.seeds)
        if not 1 <= args.trials <= 100000:
            raise InputError(f"--trials must be in [1, 100000], got {args.trials}")
        if args.workers < 1:
            raise InputError(f"--workers must be at least 1, got {args.workers}")
    except (InputError, ValueError) as exc:
        print(f"relaxation: {exc}", file=sys.stderr)
        return 2
    jobs = [(s, args.trials, relax) for s in seeds for relax in (False, True)]
    with ProcessPoolExecutor(max_workers=args.workers) as pool:
        runs = list(pool.map(run_one, *zip(*jobs)))
    summary = summarize(runs)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "relaxation.json").write_text(json.dumps(summary, indent=1) + "\n")
    figure(runs, args.out, seeds[0])
    print(markdown(summary))
    return 0


if __name__ == "__main__":
    sys.exit(main())
