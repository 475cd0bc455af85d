"""``elegant-stepping hil``: learning trials with the controller and the leg as two processes on a
real SocketCAN bus, at wall-clock rate.

The session: a bus recorder (python-can's BLF or candump writer, in this process), the
``firmware-sim`` process (plant, drivers, sensor board; the scenario side channel), then the
``controller`` process (the daemon, configured by ``DIR/controller.toml``, writing its records
to ``DIR/controller.jsonl`` and its weights to ``DIR/weights.npz``). Once the controller walks,
each trial is requested from the firmware-sim process over the side channel (the controller
learns of the obstacle only through its range sensor); the firmware-sim process measures the
ground truth on the plant and sends it back. At the end the controller is stopped (SIGTERM: it
puts the axes in IDLE itself), then the firmware-sim process (``quit``), then the recorder.

``DIR/metrics.json`` has the same stamp, ``config``, ``trials`` and ``summary`` as ``learn``; the
trials' controller-side fields (reflexes, gated ranges and cells, burst changes, burst lengths)
come from the controller's own records, matched to each trial by the monotonic clock both
processes share. ``timing``: the controller's ticks and late ticks (its own count: period above
``late_factor`` periods), its period jitter (|period - nominal|), and the command-to-feedback
latency: on the bus recording, from each Set_Input_Pos to the next Get_Encoder_Estimates from
the same axis (kernel receive timestamps of the recorder's socket); ``floor``: the platform's
floor measured beside the session (:class:`hil.bench.floor.FloorProbe`: a do-nothing process
ticking with the controller's pacing code, at the controller's priority), and ``against_floor``:
the controller's jitter and longest period beside it (:func:`against_floor`). ``hil``: where it
ran, frames each way, phases, watchdog trips, process exit codes.

This is the wall-clock session (``--clock wall``, the default): timing is what it measures, and
a loaded host can stall it into a safe stop. ``--clock sim`` is :mod:`hil.session.simsession`.

With fault options (:class:`hil.faults.session.FaultPlan`: rate faults, kill -9 of the controller,
silence of a node) the firmware-sim process is on a second channel behind the man-in-the-middle
node (:mod:`hil.faults.mitm`), and ``metrics.json`` gets a ``fault`` section (:mod:`hil.faults.session`).
Without them the session is as described above.

Where the kernel has no vcan, the whole session runs inside User-Mode Linux (:mod:`hil.uml.runner`).
"""

from __future__ import annotations

import dataclasses
import os
import shutil
import signal
import subprocess
import sys
import time
import uuid
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from controller.atomic import write_json_atomic
from controller.errors import stamp
from controller.daemon.run import phases_seen, read_records
from hil.analysis.busload import bus_load_from_log
from hil.analysis.metrics import METRICS_FORMAT
from hil.profile import Profile, current as current_profile
from hil.session.outcome import HilError
from hil.analysis.buslog import metadata_path
from hil.session.recorder import BusRecorder
from hil.session.scenario import ScenarioClient

if TYPE_CHECKING:
    from controller.config import ControllerConfig
    from hil.faults.session import FaultPlan, FaultSession
    from hil.experiments.learn import LearnConfig

# -- the session --------------------------------------------------------------------------------
def _cpu_s() -> float:
    t = os.times()
    return t.user + t.system


def stop_session(controller: subprocess.Popen | None, client: "ScenarioClient | None", firmware: subprocess.Popen,
                 rc_controller: int | None = None, bye: dict[str, Any] | None = None
                 ) -> tuple[int | None, int, dict[str, Any]]:
    """Stop a session in order: the controller first (SIGTERM: its axes go IDLE), then the
    firmware-sim process through the side channel (its goodbye carries the plant's figures), by
    signal if it lingers. Returns (controller exit code, firmware exit code, goodbye)."""
    bye = {} if bye is None else bye
    if controller is not None:
        rc_controller = _stop(controller, 30.0)
    if client is not None:
        try:
            bye = client.request({"op": "quit"}, 30.0, expect="bye")
        except (HilError, OSError, ValueError):
            pass
        client.close()
    try:
        firmware.wait(30.0)
    except subprocess.TimeoutExpired:
        pass
    return rc_controller, _stop(firmware, 10.0), bye


def _stop(proc: subprocess.Popen, timeout_s: float) -> int:
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(10)
    return proc.returncode


def assemble_trials(truths: list[dict[str, Any]], records: dict[str, list[dict[str, Any]]]) -> list[dict[str, Any]]:
    """The ``learn`` trial dicts: ground truth from the firmware-sim process, the rest from the
    controller's records, by time."""
    steps = records.get("step", [])
    reflexes = records.get("reflex", [])
    trials = []
    for g in truths:
        t0, t1, crossing = g["t0_mono"], g["end_mono"], g["crossing_mono"]
        mine = [s for s in steps if t0 <= s["onset_s"] < t1]
        decided = [s for s in mine if s["swing_start_s"] is not None and s["swing_start_s"] < crossing]
        trials.append({
            "index": g["index"],
            "success": g["success"],
            "start_distance_m": g["start_distance_m"],
            "obstacle_height_m": g["obstacle_height_m"],
            "reflexes": [{"kind": r["reflex"], "t_s": r["t_s"] - t0, "cause": r["cause"], "swing": r["swing"],
                          "phase": r["phase"]} for r in reflexes if t0 <= r["t_s"] < t1],
            "footfalls_m": g["footfalls_m"],
            "burst_s": [s["burst_s"] for s in mine if s["burst_s"] is not None],
            "gated_range_m": [s["gated_range_m"] for s in decided],
            "gated_cells": [s["cell"] for s in decided],
            "gated_contexts": [s["context"] for s in decided],
            "modulation_s": [s["modulation_s"] for s in decided],
            "gated_decisions": sum(1 for s in decided if s["modulation_s"] != 0.0),
            "lift_steps": sum(1 for s in mine if s["amplitude"] > 1.0),
            "sim_s": g["sim_s"],
        })
    return trials


def start_recorder(out: Path, work: Path, channel: str, log_format: str, audit_commands: bool
                   ) -> tuple[BusRecorder, Path]:
    """Start recording ``channel`` to ``work/bus.blf`` (or ``bus.log``), an older session's logs
    and their metadata in ``out`` removed first; returns (the recorder, the log's path)."""
    log_path = work / ("bus.blf" if log_format == "blf" else "bus.log")
    for stale in ("bus.blf", "bus.log"):
        (out / stale).unlink(missing_ok=True)
        metadata_path(out / stale).unlink(missing_ok=True)
    recorder = BusRecorder(channel, log_path, audit_commands=audit_commands)
    recorder.start()
    return recorder, log_path


def copy_out(work: Path, out: Path) -> None:
    """Move a session's files from its work folder (the profile's, when it is not ``out``) to ``out``."""
    if work != out:
        for f in work.iterdir():
            shutil.copy2(f, out / f.name)
        shutil.rmtree(work, ignore_errors=True)


def controller_facts(final: dict[str, Any], trials: int, rc_controller: int | None, rc_firmware: int | None,
                     error: str | None) -> dict[str, Any]:
    """The ``hil`` section's facts from the controller's final record, the same in both clocks'
    sessions: frames each way, its last phase and fault, reflexes, the weights' L1 norm, the exit
    codes, trials completed and the session's error."""
    weights = final.get("weights")
    return {
        "frames_controller_tx": final.get("frames_tx"),
        "frames_controller_rx": final.get("frames_rx"),
        "frames_controller_dropped": final.get("frames_dropped"),
        "controller_final_phase": final.get("phase"),
        "fault_cause": final.get("fault_cause"),
        "trials_completed": trials,
        "reflexes": final.get("reflexes"),
        "weights_l1": None if weights is None else float(np.abs(np.asarray(weights)).sum()),
        "exit_codes": {"controller": rc_controller, "firmware_sim": rc_firmware},
        "error": error,
    }


def session_controller_config(config: LearnConfig, profile: Profile | None = None) -> ControllerConfig:
    """The controller configuration of a session on this platform (``profile``, default
    :func:`hil.profile.current`): the learning run's, as :meth:`hil.profile.Profile.controller_config`
    adapts it (a longer node-silence timeout inside User-Mode Linux), arming by itself once every
    node is heard (``auto_arm = true`` in the controller.toml the session writes: a session on
    vcan has no operator)."""
    ctl = (profile or current_profile()).controller_config(config.lockstep().controller)
    return dataclasses.replace(ctl, auto_arm=True)


def session_envs(profile: Profile | None = None) -> tuple[dict[str, str], dict[str, str]]:
    """Environments of the controller and of the firmware-sim process; the firmware gets the
    coarse-clock preload where the profile says so (:attr:`hil.profile.Profile.coarse_time_preload`)."""
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    fw_env = dict(env)
    coarse = os.environ.get("ELEGANT_STEPPING_UML_COARSE_TIME")
    if coarse and os.path.exists(coarse) and (profile or current_profile()).coarse_time_preload:
        fw_env["LD_PRELOAD"] = coarse
    return env, fw_env


def run_session(*, trials: int, seed: int, out: str | Path, channel: str = "vcan0", obstacle_height_m: float = 0.08,
                range_noise_m: float = 0.02, learning: bool = True, log_format: str = "blf",
                timeout_s: float | None = None, quiet: bool = False, where: str = "native",
                faults: FaultPlan | None = None) -> dict[str, Any]:
    """One session (see the module docstring). ``faults``: the controller stays on ``channel``,
    the firmware-sim process goes to ``faults.leg_channel``, with the mitm node between them (a
    kill alone: no node, the leg on ``channel``), and the plan's event (:mod:`hil.faults.session`);
    ``metrics.json`` then has a ``fault`` section."""
    from controller.settings.file import write_config
    from controller.settings.daemon import session_config
    from hil.experiments.learn import LearnConfig, summarize

    started_unix = time.time()
    wall0 = time.monotonic()
    out = Path(out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    work = current_profile().work_folder(out, "es-hil-")  # copied out at the end if elsewhere
    config = LearnConfig(trials=trials, seed=seed, obstacle_height_m=obstacle_height_m, range_noise_m=range_noise_m,
                         learning=learning)
    ctl_config = session_controller_config(config)
    write_config(work / "controller.toml", session_config(ctl_config, channel, work / "control.sock",
                                                        current_profile().driver_watchdog_s),
                 header="the controller's configuration in this hil session (written by hil.session.run)")
    (out / "controller.json").unlink(missing_ok=True)  # an older session's (replay would prefer the TOML anyway)
    records_path = work / "controller.jsonl"
    records_path.unlink(missing_ok=True)
    for stale in ("weights.npz", "weights.npz.prev"):  # the daemon resumes from these: a session starts fresh
        (work / stale).unlink(missing_ok=True)
    budget = timeout_s if timeout_s is not None else 180.0 + 40.0 * trials
    deadline = wall0 + budget

    def say(text: str) -> None:
        if not quiet:
            print(f"hil: {text}", file=sys.stderr, flush=True)

    recorder, log_path = start_recorder(out, work, channel, log_format, audit_commands=faults is not None)
    py = [sys.executable, "-m", "hil.cli"]
    bus_args = ["--interface", "socketcan", "--channel", channel]
    addr = f"@elegant-stepping-{os.getpid()}-{uuid.uuid4().hex[:8]}"
    env, fw_env = session_envs()
    fs: FaultSession | None = None
    if faults is not None:
        from hil.faults.session import FaultSession

        (work / "mitm.json").unlink(missing_ok=True)
        fs = FaultSession(faults, channel, work, ctl_config, env, say)
        try:
            fs.start()
        except BaseException:
            fs.stop()
            recorder.stop()
            raise
    fw_bus_args = bus_args if fs is None else ["--interface", "socketcan", "--channel", fs.leg_channel]
    fw_log = open(work / "firmware.log", "w")
    ctl_log = open(work / "controller.log", "w")
    firmware = subprocess.Popen(
        [*py, "firmware-sim", *fw_bus_args, "--seed", str(seed), "--scenario", addr,
         "--range-noise-m", str(config.range_noise_m), "--range-dropout-prob", str(config.range_dropout_prob)],
        stdout=fw_log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, env=fw_env)
    controller: subprocess.Popen | None = None
    client: ScenarioClient | None = None
    truths: list[dict[str, Any]] = []
    status_running: dict[str, Any] = {}
    bye: dict[str, Any] = {}
    error: str | None = None
    rc_controller = rc_firmware = None
    t_walk = None
    floor_probe = None

    def alive() -> bool:
        return (firmware.poll() is None and (controller is None or controller.poll() is None)
                and (fs is None or fs.alive()))

    try:
        client = ScenarioClient(addr, max(10.0, deadline - time.monotonic()), alive)
        say(f"firmware-sim up after {time.monotonic() - wall0:.1f} s")
        # Both processes run at normal priority: a real-time controller inside User-Mode Linux
        # starves the plant there.
        controller = subprocess.Popen(
            [*py, "controller", *bus_args, "--config", str(work / "controller.toml"), "--records", str(records_path),
             "--weights", str(work / "weights.npz"), "--ticks", str(work / "controller.ticks")],
            stdout=ctl_log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, env=env)
        # The platform's floor beside the session: a process at the controller's priority ticking
        # with the controller's pacing code and doing nothing (hil.bench.floor, as bench --hil),
        # at 100 Hz so that it costs the session little (its wake-up latency is the figure).
        from hil.bench.floor import FloorProbe

        floor_probe = FloorProbe().start()
        try:  # the recorder and this bookkeeping yield to the two real-time processes
            os.nice(10)
        except OSError:
            pass
        while True:
            phases = phases_seen(records_path)
            if "walk" in phases:
                break
            if "fault" in phases or not alive():
                raise HilError(f"the controller did not come up (phases {phases}); see {out}/controller.log")
            if time.monotonic() > deadline:
                raise HilError(f"the controller did not reach walk in time (phases {phases})")
            time.sleep(0.2)
        t_walk = time.monotonic() - wall0
        say(f"controller walking after {t_walk:.1f} s (phases {' -> '.join(phases)})")

        time.sleep(1.0)  # one second of walking before the first obstacle, as in learn
        rng = np.random.default_rng(config.seed)
        successes = 0
        for i in range(config.trials):
            start = float(rng.uniform(config.start_min_m, config.start_max_m))
            client.send({"op": "trial", "index": i, "start_m": start, "height_m": config.obstacle_height_m,
                         "depth_m": config.obstacle_depth_m, "past_m": config.past_obstacle_m})
            if fs is not None and fs.at_trial(i, client, controller, firmware, wall0 + t_walk):
                break  # the event ended the session
            reply = client.receive(max(5.0, min(90.0, deadline - time.monotonic())), alive)
            if reply.get("op") != "trial_done":
                raise HilError(f"unexpected reply to trial {i}: {reply}")
            truths.append(reply)
            successes += reply["success"]
            phases = phases_seen(records_path)
            say(f"trial {i + 1}/{config.trials}: {'cleared' if reply['success'] else 'hit'} "
                f"({successes}/{i + 1}), {reply['sim_s']:.1f} s")
            if phases and phases[-1] == "fault":
                raise HilError(f"the controller stopped safely during trial {i}; see {out / records_path.name}")
        status_running = fs.status_before if fs is not None and fs.status_before else \
            client.request({"op": "status"}, expect="status")
    except (HilError, OSError, ValueError) as exc:
        error = str(exc)
        say(f"error: {error}")
    finally:
        floor = floor_probe.stop() if floor_probe is not None else None
        rc_controller, rc_firmware, bye = stop_session(controller, client, firmware, rc_controller, bye)
        if fs is not None:
            fs.stop()
        recorder.stop()
        fw_log.close()
        ctl_log.close()

    copy_out(work, out)
    records_path = out / records_path.name
    records = read_records(records_path) if records_path.exists() else {}
    final = (records.get("final") or [{}])[-1]
    phases = [r["phase"] for r in records.get("phase", [])]
    trial_dicts = assemble_trials(truths, records)
    wall_s = time.monotonic() - wall0
    bus = {**recorder.summary(), "file": str(out / log_path.name)}
    try:  # the load as a CAN engineer measures it: from the recording, bring-up left out
        bus["load"] = bus_load_from_log(out / log_path.name, skip_s=t_walk or 0.0)
    except (OSError, ValueError) as exc:
        bus["load"] = {"error": str(exc)}
    pacing = final.get("pacing", {})
    watchdog_trips = bye.get("watchdog_trips")
    axes_running = {n: a["state"] for n, a in status_running.get("axes", {}).items()}
    metrics = {  # a learn run's metrics (the same stamp, config, trials, summary) plus timing, hil, fault
        **stamp(METRICS_FORMAT, 1),
        "config": dataclasses.asdict(config),
        "trials": trial_dicts,
        "summary": summarize(trial_dicts, wall_s, bye.get("t_s", 0.0)) if trial_dicts else {"trials": 0},
        "timing": {
            "ticks": final.get("ticks"),
            "late_ticks": final.get("late_ticks"),
            "skipped_ticks": pacing.get("skipped"),
            "period_jitter_us": pacing.get("period_jitter_us"),
            "max_period_us": final.get("max_period_us"),
            "command_to_feedback_us": {k: bus["command_to_feedback_us"][k] for k in ("median", "p99")},
            "firmware": bye.get("pacing"),
            "cpu_s": {"controller": final.get("cpu_s"), "firmware_sim": bye.get("cpu_s"),
                      "recorder_and_harness": _cpu_s()},
            "clock": "wall",
            "floor": floor,
            "against_floor": against_floor(pacing, final.get("max_period_us"), floor),
        },
        "hil": {
            "where": where,
            "channel": channel,
            "started_unix": started_unix,
            "walk_after_s": t_walk,
            "bus": bus,
            "firmware_host": bye.get("host"),
            "phases": phases,
            "axes_while_running": axes_running,
            "axes_at_end": {n: a["state"] for n, a in bye.get("axes", {}).items()},
            "watchdog_trips": watchdog_trips,
            **controller_facts(final, len(trial_dicts), rc_controller, rc_firmware, error),
        },
    }
    if fs is not None:
        metrics["hil"]["leg_channel"] = fs.leg_channel
        metrics["fault"] = fs.section(where=where, bye=bye, final=final, rc_controller=rc_controller,
                                      recorder=recorder, out=out)
    write_json_atomic(out / "metrics.json", metrics, indent=1)
    return metrics


def against_floor(pacing: dict[str, Any], max_period_us: float | None, floor: dict[str, Any] | None
                  ) -> dict[str, Any]:
    """The controller's timing beside the platform's floor measured in the same session (a
    do-nothing process at the controller's rate, :mod:`hil.bench.floor`), each as
    :func:`hil.bench.socketcan.side_by_side` gives it (``hil``, ``floor``, ``ratio``, ``excess``):
    how much of the controller's lateness is the platform's and how much its own."""
    from hil.bench.floor import side_by_side

    floor = floor or {}
    fj, hj = floor.get("period_jitter_us") or {}, pacing.get("period_jitter_us") or {}
    fmax = floor.get("max_period_s")
    return {
        "period_jitter_median_us": side_by_side(hj.get("median"), fj.get("median")),
        "period_jitter_p99_us": side_by_side(hj.get("p99"), fj.get("p99")),
        "max_period_us": side_by_side(max_period_us, None if fmax is None else fmax * 1e6),
        "error": floor.get("error", "no floor measured (the session ended before walking)") if not fj else None,
    }
