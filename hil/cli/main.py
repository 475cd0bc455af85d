"""The ``elegant-stepping`` command line."""

from __future__ import annotations

import argparse
import json
import logging
import math
import sys
from pathlib import Path
from typing import Any, Sequence

log = logging.getLogger("elegant_stepping")


def _positive(kind):
    def parse(text: str):
        value = kind(text)
        if not (math.isfinite(value) and value > 0):
            raise argparse.ArgumentTypeError(f"must be a positive number, got {text!r}")
        return value

    return parse


def _write_json(path: str | None, data: Any) -> None:
    text = json.dumps(data, indent=2, sort_keys=False)
    if path in (None, "-"):
        print(text)
        return
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_suffix(out.suffix + ".tmp")
    tmp.write_text(text + "\n")
    tmp.replace(out)
    log.info("wrote %s", out)


def cmd_walk(args: argparse.Namespace) -> int:
    from hil.experiments.walk import run_walk

    metrics = run_walk(args.seconds, seed=args.seed, burst_s=args.burst_s, progress=not args.quiet)
    _write_json(args.json, metrics)
    stride = metrics["mean_stride_m"]
    print(
        f"walked {metrics['sim_s']:.1f} s in {metrics['wall_s']:.2f} s wall: {metrics['steps']} steps, "
        f"mean stride {stride if stride is None else round(stride, 3)} m, "
        f"clearance {metrics['swing_clearance_min_m']}, phase {metrics['phase']}",
        file=sys.stderr,
    )
    return 0 if metrics["phase"] == "walk" else 1


def cmd_learn(args: argparse.Namespace) -> int:
    from hil.experiments.learn import LearnConfig, run_learning

    config = LearnConfig(
        trials=args.trials,
        seed=args.seed,
        obstacle_height_m=args.obstacle_height_m,
        obstacle_depth_m=args.obstacle_depth_m,
        range_noise_m=args.range_noise_m,
        learning=not args.no_learning,
        trace_trials=(0, -1),
    )
    metrics = run_learning(config, out_dir=args.out, progress=not args.quiet, figures=not args.no_figures)
    s = metrics["summary"]
    late = "n/a" if s["mistakes_101_150"] is None else s["mistakes_101_150"]
    early = "n/a" if s["success_21_40"] is None else f"{s['success_21_40']:.0%}"
    print(
        f"{'learning' if config.learning else 'no learning'}, seed {config.seed}: success {s['success_rate']:.0%} "
        f"over {s['trials']} trials, {early} in trials 21-40, {late} mistakes in 101-150; "
        f"{s['sim_s']:.0f} s simulated in {s['wall_s']:.0f} s ({s['trials_per_minute']:.0f} trials/min); "
        f"wrote {args.out}/metrics.json and weights.npz"
    )
    return 0


def cmd_analyze(args: argparse.Namespace) -> int:
    from hil.analysis.metrics import analyze

    _write_json(args.json, analyze(args.folders))
    return 0


def cmd_bench(args: argparse.Namespace) -> int:
    from hil.bench.run import run_bench

    result = run_bench(seconds=args.seconds, seed=args.seed, learn_trials=args.learn_trials,
                       hil_seconds=args.hil_seconds if args.hil else None)
    _write_json(args.json, result)
    if args.hil:
        h = result["hil"]
        if not h.get("available"):
            print(f"elegant-stepping bench --hil: {h.get('error')} (install: {h.get('install')})", file=sys.stderr)
            return 3
        f = h["figures"]

        def pair(key: str) -> str:
            x = f[key]
            r = "n/a" if x["ratio"] is None else f"{x['ratio']:.1f}x"
            fmt = lambda v: "n/a" if v is None else f"{v:.0f}"  # noqa: E731
            return f"{fmt(x['hil'])} vs {fmt(x['floor'])} ({r})"

        print(f"bench --hil ({h['where']}): jitter p99 {pair('period_jitter_p99_us')} us, late/10k "
              f"{pair('late_ticks_per_10k')}, command->feedback median {pair('command_to_feedback_median_us')} us, "
              f"p99 {pair('command_to_feedback_p99_us')} us (HIL vs floor)", file=sys.stderr)
        if h.get("error"):
            print(f"elegant-stepping bench --hil: {h['error']}", file=sys.stderr)
            return 1
    return 0


def cmd_figures(args: argparse.Namespace) -> int:
    from hil.analysis.figures import paper_figures

    written = paper_figures(args.folders, args.out)
    _write_json(args.json, {name: [str(p) for p in paths] for name, paths in written.items()})
    print(f"wrote {len(written)} figures (PNG and SVG) into {args.out}", file=sys.stderr)
    return 0


def cmd_animate(args: argparse.Namespace) -> int:
    from hil.analysis.animation import AnimationConfig, animate
    from hil.experiments.learn import LearnConfig

    config = LearnConfig(trials=args.trials, seed=args.seed, obstacle_height_m=args.obstacle_height_m)
    anim = AnimationConfig(fps=args.fps, width_px=args.width, height_px=args.height)
    result = animate(config, args.out, anim, progress=not args.quiet)
    if args.json is not None:
        _write_json(args.json, result)
    files = ", ".join(f"{Path(f['path']).name} ({f['frames']} frames, {f['size_px'][0]}x{f['size_px'][1]})"
                      for f in result["files"].values())
    outcome = {k: "cleared" if v else "hit" for k, v in result["success"].items()}
    print(f"trial 1 {outcome['before']}, trial {config.trials} {outcome['after']}; wrote {files}; "
          f"rendering took {result['render_wall_s']:.1f} s of {result['wall_s']:.1f} s", file=sys.stderr)
    return 0


def cmd_sweep(args: argparse.Namespace) -> int:
    from hil.analysis.report import write_report
    from hil.experiments.sweep import SweepConfig, parse_heights, parse_methods, parse_seeds, run_sweep

    if args.report_only:
        report = write_report(args.out)
        print(f"wrote {report['report']} and {args.out}/figures/", file=sys.stderr)
        return 0
    config = SweepConfig(
        out_dir=Path(args.out),
        seeds=parse_seeds(args.seeds),
        obstacle_heights_m=parse_heights(args.obstacle_heights_m),
        methods=parse_methods(args.methods),
        trials=args.trials,
        mixed_heights=args.mixed_heights,
        dask=args.dask,
        **({} if args.workers is None else {"workers": args.workers}),
    )
    stats = run_sweep(config, progress=not args.quiet)
    if stats["rows"]:
        write_report(config.out_dir)
    print(f"sweep: {stats['cells']} cells, {stats['ran']} run, {stats['resumed']} resumed, "
          f"{len(stats['failed'])} failed; wrote {args.out}/summary.json, timing.json"
          f"{', report.md' if stats['rows'] else ''}", file=sys.stderr)
    if stats["failed"]:
        print(f"elegant-stepping sweep: {len(stats['failed'])} cells failed: {', '.join(stats['failed'])} "
              f"(errors in {args.out}/timing.json)", file=sys.stderr)
        return 1
    return 0


def _bus_kw(args: argparse.Namespace) -> dict:
    from controller.settings.daemon import bus_kwargs

    return bus_kwargs(args.interface, args.channel, args.bitrate)


def cmd_firmware_sim(args: argparse.Namespace) -> int:
    from hil.session.firmware import run_firmware

    final = run_firmware(_bus_kw(args), seed=args.seed, gui=args.gui, scenario=args.scenario,
                         range_noise_m=args.range_noise_m, range_dropout_prob=args.range_dropout_prob,
                         duration_s=args.seconds, steps_per_wake=args.steps_per_wake)
    print(json.dumps({k: final[k] for k in ("t_s", "axes", "watchdog_trips", "host", "pacing")}), file=sys.stderr)
    return 0


def cmd_controller(args: argparse.Namespace) -> int:
    from controller.settings.daemon import daemon_settings
    from controller.daemon.run import run_controller

    d = daemon_settings(args.config, args.interface, args.channel, args.bitrate, args.weights, args.save_every_s)
    final = run_controller(d.bus_kw, d.controller, records=args.records, weights=d.weights, ticks=args.ticks,
                           duration_s=args.seconds, save_every_s=d.save_every_s)
    final.pop("weights", None)
    print(json.dumps(final), file=sys.stderr)
    if final["weights_saved"] is False:
        return 1  # the learned weights could not be saved (logged)
    if final["stopped_by"] in ("SIGTERM", "SIGINT"):
        return 0  # a stop asked for, done in order: axes IDLE, weights saved (a fault is in the final record)
    return 0 if final["phase"] != "fault" else 1


def cmd_config_check(args: argparse.Namespace) -> int:
    from controller.settings.daemon import main_config_check

    return main_config_check(args)


def cmd_config_show(args: argparse.Namespace) -> int:
    from controller.settings.daemon import main_config_show

    return main_config_show(args)


def cmd_hil(args: argparse.Namespace) -> int:
    from hil.session.run import main_hil

    return main_hil(args)


def cmd_mitm(args: argparse.Namespace) -> int:
    from hil.faults.model import FaultSpec
    from hil.faults.mitm import run_mitm

    run_mitm(args.controller_channel, args.leg_channel, to_leg=FaultSpec.parse(args.to_leg),
             from_leg=FaultSpec.parse(args.from_leg), seed=args.seed, silence_node=args.silence_node,
             silence_after_s=args.silence_after_s, poll_s=args.poll_s, duration_s=args.seconds,
             json_path=args.json, ready_path=args.ready_file)
    return 0


def cmd_faults(args: argparse.Namespace) -> int:
    from hil.faults.matrix import main_faults

    return main_faults(args)


def cmd_replay(args: argparse.Namespace) -> int:
    from hil.analysis.replay import main_replay

    return main_replay(args)


def cmd_decode(args: argparse.Namespace) -> int:
    from hil.analysis.replay import main_decode

    return main_decode(args)


def cmd_killsave(args: argparse.Namespace) -> int:
    import tempfile

    from hil.faults.killsave import kill_during_saves

    if args.kills < 1:
        raise ValueError(f"--kills must be at least 1, got {args.kills}")
    if args.folder is None:
        with tempfile.TemporaryDirectory(prefix="es-killsave-") as folder:
            result = kill_during_saves(args.kills, folder, args.seed, args.max_delay_s)
    else:
        result = kill_during_saves(args.kills, args.folder, args.seed, args.max_delay_s)
    _write_json(args.json, result)
    print(f"killsave: {result['kills']} kill -9s ({result['kills_mid_save']} inside a save) over "
          f"{result['saves_completed']} completed saves in {result['elapsed_s']:.1f} s: {result['corrupt_loads']} corrupt "
          f"loads, {result['loads_ok_from_file']} from the file, {result['loads_from_prev']} from .prev, "
          f"{result['zeros']} zeros; {result['tmp_files_left']} temporary files left", file=sys.stderr)
    return 0 if result["corrupt_loads"] == 0 and result["prev_corrupt"] == 0 and result["child_errors"] == 0 else 1


def _add_bus_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--interface", default=None, help="python-can interface (default: python-can's config, else socketcan)")
    p.add_argument("--channel", default=None, help="bus channel, e.g. vcan0 (default: python-can's config)")
    p.add_argument("--bitrate", type=int, default=None, help="bit rate [bit/s] (ignored by vcan)")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="elegant-stepping", description=__doc__)
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-vv for debug)")
    sub = parser.add_subparsers(dest="command", required=True)

    walk = sub.add_parser("walk", help="walk on flat ground through the whole stack in lockstep")
    walk.add_argument("--seconds", type=_positive(float), default=20.0, help="simulated seconds (default 20)")
    walk.add_argument("--seed", type=int, default=0, help="seed of the sensor noise (default 0)")
    walk.add_argument("--burst-s", type=_positive(float), default=None, help="CPG burst length [s] (default 0.30)")
    walk.add_argument("--json", default="-", help="where to write the metrics (default: stdout)")
    walk.add_argument("--quiet", action="store_true", help="no progress bar")
    walk.set_defaults(func=cmd_walk)

    learn = sub.add_parser("learn", help="learning trials: approach an obstacle and step over it, again and again")
    learn.add_argument("--trials", type=int, default=150, help="number of approaches (default 150)")
    learn.add_argument("--seed", type=int, default=0, help="seed of start distances and sensor noise (default 0)")
    learn.add_argument("--out", required=True, help="output folder for metrics.json and weights.npz")
    learn.add_argument("--obstacle-height-m", type=_positive(float), default=0.08, help="obstacle height [m] (0.08)")
    learn.add_argument("--obstacle-depth-m", type=_positive(float), default=0.10, help="obstacle depth [m] (0.10)")
    learn.add_argument("--range-noise-m", type=float, default=0.02, help="range sensor noise, 1 sigma [m] (0.02)")
    learn.add_argument("--no-learning", action="store_true", help="freeze the weights at zero (the baseline)")
    learn.add_argument("--no-figures", action="store_true", help="skip DIR/figures/")
    learn.add_argument("--quiet", action="store_true", help="no progress bar")
    learn.set_defaults(func=cmd_learn)

    analyze = sub.add_parser("analyze", help="acceptance figures from one or more learn output folders")
    analyze.add_argument("folders", nargs="+", help="learn output folders (one per seed)")
    analyze.add_argument("--json", default="-", help="where to write the figures (default: stdout)")
    analyze.set_defaults(func=cmd_analyze)

    bench = sub.add_parser("bench", help="performance figures as JSON, ratios measured side by side")
    bench.add_argument("--seconds", type=_positive(float), default=10.0, help="simulated seconds per figure")
    bench.add_argument("--seed", type=int, default=0)
    bench.add_argument("--learn-trials", type=int, default=10, help="learning trials timed (default 10)")
    bench.add_argument("--json", default="-", help="where to write the figures (default: stdout)")
    bench.add_argument("--hil", action="store_true",
                       help="also the HIL figures on a real vcan0 (User-Mode Linux where needed), beside the floor")
    bench.add_argument("--hil-seconds", type=_positive(float), default=10.0,
                       help="seconds of walking (and of each floor run) for --hil (default 10)")
    bench.set_defaults(func=cmd_bench)

    figures = sub.add_parser("figures", help="the paper's figures (PNG and SVG) from learn output folders")
    figures.add_argument("folders", nargs="+", help="learn output folders (seeds, heights, baselines)")
    figures.add_argument("--out", required=True, help="output folder for the figures")
    figures.add_argument("--json", default="-", help="where to list the written files (default: stdout)")
    figures.set_defaults(func=cmd_figures)

    animate = sub.add_parser("animate", help="GIFs of the leg before and after learning (PyBullet renderer)")
    animate.add_argument("--trials", type=int, default=60, help="learning trials; the first and last are filmed (60)")
    animate.add_argument("--seed", type=int, default=0, help="seed of start distances and sensor noise (default 0)")
    animate.add_argument("--out", required=True, help="output folder for before.gif, after.gif, before_after.gif")
    animate.add_argument("--obstacle-height-m", type=_positive(float), default=0.08, help="obstacle height [m] (0.08)")
    animate.add_argument("--fps", type=_positive(float), default=15.0, help="frames per simulated second (15)")
    animate.add_argument("--width", type=int, default=360, help="frame width [px] (360)")
    animate.add_argument("--height", type=int, default=240, help="frame height [px] (240)")
    animate.add_argument("--json", default=None, help="also write the summary as JSON here ('-': stdout)")
    animate.add_argument("--quiet", action="store_true", help="no progress bar")
    animate.set_defaults(func=cmd_animate)
    sweep = sub.add_parser("sweep", help="learning runs over seeds x obstacle heights x methods, with a report")
    sweep.add_argument("--out", required=True, help="sweep folder: cells/, summary.json, timing.json, report.md")
    sweep.add_argument("--seeds", default="0-9", help="seeds: a list 0,1,2 and/or ranges 0-9 (default 0-9)")
    sweep.add_argument("--obstacle-heights-m", default="0.08", help="obstacle heights [m], comma list (0.08)")
    sweep.add_argument("--mixed-heights", action="store_true",
                       help="one scenario in which each trial draws its height from the list")
    sweep.add_argument("--methods", default="learner,none,oracle,rl",
                       help="methods, comma list: learner, none, oracle, rl, context (default learner,none,oracle,rl)")
    sweep.add_argument("--trials", type=int, default=150, help="trials per run (default 150)")
    sweep.add_argument("--workers", type=int, default=None, help="worker processes (default: os.cpu_count())")
    sweep.add_argument("--dask", default=None, metavar="ADDRESS",
                       help="run on the Dask scheduler at ADDRESS, or 'local' for a LocalCluster of --workers")
    sweep.add_argument("--report-only", action="store_true", help="only rewrite report.md and figures/ from DIR")
    sweep.add_argument("--quiet", action="store_true", help="no progress bar")
    sweep.set_defaults(func=cmd_sweep)

    fw = sub.add_parser("firmware-sim", help="the simulated leg (plant, drivers, sensor board) on a CAN bus, real time")
    _add_bus_args(fw)
    fw.add_argument("--seed", type=int, default=0, help="seed of the sensor noise (default 0)")
    fw.add_argument("--gui", action="store_true", help="open PyBullet's window")
    fw.add_argument("--scenario", default=None, metavar="ADDR",
                    help="Unix socket for the scenario side channel ('@name': abstract namespace)")
    fw.add_argument("--range-noise-m", type=float, default=None, help="range sensor noise, 1 sigma [m]")
    fw.add_argument("--range-dropout-prob", type=float, default=None, help="range dropout probability")
    fw.add_argument("--seconds", type=_positive(float), default=None, help="stop after this much time (default: run)")
    fw.add_argument("--steps-per-wake", type=int, default=None,
                    help="physics steps per wake-up (default 1; 2 inside User-Mode Linux)")
    fw.set_defaults(func=cmd_firmware_sim)

    ctl = sub.add_parser("controller", help="the controller daemon at its fixed rate on a CAN bus")
    _add_bus_args(ctl)
    ctl.add_argument("--config", default=None, metavar="FILE",
                     help="the configuration (TOML, see configs/; defaults otherwise): bus, controller, axes, weights")
    ctl.add_argument("--records", default=None, metavar="FILE", help="write the controller's records here (JSON lines)")
    ctl.add_argument("--weights", default=None, metavar="FILE",
                     help="resume from these learned weights (else FILE.prev, else zeros) and save them here "
                          "while walking and at exit (.npz; default: the configuration's [weights] path)")
    ctl.add_argument("--save-every-s", type=_positive(float), default=None,
                     help="save the weights every this many seconds of walking, if they changed "
                          "(default: the configuration's [weights] save_every_s, else 10)")
    ctl.add_argument("--ticks", default=None, metavar="FILE", help="write every tick's clock here (for replay)")
    ctl.add_argument("--seconds", type=_positive(float), default=None, help="stop after this long (default: run)")
    ctl.set_defaults(func=cmd_controller)

    config = sub.add_parser("config", help="the configuration file (TOML): check it, or show the effective one")
    config_sub = config.add_subparsers(dest="config_command", required=True)
    check = config_sub.add_parser("check", help="validate FILE: exit 0 and a summary, or 2 and every problem")
    check.add_argument("file", metavar="FILE", help="a TOML configuration, e.g. configs/odrive-leg.toml")
    check.set_defaults(func=cmd_config_check)
    show = config_sub.add_parser("show", help="print the effective configuration (FILE's, with every default) as TOML")
    show.add_argument("file", metavar="FILE", nargs="?", default=None, help="a TOML configuration (default: none)")
    show.set_defaults(func=cmd_config_show)

    hil = sub.add_parser("hil", help="learning trials with the controller and the simulated leg as two processes "
                                     "on a real SocketCAN bus (inside User-Mode Linux where the kernel has no CAN)")
    hil.add_argument("--trials", type=int, default=10, help="number of approaches (default 10)")
    hil.add_argument("--seed", type=int, default=0, help="seed of start distances and sensor noise (default 0)")
    hil.add_argument("--out", required=True, help="output folder: metrics.json, bus.blf/bus.log, weights.npz, logs")
    hil.add_argument("--channel", default="vcan0", help="SocketCAN channel (default vcan0)")
    hil.add_argument("--obstacle-height-m", type=_positive(float), default=0.08, help="obstacle height [m] (0.08)")
    hil.add_argument("--range-noise-m", type=float, default=0.02, help="range sensor noise, 1 sigma [m] (0.02)")
    hil.add_argument("--no-learning", action="store_true", help="freeze the weights at zero (the baseline)")
    hil.add_argument("--log-format", choices=("blf", "log"), default="blf",
                     help="bus recording: BLF (bus.blf) or candump (bus.log); default blf")
    hil.add_argument("--where", choices=("auto", "native", "uml"), default="auto",
                     help="native vcan, User-Mode Linux, or auto: native if vcan can be had, else UML")
    hil.add_argument("--timeout", type=_positive(float), default=None, help="give up after this many seconds")
    hil.add_argument("--quiet", action="store_true", help="less output")
    from hil.faults.session import add_hil_fault_args

    add_hil_fault_args(hil)
    hil.set_defaults(func=cmd_hil)

    from hil.dryrun.run import add_dryrun_args, main_dryrun

    dryrun = sub.add_parser("dryrun", help="the deployment dry run: the systemd unit's command line against the "
                                           "simulated leg on vcan0, playing systemd's notify socket; a checklist")
    add_dryrun_args(dryrun)
    dryrun.set_defaults(func=main_dryrun)

    mitm = sub.add_parser("mitm", help="a man-in-the-middle node: forward between two SocketCAN channels, "
                                       "injecting faults; silence a node (SIGUSR1 or --silence-after-s)")
    mitm.add_argument("--controller-channel", default="vcan0", help="the controller's channel (default vcan0)")
    mitm.add_argument("--leg-channel", default="vcan1", help="the leg's channel (default vcan1)")
    mitm.add_argument("--to-leg", default="", metavar="SPEC", help="faults on frames to the leg, e.g. drop=0.05")
    mitm.add_argument("--from-leg", default="", metavar="SPEC", help="faults on frames from the leg")
    mitm.add_argument("--seed", type=int, default=0, help="seed of the faults (default 0)")
    mitm.add_argument("--silence-node", type=int, default=None, metavar="ID",
                      help="the node to silence (its frames to the controller dropped) on SIGUSR1 or at --silence-after-s")
    mitm.add_argument("--silence-after-s", type=float, default=None, metavar="T", help="silence the node T s after start")
    mitm.add_argument("--poll-s", type=_positive(float), default=None,
                      help="pause after each batch of frames [s] (default 0.0005; 0.002 inside User-Mode Linux)")
    mitm.add_argument("--seconds", type=_positive(float), default=None, help="stop after this long (default: run)")
    mitm.add_argument("--json", default=None, metavar="FILE", help="write the counts here at exit")
    mitm.add_argument("--ready-file", default=None, metavar="FILE", help="create this file once both channels are open")
    mitm.set_defaults(func=cmd_mitm)

    faults = sub.add_parser("faults", help="the fault-injection matrix: inject every failure mode, report what happened")
    faults.add_argument("--json", default="-", help="where to write the rows (default: stdout)")
    faults.add_argument("--out", default="out/faults", help="folder for each case's row, trials and weights (out/faults)")
    faults.add_argument("--trials", type=int, default=150, help="learning trials of each rate-fault case (150)")
    faults.add_argument("--seeds", default="0", help="seeds of the whole matrix, e.g. 0 or 0-2 (default 0)")
    faults.add_argument("--loss-seeds", default="", help="also run 5%% frame loss on these seeds, e.g. 0-9")
    faults.add_argument("--only", default="", help="only these faults, comma separated (e.g. drop,kill)")
    faults.add_argument("--kills", type=int, default=1000, help="kill -9s during weight saves (1000; 0: none)")
    faults.add_argument("--hil", action="store_true", help="also the HIL rows (SocketCAN, User-Mode Linux here)")
    faults.add_argument("--hil-trials", type=int, default=10, help="trials of the HIL rate-fault row (10)")
    faults.add_argument("--workers", type=int, default=2, help="processes in parallel (2)")
    faults.add_argument("--quiet", action="store_true", help="no progress bar")
    faults.set_defaults(func=cmd_faults)

    replay = sub.add_parser("replay", help="feed a recorded bus log to the controller offline; print its decisions")
    replay.add_argument("log", help="bus log (.blf, .log, .asc, ...) recorded by hil")
    replay.add_argument("--config", default=None, metavar="FILE",
                        help="configuration (TOML; default: controller.toml beside the log, else an old "
                             "controller.json there, else defaults)")
    replay.add_argument("--records", default=None, metavar="FILE",
                        help="the live run's records to compare with (default: controller.jsonl beside the log)")
    replay.add_argument("--json", default=None, help="also write the replayed decisions as JSON here ('-': stdout)")
    replay.set_defaults(func=cmd_replay)

    decode = sub.add_parser("decode", help="print a bus log as named signals (cantools with our DBC)")
    decode.add_argument("log", help="bus log (.blf, .log, .asc, ...)")
    decode.add_argument("--limit", type=int, default=None, help="print at most this many frames")
    decode.add_argument("--load", action="store_true",
                        help="print the bus load instead (JSON: frames/s x bits/frame, per message)")
    decode.add_argument("--bitrate", type=int, default=1_000_000, help="bus bitrate for --load [bit/s] (1000000)")
    decode.add_argument("--skip-s", type=float, default=0.0, help="leave out the first seconds for --load (0)")
    decode.set_defaults(func=cmd_decode)

    killsave = sub.add_parser("killsave", help="fault injection: kill -9 a process while it saves weights, "
                                               "then load; count corrupt loads")
    killsave.add_argument("--kills", type=int, default=1000, help="number of kill -9s (default 1000)")
    killsave.add_argument("--seed", type=int, default=0, help="seed of the kill delays (default 0)")
    killsave.add_argument("--max-delay-s", type=_positive(float), default=0.02,
                          help="kill after a uniform random delay below this [s] (default 0.02)")
    killsave.add_argument("--folder", default=None, help="where to save (default: a temporary folder, removed)")
    killsave.add_argument("--json", default="-", help="where to write the counts (default: stdout)")
    killsave.set_defaults(func=cmd_killsave)

    from controller.cli.bringup import add_bringup_args, main_bringup

    bringup = sub.add_parser("bringup", help="bring-up checklist on real hardware: nodes, versions, errors, bus "
                                             "voltage, positions, small slow moves; PASS/FAIL per item")
    _add_bus_args(bringup)
    add_bringup_args(bringup)
    bringup.set_defaults(func=main_bringup)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    level = logging.WARNING - 10 * min(args.verbose, 2)
    logging.basicConfig(level=level, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    try:
        return args.func(args)
    except (ValueError, FileNotFoundError) as exc:
        print(f"elegant-stepping {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
