"""The take-off window: from where, before the block, the leg's last swing clears it.

A learner places the last footfall before the obstacle only as precisely as its gates see the
distance: with the paper's non-overlapping range cells, every distance within one cell (the
encoder's ``cell_width_m``, 0.04 m) gets the same stride, so the last footfall spreads over a
cell's width even when every weight is right. Whether a height can be cleared nearly always is
then a matter of the take-off window's width against that spread. This module measures the
window, with the oracle (:mod:`hil.experiments.oracle`), which knows the true distance and
height: it plans the last footfall at each of ``plans_m`` in turn (its ``takeoff_m`` and
``tucked_takeoff_m`` both set there) for ``trials`` trials each, and records where the last
footfall actually came down and whether the trial succeeded::

    python -m hil.experiments.window --heights 0.08,0.12,0.16,0.20 --seed 5

prints, per height, the successful last footfalls' span (the window is at least that wide) and
the nearest failed ones on either side (it is at most that wide), with the first reflex of each
failure: ``foot_on_top`` on the far side (the swing could not carry the foot over), ``shin`` on
the near side (the leg struck the near face rising). ``--lift-margin-m`` raises the oracle's lift
(and so tucks the swing, from a lift of 3.0), as a shared context's learned lift does.
``--controller SECTION.NAME=VALUE`` (repeatable, as ``hil.experiments.tuning`` takes it) measures
the window with a controller setting changed, e.g. the tucked path's shape
(``gait.tuck_descend_phase``, docs/leg_limits.md).

The seed is the run's (start distances, sensor noise); the oracle never learns, so no seed is
"tuned on" here, but the commands in docs use tuning seeds all the same.

May import what :mod:`hil.experiments` may.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass, replace


@dataclass(frozen=True)
class Landing:
    """One trial: the planned last footfall [m, from the near face], where it came down [m] (None:
    no footfall before the face), success, and the first reflex's cause (None: no reflex)."""

    plan_m: float
    last_footfall_m: float | None
    success: bool
    cause: str | None


@dataclass(frozen=True)
class Window:
    """The window at one height, from :func:`measure`'s landings: ``inner_m`` the span of the
    successful last footfalls (None: none succeeded), ``outer_m`` the nearest failed footfalls
    outside that span on the far and the near side (None where there was none); widths [m]."""

    height_m: float
    landings: tuple[Landing, ...]

    @property
    def inner_m(self) -> tuple[float, float] | None:
        ok = [x.last_footfall_m for x in self.landings if x.success and x.last_footfall_m is not None]
        return (min(ok), max(ok)) if ok else None

    @property
    def outer_m(self) -> tuple[float | None, float | None]:
        inner = self.inner_m
        if inner is None:
            return None, None
        failed = [x.last_footfall_m for x in self.landings if not x.success and x.last_footfall_m is not None]
        far = [f for f in failed if f < inner[0]]
        near = [f for f in failed if f > inner[1]]
        return (max(far) if far else None), (min(near) if near else None)

    @property
    def failures_inside(self) -> int:
        """Failed trials whose last footfall lies within the successful span (a window with holes)."""
        inner = self.inner_m
        if inner is None:
            return 0
        return sum(1 for x in self.landings if not x.success and x.last_footfall_m is not None
                   and inner[0] <= x.last_footfall_m <= inner[1])

    def width_m(self) -> tuple[float | None, float | None]:
        """(at least, at most) [m]: the successful span, and the gap between the nearest failures
        (None where a side had no failure)."""
        inner = self.inner_m
        if inner is None:
            return None, None
        far, near = self.outer_m
        return inner[1] - inner[0], (near - far if far is not None and near is not None else None)


def measure(height_m: float, plans_m: tuple[float, ...], trials: int = 8, seed: int = 5,
            lift_margin_m: float | None = None, depth_m: float = 0.10,
            controller: dict | None = None) -> Window:
    """The oracle's landings at ``height_m`` for each planned last footfall in ``plans_m`` [m,
    negative: before the near face], ``trials`` trials each (a fresh run per plan, seeded
    ``seed``); ``lift_margin_m``: the oracle's lift margin (None: its default 0.07 m);
    ``controller``: changes to the controller's settings ({section: {name: value}}, as
    :func:`hil.experiments.tuning.controller_config` takes them; None: the defaults)."""
    from hil.experiments.learn import LearnConfig, LearningRun
    from hil.experiments.tuning import controller_config

    config = LearnConfig(seed=seed, trials=trials, method="oracle", obstacle_height_m=height_m,
                         obstacle_depth_m=depth_m, controller=controller_config(controller or {}))
    landings: list[Landing] = []
    for plan in plans_m:
        run = LearningRun(config)
        oracle = run.premotor
        settings = {"takeoff_m": plan, "tucked_takeoff_m": plan}
        if lift_margin_m is not None:
            settings["lift_margin_m"] = lift_margin_m
        oracle.config = replace(oracle.config, **settings)  # read at every plan: this run's take-off
        try:
            run.bring_up()
            for i in range(trials):
                record = run.trial(i)
                before = [x for x in record["footfalls_m"] if x < 0.0]
                first = record["reflexes"][0] if record["reflexes"] else None
                landings.append(Landing(plan, before[-1] if before else None, bool(record["success"]),
                                        None if first is None else first["cause"]))
        finally:
            run.close()
    return Window(height_m, tuple(landings))


def parse_plans(text: str) -> tuple[float, ...]:
    """``FROM:TO:STEP`` (inclusive, e.g. ``-0.06:-0.28:0.03``) or a comma list [m]."""
    if ":" in text:
        lo, hi, step = (float(x) for x in text.split(":"))
        if step <= 0.0:
            raise ValueError(f"--plans {text!r}: the step must be positive")
        n = int(abs(hi - lo) / step + 1e-9) + 1
        sign = 1.0 if hi >= lo else -1.0
        return tuple(round(lo + sign * k * step, 6) for k in range(n))
    return tuple(float(x) for x in text.split(","))


def report(windows: list[Window], cell_width_m: float) -> str:
    """A markdown table: per height, the window's width (at least, at most), where it lies, the
    failures either side and the share of a cell's width it covers."""
    def cm(x: float | None) -> str:
        return "-" if x is None else f"{100 * x:.1f}"

    lines = ["| height [m] | trials | successes | window [cm from the face] | width at least / at most [cm] "
             "| nearest failures (far, near) [cm] and their reflex | window / cell width |",
             "|---|---|---|---|---|---|---|"]
    for w in windows:
        inner = w.inner_m
        least, most = w.width_m()
        far, near = w.outer_m
        cause = {x.last_footfall_m: x.cause for x in w.landings if not x.success}
        span = "none" if inner is None else f"{cm(inner[0])} .. {cm(inner[1])}"
        sides = f"{cm(far)} ({cause.get(far, '-')}), {cm(near)} ({cause.get(near, '-')})"
        ratio = "-" if least is None else f"{least / cell_width_m:.2f} .. " + (
            "-" if most is None else f"{most / cell_width_m:.2f}")
        holes = f" ({w.failures_inside} failed inside)" if w.failures_inside else ""
        lines.append(f"| {w.height_m:g} | {len(w.landings)} | {sum(x.success for x in w.landings)}{holes} | {span} "
                     f"| {cm(least)} / {cm(most)} | {sides} | {ratio} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m hil.experiments.window", description=__doc__.split("\n")[0])
    p.add_argument("--heights", default="0.08,0.12,0.16,0.20", help="obstacle heights [m], comma list")
    p.add_argument("--plans", default="-0.06:-0.28:0.03",
                   help="planned last footfalls [m from the near face]: FROM:TO:STEP or a comma list")
    p.add_argument("--trials", type=int, default=8, help="trials per planned footfall")
    p.add_argument("--seed", type=int, default=5)
    p.add_argument("--lift-margin-m", type=float, default=None, help="the oracle's lift margin [m] (default 0.07)")
    p.add_argument("--controller", action="append", default=[], metavar="SECTION.NAME=VALUE",
                   help="change a controller setting (value as JSON), e.g. gait.tuck_back_m=0.05; repeatable")
    args = p.parse_args(argv)
    try:
        from hil.experiments.tuning import parse_controller

        controller = parse_controller(args.controller)
        heights = [float(h) for h in args.heights.split(",")]
        plans = parse_plans(args.plans)
        if not 1 <= args.trials <= 1000:
            raise ValueError(f"--trials must be in [1, 1000], got {args.trials}")
        from hil.experiments.learn import LearnConfig

        for h in heights:  # the leg's limit and the conditions' ranges, before any run
            LearnConfig(obstacle_height_m=h, method="oracle")
    except ValueError as exc:
        print(f"window: error: {exc}", file=sys.stderr)
        return 2
    from controller.config import ControllerConfig

    windows = [measure(h, plans, args.trials, args.seed, args.lift_margin_m, controller=controller) for h in heights]
    print(report(windows, ControllerConfig().encoder.cell_width_m))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
