"""``hil``: learning trials with the controller and the simulated leg as two processes on a real
SocketCAN bus (inside User-Mode Linux where the kernel has no CAN), with optional fault injection.

Every option is checked before anything starts (User-Mode Linux boots in tens of seconds): a bad
number is a usage error (exit 2), an output folder that cannot be written an input error (3), no
vcan and no User-Mode Linux a missing dependency (6)."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

from controller.cli.common import non_negative, positive

if TYPE_CHECKING:
    from hil.faults.session import FaultPlan


def add_arguments(p: argparse.ArgumentParser) -> None:
    from hil.faults.session import add_hil_fault_args

    p.add_argument("--trials", type=positive(int), default=10, help="number of approaches (default 10)")
    p.add_argument("--seed", type=non_negative(int), default=0, help="seed of start distances and sensor noise (default 0)")
    p.add_argument("--out", required=True, help="output folder: metrics.json, bus.blf/bus.log, weights.npz, logs")
    p.add_argument("--channel", default="vcan0", help="SocketCAN channel (default vcan0)")
    p.add_argument("--obstacle-height-m", type=positive(float), default=0.08, help="obstacle height [m] (0.08)")
    p.add_argument("--range-noise-m", type=non_negative(float), default=0.02, help="range sensor noise, 1 sigma [m] (0.02)")
    p.add_argument("--no-learning", action="store_true", help="freeze the weights at zero (the baseline)")
    p.add_argument("--log-format", choices=("blf", "log"), default="blf",
                   help="bus recording: BLF (bus.blf) or candump (bus.log); default blf")
    p.add_argument("--where", choices=("auto", "native", "uml"), default="auto",
                   help="native vcan, User-Mode Linux, or auto: native if vcan can be had, else UML")
    p.add_argument("--timeout", type=positive(float), default=None, help="give up after this many seconds")
    p.add_argument("--quiet", action="store_true", help="less output")
    p.add_argument("--clock", choices=("wall", "sim"), default="wall",
                   help="wall: both processes at real time, timing measured against this machine's floor (the "
                        "default); sim: the plant's simulated time, one controller tick per sync frame: the same "
                        "records as learn for a seed, however loaded the machine")
    p.add_argument("--grace-s", type=positive(float), default=None,
                   help="--clock sim: wall-clock seconds the plant waits for the controller's end of period before "
                        "it declares the controller gone and steps on alone (default 10)")
    add_hil_fault_args(p)


def run(args: argparse.Namespace) -> int:
    return main_hil(args)


def _inner_argv(args, out: Path) -> list[str]:
    argv = [sys.executable, "-m", "hil.cli", "hil", "--trials", str(args.trials), "--seed", str(args.seed),
            "--out", str(out), "--channel", args.channel, "--obstacle-height-m", str(args.obstacle_height_m),
            "--range-noise-m", str(args.range_noise_m), "--log-format", args.log_format, "--where", "native"]
    if args.no_learning:
        argv.append("--no-learning")
    if getattr(args, "clock", "wall") == "sim":
        argv += ["--clock", "sim"]
        if args.grace_s is not None:
            argv += ["--grace-s", str(args.grace_s)]
    if args.quiet:
        argv.append("--quiet")
    if args.timeout is not None:
        argv += ["--timeout", str(args.timeout)]
    plan = _fault_plan(args)
    return argv + ([] if plan is None else plan.argv())


def _fault_plan(args) -> "FaultPlan | None":
    """The session's fault plan from the ``hil`` options (None without any; also None for an
    argparse namespace from before the fault options existed)."""
    if not hasattr(args, "faults_to_leg"):
        return None
    from hil.faults.session import FaultPlan

    return FaultPlan.from_args(args)


def main_hil(args) -> int:
    """``elegant-stepping hil``: the options are checked first (the trial count, the output folder,
    the fault plan), then where the session can run (no vcan and no User-Mode Linux: exit 6), and
    only then is anything started, User-Mode Linux included."""
    from controller.atomic import write_json_atomic
    from controller.cli.common import check_output_folder
    from controller.errors import MissingDependency, UsageError
    from hil.profile import current as current_profile
    from hil.session.outcome import session_ok
    from hil.session.run import run_session
    from hil.uml.runner import VcanUnavailable, instruction, native_vcan, run_in_uml, where

    if args.trials < 1:
        raise UsageError(f"--trials must be at least 1, got {args.trials}")
    check_output_folder(args.out, "--out")
    try:
        plan = _fault_plan(args)
    except ValueError as exc:  # the fault options contradict each other
        raise UsageError(str(exc)) from None
    if plan is not None and plan.through_mitm and plan.leg_channel == args.channel:
        raise UsageError(f"the leg's channel must differ from the controller's --channel {args.channel}")
    sim = getattr(args, "clock", "wall") == "sim"
    if sim and plan is not None and plan.kind == "kill":
        raise UsageError("--kill-controller-at-trial measures the wall clock (every axis IDLE after a kill -9): "
                         "use it with --clock wall")
    if not sim and getattr(args, "grace_s", None) is not None:
        raise UsageError("--grace-s is the plant's wait in simulated time: it needs --clock sim")
    try:
        place = where(args.where, args.channel)
        if plan is not None and plan.through_mitm and place == "native" and not native_vcan(plan.leg_channel):
            if args.where != "auto" or current_profile().uml:
                raise VcanUnavailable(f"the fault options need a second channel {plan.leg_channel!r}: "
                                      f"{instruction(plan.leg_channel, uml_considered=False)}")
            place = where("uml", args.channel)
    except VcanUnavailable as exc:
        raise MissingDependency(str(exc)) from None
    out = Path(args.out).resolve()
    if place == "uml" and not current_profile().uml:
        out.mkdir(parents=True, exist_ok=True)
        budget = args.timeout if args.timeout is not None else 180.0 + 40.0 * args.trials
        t0 = time.time()
        if not args.quiet:
            print("hil: no vcan on this kernel; running the session inside User-Mode Linux", file=sys.stderr)
        result = run_in_uml(_inner_argv(args, out), timeout_s=budget + 60.0)
        metrics_path = out / "metrics.json"
        if metrics_path.exists():
            m = json.loads(metrics_path.read_text())
            if m["hil"].get("started_unix", 0) >= t0:
                m["hil"]["where"] = "uml"
                m["hil"]["uml"] = {"boot_to_session_s": m["hil"]["started_unix"] - t0, "wall_s": time.time() - t0,
                                   "exit_code": result.returncode}
                write_json_atomic(metrics_path, m, indent=1)
        return result.returncode
    if sim:
        from hil.session.simsession import run_sim_session, sim_problems

        m = run_sim_session(trials=args.trials, seed=args.seed, out=out, channel=args.channel,
                            obstacle_height_m=args.obstacle_height_m, range_noise_m=args.range_noise_m,
                            learning=not args.no_learning, log_format=args.log_format, timeout_s=args.timeout,
                            quiet=args.quiet, where=current_profile().name, faults=plan, grace_s=args.grace_s)
        problems = sim_problems(m, args.trials)
        s, t, h = m["summary"], m["timing"], m["hil"]
        print(f"hil ({h['where']}, {args.channel}, simulated time): {h['trials_completed']}/{args.trials} trials, "
              f"success {s.get('success_rate', 0) or 0:.0%}; {t['sim_s']:.1f} s simulated in {t['wall_s']:.1f} s "
              f"({t['sim_per_wall'] or 0:.2f}x real time); frames {h['bus']['controller_to_leg']} to the leg, "
              f"{h['bus']['leg_to_controller']} from it; wrote {out}/metrics.json", file=sys.stderr)
        if "fault" in m:
            f = m["fault"]
            print(f"hil faults ({f['kind']}, simulated time): "
                  + (f"every axis IDLE {'never' if f['safe_state_sim_ms'] is None else round(f['safe_state_sim_ms'])} "
                     f"ms (simulated) after the silence (bound {f['bound_ms']:.0f} ms)"
                     if f["kind"] == "silence" else f"mitm {f['mitm'].get('to_leg')} / {f['mitm'].get('from_leg')}"),
                  file=sys.stderr)
        for p in problems:
            print(f"elegant-stepping hil: {p}", file=sys.stderr)
        return 1 if problems else 0
    m = run_session(trials=args.trials, seed=args.seed, out=out, channel=args.channel,
                    obstacle_height_m=args.obstacle_height_m, range_noise_m=args.range_noise_m,
                    learning=not args.no_learning, log_format=args.log_format, timeout_s=args.timeout,
                    quiet=args.quiet, where=current_profile().name, faults=plan)
    if plan is not None:
        from hil.faults.session import fault_problems, fault_summary

        problems = fault_problems(m, args.trials)
        print(fault_summary(m), file=sys.stderr)
    else:
        problems = session_ok(m, args.trials)
    s, t = m["summary"], m["timing"]
    jit = t["period_jitter_us"] or {}
    af = t.get("against_floor") or {}
    p99 = af.get("period_jitter_p99_us") or {}
    c2f = t["command_to_feedback_us"]
    print(f"hil ({m['hil']['where']}, {args.channel}): {m['hil']['trials_completed']}/{args.trials} trials, "
          f"success {s.get('success_rate', 0) or 0:.0%}; frames {m['hil']['bus']['controller_to_leg']} to the leg, "
          f"{m['hil']['bus']['leg_to_controller']} from it; ticks {t['ticks']}, late {t['late_ticks']}, "
          f"skipped {t['skipped_ticks']}; jitter median/p99/max {jit.get('median')}/{jit.get('p99')}/"
          f"{None if jit.get('max') is None else round(jit['max'])} us (the platform's floor in this session: "
          f"p99 {None if p99.get('floor') is None else round(p99['floor'])} us); command->feedback median/p99 "
          f"{None if c2f['median'] is None else round(c2f['median'])}/"
          f"{None if c2f['p99'] is None else round(c2f['p99'])} us; watchdog trips {m['hil']['watchdog_trips']}; "
          f"wrote {out}/metrics.json and {Path(m['hil']['bus']['file']).name}", file=sys.stderr)
    for p in problems:
        print(f"elegant-stepping hil: {p}", file=sys.stderr)
    return 1 if problems else 0

