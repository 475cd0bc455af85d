"""Who moved a weight: every reflex that changed one weight of the improved learner in a learning
run, with the gate it was judged by, and every failed trial beside them.

A late mistake of the improved learner is often a weight learnt long before, by a reflex judged
at another cell: the credit spreads over neighbouring cells, across heights, and along earlier
gates' traces (:mod:`controller.stepping.improved`). This tool runs ``learn --method improved``
with the same seed and conditions (so the same records) and prints, in order::

    python -m hil.experiments.credit --seed 59 --trials 115 --row 1 --cell 6

- ``trial T KIND judged at cell C row R (tuck U): w[ROW,CELL] BEFORE -> AFTER s``, for each reflex
  that moved the watched weight (``KIND`` as learnt, after the too-close rule and the flip; cell
  ``-``: the judged gate held none);
- ``trial T failed: footfalls ...; gates ...; reflexes ...``, for each failed trial.

The seed is only run here, nothing is tuned: the commands in docs use tuning seeds (0-99).

May import what :mod:`hil.experiments` may.
"""

from __future__ import annotations

import argparse
import sys
from typing import Any


def lesson_line(trial: int, lesson, row: int, cell: int) -> str | None:
    """The line of a lesson that moved weight ``[row, cell]``; None if it did not."""
    before, after = float(lesson.before_s[row, cell]), float(lesson.after_s[row, cell])
    if before == after:
        return None
    judged = "-" if lesson.cell is None else str(lesson.cell)
    where = "-" if lesson.row is None else str(lesson.row)
    return (f"trial {trial} {lesson.kind} judged at cell {judged} row {where} (tuck {lesson.tuck:.2f}): "
            f"w[{row},{cell}] {before:+.3f} -> {after:+.3f} s")


def failure_line(record: dict[str, Any]) -> str:
    gates = " ".join("-" if c is None else str(c) for c in record["gated_cells"][-3:])
    footfalls = " ".join(f"{x:+.3f}" for x in record["footfalls_m"][-3:])
    reflexes = ", ".join(f"{r['kind']} {r['cause']}" for r in record["reflexes"]) or "none"
    return f"trial {record['index']} failed: footfalls {footfalls}; gates {gates}; reflexes {reflexes}"


def check_weight(config, row: int, cell: int) -> None:
    """ValueError unless ``[row, cell]`` is a weight of the improved learner of ``config``."""
    rows, cells = config.controller.height.n_contexts, config.controller.encoder.n_cells
    if not (0 <= row < rows and 0 <= cell < cells):
        raise ValueError(f"--row must be in [0, {rows - 1}] and --cell in [0, {cells - 1}], got {row}, {cell}")


def watch(config, row: int, cell: int) -> list[str]:
    """Run the learning run ``config`` (a :class:`hil.experiments.learn.LearnConfig` of the
    improved learner) and return the lines, in order."""
    from hil.experiments.learn import LearningRun

    check_weight(config, row, cell)
    run = LearningRun(config)
    premotor = run.premotor
    lines: list[str] = []
    trial = [-1]

    def on_lesson(lesson) -> None:
        line = lesson_line(trial[0], lesson, row, cell)
        if line is not None:
            lines.append(line)

    premotor.on_lesson = on_lesson
    try:
        run.bring_up()
        for i in range(config.trials):
            trial[0] = i
            record = run.trial(i)
            run.trials.append(record)
            if not record["success"]:
                lines.append(failure_line(record))
    finally:
        run.close()
    return lines


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m hil.experiments.credit", description=__doc__.split("\n")[0])
    p.add_argument("--seed", type=int, required=True, help="the learning run's seed")
    p.add_argument("--trials", type=int, default=150, help="trials to run (default 150)")
    p.add_argument("--row", type=int, required=True, help="the weight's height context (row), from 0")
    p.add_argument("--cell", type=int, required=True, help="the weight's range cell, from 0")
    p.add_argument("--heights", default="0.08", help="obstacle heights [m], comma list (several: mixed per trial)")
    args = p.parse_args(argv)
    try:
        from hil.experiments.sweep import parse_heights

        heights = parse_heights(args.heights)
        if not 1 <= args.trials <= 10000:
            raise ValueError(f"--trials must be in [1, 10000], got {args.trials}")
        from hil.experiments.learn import learn_config, one_or_mixed

        config = learn_config("improved", seed=args.seed, trials=args.trials, obstacle_height_m=one_or_mixed(heights))
        check_weight(config, args.row, args.cell)
    except ValueError as exc:
        print(f"credit: error: {exc}", file=sys.stderr)
        return 2
    lines = watch(config, args.row, args.cell)
    print("\n".join(lines) if lines else f"w[{args.row},{args.cell}] never moved, and no trial failed")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
