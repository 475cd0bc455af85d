"""``elegant-stepping hil --clock sim``: the two processes on SocketCAN, on the plant's simulated time.

The same session as :mod:`hil.session.run` (the bus recorder in this process, the
``firmware-sim`` process, the ``controller`` process, talking only over the CAN channel), but
time is the plant's (``use_sim_time`` in ROS words; CANopen's SYNC in spirit): the plant sends
``ES_Sim_Sync`` after each control period, the controller (``--clock sim``,
:mod:`controller.daemon.simclock`) ticks once per sync with its time and answers
``ES_End_Of_Period``, and the plant steps on when that answer has arrived. A stalled process only
slows the session; it never changes what happens in it, so the same seed gives, trial for trial,
the records of ``elegant-stepping learn --method paper`` (the deployed learner; wall-clock figures
aside), however loaded the host is.

The order: the recorder; ``firmware-sim --clock sim`` (:mod:`hil.session.simplant`), asked on the
side channel for the learning run (trials, seed, height, noise, learning; the trial schedule runs
beside the plant, as ``learn`` runs it); then the controller, configured exactly as ``learn``'s
(no platform allowances: its timeouts are simulated time now). The plant opens simulated time
once the controller answers its first sync, runs the trials and reports each one's plant-side
fields and simulated times; at the end the controller is stopped (SIGTERM: its final records and
weights), then the plant (``quit``), then the recorder. Each trial's controller fields come from
the controller's records by simulated time (:func:`fill_from_records`).

``DIR/metrics.json``: a learn run's stamp, ``config``, ``trials`` and ``summary``, plus ``timing``
(``clock: "sim"``, wall and simulated seconds, their ratio, the wall time the plant waited for
the controller, CPU per process) and ``hil`` (where, the sync protocol's counts on both sides,
frames, exit codes). With a node silence (``--silence-node``, ``--silence-at-trial``) the node's
transmitter stops ``event_after_s`` of simulated time into that trial, on the plant's side
(:meth:`hil.lockstep.synced.SimTimePlant.silence`), and ``fault`` gets the safe state in
simulated milliseconds. Rate faults go through the man-in-the-middle node in its simulated-time
mode (``mitm --clock sim``: faults drawn per frame in order, sync and end-of-period frames passed
untouched). A kill -9 measures the wall clock: it stays in ``--clock wall``.
"""

from __future__ import annotations

import dataclasses
import math
import os
import subprocess
import sys
import time
import uuid
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from controller.atomic import write_json_atomic
from controller.daemon.run import read_records
from controller.errors import stamp
from hil.analysis.metrics import METRICS_FORMAT
from hil.profile import current as current_profile
from hil.session.outcome import HilError
from hil.session.run import controller_facts, copy_out, session_envs, start_recorder, stop_session
from hil.session.scenario import ScenarioClient

if TYPE_CHECKING:
    from hil.faults.session import FaultPlan, FaultSession


CONTROLLER_FIELDS = ("reflexes", "burst_s", "gated_range_m", "gated_cells", "gated_contexts", "modulation_s",
                     "gated_decisions", "lift_steps", "contact_misses")
"""The fields of a trial that come from the controller's records (the rest from the plant)."""


def fill_from_records(trial: dict[str, Any], times: dict[str, float],
                      records: dict[str, list[dict[str, Any]]], bursts: np.ndarray | None = None,
                      refractory_s: float | None = None) -> dict[str, Any]:
    """A trial of ``hil --clock sim``: the plant's half (``trial``, from :class:`hil.experiments.learn.
    LearningRun` run against the controller in another process, its controller fields empty)
    completed from the controller's records, exactly as ``LearningRun.trial`` computes them in
    one process. ``times``: the trial's simulated times (``LearningRun.last_times``: ``t0_s``,
    ``crossing_s``, ``end_s``), on the clock the controller's records use in simulated time.

    The rules, each what the in-process run sees at the trial's end: a step or reflex belongs to the
    trial if it happened in (t0, end] (the tick at t0 is the previous step's); a step's burst length
    was known at the end only if its swing had begun by then (the controller sets both at once);
    the decisions are the steps whose swing began before the crossing. A traced trial's burst
    lengths come from ``bursts`` (the controller's ``--bursts`` file: (tick time, burst length)
    rows): each sample's is the one after the last tick at or before it (within 1 ns: the sample's
    time is rebuilt as t0 + its offset, and ticks are a period apart). ``contact_misses`` is counted
    again from the plant's ``contacts`` and these reflexes (``refractory_s``: the controller's
    reflex setting, default :class:`~controller.stepping.reflexes.ReflexConfig`'s)."""
    from controller.stepping.reflexes import ReflexConfig
    from hil.experiments.learn import contact_misses

    t0, crossing, end = times["t0_s"], times["crossing_s"], times["end_s"]
    steps = [s for s in records.get("step", []) if t0 < s["onset_s"] <= end]
    started = [s for s in steps if s["swing_start_s"] is not None and s["swing_start_s"] <= end]
    decided = [s for s in steps if s["swing_start_s"] is not None and s["swing_start_s"] < crossing]
    out = dict(trial)
    out.update({
        "reflexes": [{"kind": r["reflex"], "t_s": r["t_s"] - t0, "cause": r["cause"], "swing": r["swing"],
                      "phase": r["phase"]} for r in records.get("reflex", []) if t0 < r["t_s"] <= end],
        "burst_s": [s["burst_s"] for s in started if s["burst_s"] is not None],
        "gated_range_m": [s["gated_range_m"] for s in decided],
        "gated_cells": [s["cell"] for s in decided],
        "gated_contexts": [s["context"] for s in decided],
        "modulation_s": [s["modulation_s"] for s in decided],
        "gated_decisions": sum(1 for s in decided if s["modulation_s"] != 0.0),
        "lift_steps": sum(1 for s in steps if s["amplitude"] > 1.0),
    })
    if "contacts" in trial:
        out["contact_misses"] = contact_misses(
            trial["contacts"], [r["t_s"] for r in out["reflexes"]],
            ReflexConfig().refractory_s if refractory_s is None else refractory_s)
    if "trace" in trial:
        trace = dict(trial["trace"])
        if bursts is None or not len(bursts):
            trace["burst_s"] = [math.nan] * len(trace["t_s"])
        else:
            at = np.searchsorted(bursts[:, 0], [t0 + t + 1e-9 for t in trace["t_s"]], side="right") - 1
            trace["burst_s"] = [float(bursts[i, 1]) if i >= 0 else math.nan for i in at]
        out["trace"] = trace
    return out


def read_bursts(path: str | Path) -> np.ndarray:
    """The controller's ``--bursts`` file as (tick time, burst length) rows; an empty array when
    missing (a torn last row, from a kill while writing, is dropped)."""
    try:
        raw = np.fromfile(path, dtype=np.float64)
    except (FileNotFoundError, ValueError):
        return np.empty((0, 2))
    return raw[: len(raw) // 2 * 2].reshape(-1, 2)


def run_sim_session(*, trials: int, seed: int, out: str | Path, channel: str = "vcan0",
                    obstacle_height_m: float = 0.08, range_noise_m: float = 0.02, learning: bool = True,
                    log_format: str = "blf", timeout_s: float | None = None, quiet: bool = False,
                    where: str = "native", faults: "FaultPlan | None" = None,
                    grace_s: float | None = None) -> dict[str, Any]:
    """One session in simulated time (see the module doc); returns the metrics (also in
    ``out/metrics.json``). ``timeout_s``: wall-clock budget of the whole session (default 180 s +
    60 s per trial); ``grace_s``: the plant's wait for an end-of-period [s of wall time] before
    it declares the controller gone (default :data:`hil.lockstep.synced.GRACE_S`)."""
    from controller.settings.daemon import session_config
    from controller.settings.file import write_config
    from hil.experiments.learn import FIGURE_TRACES, LearnConfig, summarize

    started_unix = time.time()
    wall0 = time.monotonic()
    cpu0 = sum(os.times()[:2])
    out = Path(out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    work = current_profile().work_folder(out, "es-hil-")
    config = LearnConfig(trials=trials, seed=seed, obstacle_height_m=obstacle_height_m, range_noise_m=range_noise_m,
                         learning=learning, trace_trials=FIGURE_TRACES)  # learn's, traces included
    ctl_config = dataclasses.replace(config.lockstep().controller, auto_arm=True)  # learn's, exactly
    write_config(work / "controller.toml", session_config(ctl_config, channel, work / "control.sock"),
                 header="the controller's configuration in this hil --clock sim session (written by "
                        "hil.session.simsession)")
    records_path = work / "controller.jsonl"
    for stale in ("controller.jsonl", "weights.npz", "weights.npz.prev", "controller.ticks", "controller.bursts"):
        (work / stale).unlink(missing_ok=True)
    (out / "controller.json").unlink(missing_ok=True)
    deadline = wall0 + (timeout_s if timeout_s is not None else 180.0 + 60.0 * trials)

    def say(text: str) -> None:
        if not quiet:
            print(f"hil: {text}", file=sys.stderr, flush=True)

    rate = faults is not None and faults.kind == "rate"
    recorder, log_path = start_recorder(out, work, channel, log_format, audit_commands=faults is not None)
    py = [sys.executable, "-m", "hil.cli"]
    addr = f"@elegant-stepping-{os.getpid()}-{uuid.uuid4().hex[:8]}"
    env, fw_env = session_envs()
    fw_env.pop("LD_PRELOAD", None)  # the coarse clock is for wall-clock pacing; simulated time needs none
    fs: FaultSession | None = None
    if rate:
        from hil.faults.session import FaultSession

        fs = FaultSession(faults, channel, work, ctl_config, env, say, clock="sim")
        try:
            fs.start()
        except BaseException:
            fs.stop()
            recorder.stop()
            raise
    fw_channel = faults.leg_channel if rate else channel
    fw_log = open(work / "firmware.log", "w")
    ctl_log = open(work / "controller.log", "w")
    firmware = subprocess.Popen(
        [*py, "firmware-sim", "--interface", "socketcan", "--channel", fw_channel, "--clock", "sim",
         "--scenario", addr],
        stdout=fw_log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, env=fw_env)
    controller: subprocess.Popen | None = None
    client: ScenarioClient | None = None
    plant_trials: list[tuple[dict[str, Any], dict[str, float]]] = []
    done: dict[str, Any] = {}
    bye: dict[str, Any] = {}
    error: str | None = None
    rc_controller = rc_firmware = None
    t_walk = None

    def alive() -> bool:
        return (firmware.poll() is None and (controller is None or controller.poll() is None)
                and (fs is None or fs.alive()))

    try:
        client = ScenarioClient(addr, max(10.0, deadline - time.monotonic()), alive)
        request = {"op": "learn", "trials": trials, "seed": seed, "obstacle_height_m": obstacle_height_m,
                   "range_noise_m": range_noise_m, "learning": learning, "trace_trials": list(config.trace_trials),
                   "grace_s": grace_s}
        if faults is not None and faults.kind == "silence":
            request.update(silence_node=faults.silence_node, silence_at_trial=faults.silence_at_trial,
                           event_after_s=faults.event_after_s)
        client.send(request)
        say(f"firmware-sim up after {time.monotonic() - wall0:.1f} s (simulated time)")
        controller = subprocess.Popen(
            [*py, "controller", "--interface", "socketcan", "--channel", channel, "--clock", "sim",
             "--config", str(work / "controller.toml"), "--records", str(records_path),
             "--weights", str(work / "weights.npz"), "--ticks", str(work / "controller.ticks"),
             "--bursts", str(work / "controller.bursts")],
            stdout=ctl_log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, env=env)
        try:  # the recorder and this bookkeeping yield to the two processes
            os.nice(10)
        except OSError:
            pass
        successes = 0
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                raise HilError(f"the session ran out of its {deadline - wall0:.0f} s after "
                               f"{len(plant_trials)} of {trials} trials")
            reply = client.receive(left, alive)
            op = reply.get("op")
            if op == "trial_done":
                plant_trials.append((reply["trial"], reply["times"]))
                if t_walk is None:
                    t_walk = time.monotonic() - wall0
                successes += reply["trial"]["success"]
                n = len(plant_trials)
                say(f"trial {n}/{trials}: {'cleared' if reply['trial']['success'] else 'hit'} ({successes}/{n}), "
                    f"{reply['trial']['sim_s']:.1f} s simulated")
            elif op == "learn_done":
                done = reply
                if reply.get("error"):
                    error = reply["error"]
                    say(f"the run ended early: {error}")
                break
            elif op == "error":
                raise HilError(f"firmware-sim: {reply.get('error')}")
    except (HilError, OSError, ValueError) as exc:
        error = str(exc)
        say(f"error: {error}")
    finally:
        rc_controller, rc_firmware, bye = stop_session(controller, client, firmware)
        if fs is not None:
            fs.stop()
        recorder.stop()
        fw_log.close()
        ctl_log.close()

    copy_out(work, out)
    records_path = out / records_path.name
    records = read_records(records_path) if records_path.exists() else {}
    final = (records.get("final") or [{}])[-1]
    bursts = read_bursts(records_path.with_name("controller.bursts"))
    trial_dicts = [fill_from_records(t, times, records, bursts) for t, times in plant_trials]
    wall_s = time.monotonic() - wall0
    sim_s = done.get("t_s", bye.get("t_s", 0.0)) or 0.0
    bus = {**recorder.summary(), "file": str(out / log_path.name)}
    phases = [r["phase"] for r in records.get("phase", [])]
    figures = done or bye  # the plant's figures at the end of the trials
    metrics: dict[str, Any] = {
        **stamp(METRICS_FORMAT, 1),
        "config": dataclasses.asdict(config),
        "trials": trial_dicts,
        "summary": summarize(trial_dicts, wall_s, sim_s) if trial_dicts else {"trials": 0},
        "timing": {
            "clock": "sim",
            "wall_s": wall_s,
            "sim_s": sim_s,
            "sim_per_wall": sim_s / wall_s if wall_s > 0 else None,
            "plant_waited_for_controller_s": figures.get("wall_waiting_s"),
            "plant_wall_s": figures.get("wall_s"),
            "ticks": final.get("ticks"),
            "cpu_s": {"controller": final.get("cpu_s"), "firmware_sim": figures.get("cpu_s"),
                      "recorder_and_harness": sum(os.times()[:2]) - cpu0},
        },
        "hil": {
            "where": where,
            "clock": "sim",
            "channel": channel,
            "started_unix": started_unix,
            "walk_after_s": t_walk,
            "bus": bus,
            "sync": {"plant": figures.get("sync"), "controller_gone": figures.get("controller_gone")},
            "firmware_host": figures.get("host"),
            "phases": phases,
            "axes_while_running": {n: a["state"] for n, a in (done.get("axes") or {}).items()},
            "axes_at_end": {n: a["state"] for n, a in (bye.get("axes") or {}).items()},
            "watchdog_expired_axes": figures.get("watchdog_expired"),
            **controller_facts(final, len(trial_dicts), rc_controller, rc_firmware, error),
        },
    }
    if faults is not None:
        metrics["hil"]["fault_kind"] = faults.kind
        if fs is not None:
            metrics["hil"]["leg_channel"] = faults.leg_channel
            metrics["fault"] = {"kind": "rate", "clock": "sim", "plan": dataclasses.asdict(faults),
                                "mitm": fs.mitm_summary, "mitm_exit_code": fs.rc_mitm,
                                "controller_exit_code": rc_controller}
        else:
            sil = figures.get("silence") or {}
            bound_ms = (ctl_config.heartbeat_timeout_s + _heartbeat_s()) * 1e3
            ms = sil.get("safe_state_sim_ms")
            metrics["fault"] = {"kind": "silence", "clock": "sim", "plan": dataclasses.asdict(faults),
                                "at_trial": faults.silence_at_trial, "node": faults.silence_node,
                                "silenced_at_sim_s": sil.get("at_s"), "axes_idle_sim_ms": sil.get("axes_idle_sim_ms"),
                                "safe_state_sim_ms": ms, "bound_ms": bound_ms,
                                "within_bound": ms is not None and ms <= bound_ms,
                                "frames_silenced": (figures.get("sync") or {}).get("silenced"),
                                "controller_final_phase": final.get("phase"),
                                "controller_fault_cause": final.get("fault_cause"),
                                "controller_exit_code": rc_controller}
    write_json_atomic(out / "metrics.json", metrics, indent=1)
    return metrics


def _heartbeat_s() -> float:
    from hil.faults.session import driver_timing_s

    return driver_timing_s()[1]


def sim_problems(m: dict[str, Any], trials: int) -> list[str]:
    """What went wrong in a ``--clock sim`` session (empty: nothing). A silence's safe stop, and
    the trials it cut short, are the expected outcome of that fault, not a problem."""
    h = m["hil"]
    problems = []
    kind = h.get("fault_kind")
    if h["exit_codes"].get("firmware_sim") != 0:
        problems.append(f"firmware-sim exit code {h['exit_codes'].get('firmware_sim')}")
    if h["exit_codes"].get("controller") not in (0, 1 if kind == "silence" else 0):
        problems.append(f"controller exit code {h['exit_codes'].get('controller')}")
    if (h.get("sync") or {}).get("controller_gone"):
        problems.append("the plant declared the controller gone (no end of period within the grace)")
    if kind == "silence":
        f = m["fault"]
        if f["safe_state_sim_ms"] is None:
            problems.append("no safe state after the silence: not every axis entered IDLE")
        elif not f["within_bound"]:
            problems.append(f"safe state {f['safe_state_sim_ms']:.0f} ms (simulated) after the silence, over the "
                            f"bound of {f['bound_ms']:.0f} ms")
        if h["controller_final_phase"] != "fault":
            problems.append(f"the controller did not stop safely after the silence (phase {h['controller_final_phase']})")
        if h["trials_completed"] != f["at_trial"]:
            problems.append(f"{h['trials_completed']} trials completed before the silence in trial {f['at_trial']}")
        return problems
    if h["error"]:
        problems.append(h["error"])
    if h["trials_completed"] != trials:
        problems.append(f"{h['trials_completed']} of {trials} trials completed")
    if kind == "rate" and m.get("fault", {}).get("mitm_exit_code") != 0:
        problems.append(f"mitm node exit code {m['fault'].get('mitm_exit_code')}")
    return problems


__all__ = ["run_sim_session", "sim_problems", "fill_from_records", "read_bursts", "CONTROLLER_FIELDS"]
