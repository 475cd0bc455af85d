"""A trial's obstacle contacts, physics step by physics step: what the leg's switches said, what
the ground truth saw, where the foot was, and the contact points PyBullet reported.

Issue 18 asks that every obstacle contact reach the learner as a reflex. A trial's record counts
the contacts no reflex heard (``contact_misses``) but cannot say why; this tool replays the run
to the trial (lockstep is deterministic: the same seed gives the same records, so trial ``N`` is
the trial ``N`` of ``learn`` with the same method, seed and heights) and prints every physics
step from ``--before-s`` before each contact episode to ``--after-s`` after it::

    python -m hil.experiments.touches --seed 10 --trial 11 --heights 0.04,0.08,0.12,0.16,0.20

A row: time from the trial's start [s]; the foot's lowest point, x from the block's near face and
z above the ground [m]; the foot and shin switches (``F``/``S`` closed, ``.`` open); ``T`` while
the ground truth counts a touch (:meth:`firmware_sim.plant.RigPlant.obstacle_contact`); the CPG's
half (``swing``/``stance``) and phase; then each of the leg's contact points as
``link>body d=DIST_mm f=FORCE_N`` (``link``: foot, shank, ...; ``body``: ``block`` or
``ground``). Above the rows, the trial's record: its height, success, contact episodes, reflexes,
last footfalls and gates.

The seed is only replayed here, nothing is tuned: the commands in docs use tuning seeds (0-99).

May import what :mod:`hil.experiments` may.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass, replace
from typing import Any, Sequence


@dataclass(frozen=True)
class Step:
    """One physics step of the replayed trial. ``points``: (link, body, distance [m], normal force [N])."""

    t_s: float
    foot_x_m: float
    foot_z_m: float
    foot_switch: bool
    shin_switch: bool
    touching: bool
    swing: bool
    phase: float
    points: tuple[tuple[str, str, float, float], ...]


def around_contacts(steps: Sequence[Step], contacts: Sequence[Sequence[float]], before_s: float,
                    after_s: float) -> list[list[Step]]:
    """The steps from ``before_s`` before each contact episode ``[start, end]`` to ``after_s``
    after it, one list per episode (times from the trial's start, as the record's ``contacts``)."""
    return [[s for s in steps if start - before_s <= s.t_s <= end + after_s] for start, end in contacts]


def row(step: Step) -> str:
    points = " ".join(f"{link}>{body} d={dist * 1000:.2f}mm f={force:.1f}N" for link, body, dist, force in step.points)
    return (f"{step.t_s:7.3f} {step.foot_x_m:+.4f} {step.foot_z_m:+.4f} "
            f"{'F' if step.foot_switch else '.'}{'S' if step.shin_switch else '.'}{'T' if step.touching else '.'} "
            f"{'swing ' if step.swing else 'stance'} {step.phase:.3f} {points}".rstrip())


def header(record: dict[str, Any]) -> list[str]:
    gates = ", ".join(f"{c if c is not None else '-'}@{r:.3f}" if r is not None else "-"
                      for c, r in zip(record["gated_cells"][-4:], record["gated_range_m"][-4:]))
    reflexes = ", ".join(f"{r['kind']} {r['cause']} at {r['t_s']:.3f} s ({'swing' if r['swing'] else 'stance'} "
                         f"{r['phase']:.2f})" for r in record["reflexes"]) or "none"
    return [
        f"trial {record['index']}: height {record['obstacle_height_m']} m, "
        f"{'success' if record['success'] else 'failed'}, contacts no reflex heard {record['contact_misses']}",
        "contact episodes [s]: " + (", ".join(f"{a:.3f}-{b:.3f}" for a, b in record["contacts"]) or "none"),
        f"reflexes: {reflexes}",
        "last footfalls [m from the near face]: " + " ".join(f"{x:+.3f}" for x in record["footfalls_m"][-3:]),
        f"last gates (cell@range m): {gates}",
    ]


def replay(config, trial: int) -> tuple[dict[str, Any], list[Step]]:
    """Run the learning run ``config`` (a :class:`hil.experiments.learn.LearnConfig`) to trial
    ``trial`` and record that trial step by step."""
    from hil.experiments.learn import LearningRun

    run = LearningRun(config)
    try:
        run.bring_up()
        for i in range(trial):
            run.trials.append(run.trial(i))
        plant, loop = run.ls.plant, run.ls.loop
        steps: list[Step] = []

        def on_step(ls) -> None:
            foot, shin = plant.contacts()
            x, z = plant.foot_position()
            near = run.near_edge_m if run.near_edge_m is not None else 0.0
            out = loop.last_cpg
            steps.append(Step(ls.t_s, x - near, z, foot, shin, plant.obstacle_contact(), bool(out.flexing), out.phase,
                              tuple(plant.leg_contact_points())))

        record = run.trial(trial, on_step=on_step)
        t0 = run.last_times["t0_s"]
        return record, [replace(s, t_s=s.t_s - t0) for s in steps]
    finally:
        run.close()


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m hil.experiments.touches", description=__doc__.split("\n")[0])
    p.add_argument("--seed", type=int, required=True, help="the learning run's seed")
    p.add_argument("--trial", type=int, required=True, help="the trial to show, from 0")
    p.add_argument("--method", default="improved", help="a method of the registry (default improved)")
    p.add_argument("--heights", default="0.08", help="obstacle heights [m], comma list (several: mixed per trial)")
    p.add_argument("--before-s", type=float, default=0.06, help="steps shown before each contact [s] (default 0.06)")
    p.add_argument("--after-s", type=float, default=0.03, help="steps shown after each contact [s] (default 0.03)")
    args = p.parse_args(argv)
    try:
        from hil.experiments.sweep import parse_heights

        heights = parse_heights(args.heights)
        if not 0 <= args.trial <= 10000:
            raise ValueError(f"--trial must be in [0, 10000], got {args.trial}")
        if not (0.0 <= args.before_s <= 10.0 and 0.0 <= args.after_s <= 10.0):
            raise ValueError(f"--before-s and --after-s must be in [0, 10] s, got {args.before_s}, {args.after_s}")
        from hil.experiments.learn import learn_config, one_or_mixed

        config = learn_config(args.method, seed=args.seed, trials=args.trial + 1,
                              obstacle_height_m=one_or_mixed(heights))
    except ValueError as exc:
        print(f"touches: error: {exc}", file=sys.stderr)
        return 2
    record, steps = replay(config, args.trial)
    lines = header(record)
    for k, episode in enumerate(around_contacts(steps, record["contacts"], args.before_s, args.after_s)):
        lines.append(f"-- contact episode {k + 1}: t_s foot_x_m foot_z_m switches/truth half phase points")
        lines.extend(row(s) for s in episode)
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
