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

``DIR/metrics.json`` has the same ``config``, ``trials`` and ``summary`` as ``learn``; the
trials' controller-side fields (reflexes, gated ranges and cells, burst changes, burst lengths)
come from the controller's own records, matched to each trial by the monotonic clock both
processes share. ``timing``: the controller's ticks and late ticks (its own count: period above
``late_factor`` periods), its period jitter (|period - nominal|), and the command-to-feedback
latency: on the bus recording, from each Set_Input_Pos to the next Get_Encoder_Estimates from
the same axis (kernel receive timestamps of the recorder's socket). ``hil``: where it ran,
frames each way, phases, watchdog trips, process exit codes.

With fault options (:class:`hil.faults.session.FaultPlan`: rate faults, kill -9 of the controller,
silence of a node) the firmware-sim process is on a second channel behind the man-in-the-middle
node (:mod:`hil.faults.mitm`), and ``metrics.json`` gets a ``fault`` section (:mod:`hil.faults.session`).
Without them the session is as described above.

Where the kernel has no vcan, the whole session runs inside User-Mode Linux (:mod:`hil.uml.runner`).
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import shutil
import signal
import socket
import struct
import subprocess
import sys
import tempfile
import threading
import time
import uuid
from array import array
from pathlib import Path
from typing import TYPE_CHECKING, Any

import can
import numpy as np

from hil.analysis.busload import bus_load_from_log
from protocol import BusContract
from controller.daemon.run import phases_seen, read_records

if TYPE_CHECKING:
    from controller.config import ControllerConfig
    from hil.faults.session import FaultPlan, FaultSession
    from hil.experiments.learn import LearnConfig

CONTROLLER_CMDS = BusContract.load().odrive_master_cmds  # the DBC's messages sent by the Controller
SET_INPUT_POS, GET_ENCODER_ESTIMATES = 12, 9
_F32 = struct.Struct("<f")  # Set_Input_Pos's Input_Pos [rev]
SENSOR_BOARD_NODE = 16


UML_SILENCE_PERIODS = 10.0  # the controller's node-silence timeout inside UML [heartbeat periods] (3.5 natively)


def _in_uml() -> bool:
    from hil.uml.runner import in_uml

    return in_uml()


class HilError(RuntimeError):
    pass


# -- the bus recorder ---------------------------------------------------------------------------
class BusRecorder(threading.Thread):
    """Records every frame on the channel with python-can's writer for ``path``'s suffix, counts
    frames each way and measures command-to-feedback latency. Drains a non-blocking socket every
    10 ms (one system call per frame). With ``audit_commands``, it also keeps every Set_Input_Pos
    target [rev] per node in ``commanded`` (to count targets outside the joint limits later)."""

    def __init__(self, channel: str, path: Path, audit_commands: bool = False) -> None:
        super().__init__(name="bus-recorder", daemon=True)
        from controller.daemon.fastbus import lean

        self.raw = can.Bus(interface="socketcan", channel=channel)
        for opt in (getattr(socket, "SO_RCVBUFFORCE", None), socket.SO_RCVBUF):
            if opt is None:
                continue
            try:  # room for a second of traffic between drains
                self.raw.socket.setsockopt(socket.SOL_SOCKET, opt, 4 << 20)
                break
            except OSError:
                continue
        self.bus = lean(self.raw)
        self.writer = can.Logger(str(path))
        self.path = path
        self.stop_event = threading.Event()
        self.frames = 0
        self.to_leg = 0
        self.from_leg = 0
        self.by_id: dict[int, int] = {}
        self._pending: dict[int, float] = {}
        self.latency_s: list[float] = []
        self.commanded: dict[int, array] | None = {} if audit_commands else None
        self.error: str | None = None

    def _take(self, msg: can.Message) -> None:
        self.writer.on_message_received(msg)
        self.frames += 1
        arb = msg.arbitration_id
        self.by_id[arb] = self.by_id.get(arb, 0) + 1
        node, cmd = arb >> 5, arb & 0x1F
        if node != SENSOR_BOARD_NODE and (cmd in CONTROLLER_CMDS or msg.is_remote_frame):
            self.to_leg += 1
            if cmd == SET_INPUT_POS:
                if node not in self._pending:
                    self._pending[node] = msg.timestamp
                if self.commanded is not None and len(msg.data) >= 4:
                    self.commanded.setdefault(node, array("f")).append(_F32.unpack_from(msg.data)[0])
        else:
            self.from_leg += 1
            if cmd == GET_ENCODER_ESTIMATES and node != SENSOR_BOARD_NODE:
                t = self._pending.pop(node, None)
                if t is not None:
                    self.latency_s.append(msg.timestamp - t)

    def _drain(self) -> None:
        recv = self.bus.recv
        msg = recv(0)
        while msg is not None:
            self._take(msg)
            msg = recv(0)

    def run(self) -> None:
        try:
            while not self.stop_event.is_set():
                time.sleep(0.01)
                self._drain()
            self._drain()
        except Exception as exc:  # noqa: BLE001 - reported in the metrics
            self.error = repr(exc)

    def stop(self) -> None:
        self.stop_event.set()
        self.join(timeout=10)
        self.writer.stop()
        self.raw.shutdown()

    def summary(self) -> dict[str, Any]:
        lat = sorted(self.latency_s)
        q = (lambda p: lat[min(len(lat) - 1, int(math.ceil(p * len(lat))) - 1)] * 1e6) if lat else (lambda p: None)
        return {
            "file": str(self.path),
            "frames": self.frames,
            "controller_to_leg": self.to_leg,
            "leg_to_controller": self.from_leg,
            "command_to_feedback_us": {"median": q(0.5), "p99": q(0.99), "n": len(lat)},
            "error": self.error,
        }


# -- the side channel's client ----------------------------------------------------------------
class ScenarioClient:
    def __init__(self, addr: str, timeout_s: float, alive) -> None:
        from hil.session.firmware import unix_address

        deadline = time.monotonic() + timeout_s
        while True:
            self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            try:
                self.sock.connect(unix_address(addr))
                break
            except OSError:
                self.sock.close()
                if not alive():
                    raise HilError("the firmware-sim process ended before opening its side channel")
                if time.monotonic() > deadline:
                    raise HilError(f"no side channel at {addr} after {timeout_s:.0f} s")
                time.sleep(0.2)
        self._buf = b""

    def send(self, msg: dict[str, Any]) -> None:
        self.sock.sendall((json.dumps(msg) + "\n").encode())

    def receive(self, timeout_s: float, alive=lambda: True) -> dict[str, Any]:
        deadline = time.monotonic() + timeout_s
        while b"\n" not in self._buf:
            left = deadline - time.monotonic()
            if left <= 0:
                raise HilError(f"no answer on the side channel within {timeout_s:.0f} s")
            self.sock.settimeout(min(1.0, left))
            try:
                chunk = self.sock.recv(65536)
            except TimeoutError:
                if not alive():
                    raise HilError("a process of the session ended unexpectedly") from None
                continue
            if not chunk:
                raise HilError("the firmware-sim process closed the side channel")
            self._buf += chunk
        line, self._buf = self._buf.split(b"\n", 1)
        return json.loads(line)

    def request(self, msg: dict[str, Any], timeout_s: float = 30.0, expect: str | None = None) -> dict[str, Any]:
        """Send ``msg``, return the reply; with ``expect``, the first reply whose op it is (a
        trial's ``trial_done`` sent meanwhile is skipped)."""
        self.send(msg)
        deadline = time.monotonic() + timeout_s
        while True:
            reply = self.receive(max(1.0, deadline - time.monotonic()))
            if expect is None or reply.get("op") == expect:
                return reply

    def close(self) -> None:
        self.sock.close()


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


def session_controller_config(config: LearnConfig) -> ControllerConfig:
    """The controller configuration of a session on this platform: the learning run's, with the
    node-silence timeout of :data:`UML_SILENCE_PERIODS` heartbeat periods inside User-Mode Linux.

    User-Mode Linux is one virtual CPU for both processes, the recorder and the harness, and it
    runs near saturation: a node can look silent for a few hundred ms while the plant catches up
    (measured: a 0.35 s gap ended a 5-trial session). The drivers' own watchdogs (0.1 s) still
    stop the leg; the controller waits longer before calling a node lost.
    """
    ctl_config = config.lockstep().controller
    return uml_patient(ctl_config) if _in_uml() else ctl_config


def uml_patient(ctl: ControllerConfig) -> ControllerConfig:
    """``ctl`` waiting at least :data:`UML_SILENCE_PERIODS` heartbeat periods (and as long for a
    stale heartbeat) before it calls a node lost: how the controller runs inside User-Mode Linux."""
    return dataclasses.replace(ctl, silence_periods=max(UML_SILENCE_PERIODS, ctl.silence_periods),
                               stale_heartbeat_periods=max(UML_SILENCE_PERIODS, ctl.stale_heartbeat_periods))


def session_envs() -> tuple[dict[str, str], dict[str, str]]:
    """Environments of the controller and of the firmware-sim process. Inside User-Mode Linux the
    firmware gets the coarse-clock preload: PyBullet's profiler reads gettimeofday() about 7 times
    a step, a trapped system call there."""
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    fw_env = dict(env)
    coarse = os.environ.get("ELEGANT_STEPPING_UML_COARSE_TIME")
    if coarse and os.path.exists(coarse) and os.environ.get("ELEGANT_STEPPING_IN_UML") == "1":
        fw_env["LD_PRELOAD"] = coarse
    return env, fw_env


def run_session(*, trials: int, seed: int, out: str | Path, channel: str = "vcan0", obstacle_height_m: float = 0.08,
                range_noise_m: float = 0.02, learning: bool = True, log_format: str = "blf",
                timeout_s: float | None = None, quiet: bool = False, where: str = "native",
                faults: FaultPlan | None = None) -> dict[str, Any]:
    """One session (see the module docstring). ``faults``: the controller stays on ``channel``,
    the firmware-sim process goes to ``faults.leg_channel``, with the mitm node between them and
    the plan's event (:mod:`hil.faults.session`); ``metrics.json`` then has a ``fault`` section."""
    from controller.settings.file import write_config
    from controller.settings.daemon import session_config
    from hil.experiments.learn import LearnConfig, summarize

    started_unix = time.time()
    wall0 = time.monotonic()
    out = Path(out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    # Inside User-Mode Linux the session writes to the guest's own tmpfs (a write to the host's
    # file system stalls the whole VM for its duration) and copies the files out at the end.
    work = Path(tempfile.mkdtemp(prefix="es-hil-", dir="/dev/shm")) if _in_uml() and os.path.isdir("/dev/shm") else out
    config = LearnConfig(trials=trials, seed=seed, obstacle_height_m=obstacle_height_m, range_noise_m=range_noise_m,
                         learning=learning)
    ctl_config = session_controller_config(config)
    write_config(work / "controller.toml", session_config(ctl_config, channel),
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

    log_path = work / ("bus.blf" if log_format == "blf" else "bus.log")
    for stale in ("bus.blf", "bus.log"):
        (out / stale).unlink(missing_ok=True)
    recorder = BusRecorder(channel, log_path, audit_commands=faults is not None)
    recorder.start()
    py = [sys.executable, "-m", "hil.cli.main"]
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
    fw_bus_args = bus_args if faults is None else ["--interface", "socketcan", "--channel", faults.leg_channel]
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

    def alive() -> bool:
        return (firmware.poll() is None and (controller is None or controller.poll() is None)
                and (fs is None or fs.alive()))

    try:
        client = ScenarioClient(addr, max(10.0, deadline - time.monotonic()), alive)
        say(f"firmware-sim up after {time.monotonic() - wall0:.1f} s")
        # (A real-time priority for the controller inside User-Mode Linux was tried: it starved
        # the plant there. Both processes run at normal priority.)
        controller = subprocess.Popen(
            [*py, "controller", *bus_args, "--config", str(work / "controller.toml"), "--records", str(records_path),
             "--weights", str(work / "weights.npz"), "--ticks", str(work / "controller.ticks")],
            stdout=ctl_log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, env=env)
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
        rc_controller, rc_firmware, bye = stop_session(controller, client, firmware, rc_controller, bye)
        if fs is not None:
            fs.stop()
        recorder.stop()
        fw_log.close()
        ctl_log.close()

    if work != out:
        for f in work.iterdir():
            shutil.copy2(f, out / f.name)
        shutil.rmtree(work, ignore_errors=True)
        records_path = out / records_path.name
    records = read_records(records_path) if records_path.exists() else {}
    final = (records.get("final") or [{}])[-1]
    phases = [r["phase"] for r in records.get("phase", [])]
    trial_dicts = assemble_trials(truths, records)
    wall_s = time.monotonic() - wall0
    weights = final.get("weights")
    bus = {**recorder.summary(), "file": str(out / log_path.name)}
    try:  # the load as a CAN engineer measures it: from the recording, bring-up left out
        bus["load"] = bus_load_from_log(out / log_path.name, skip_s=t_walk or 0.0)
    except (OSError, ValueError) as exc:
        bus["load"] = {"error": str(exc)}
    pacing = final.get("pacing", {})
    watchdog_trips = bye.get("watchdog_trips")
    axes_running = {n: a["state"] for n, a in status_running.get("axes", {}).items()}
    metrics = {
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
        },
        "hil": {
            "where": where,
            "channel": channel,
            "started_unix": started_unix,
            "walk_after_s": t_walk,
            "bus": bus,
            "frames_controller_tx": final.get("frames_tx"),
            "frames_controller_rx": final.get("frames_rx"),
            "frames_controller_dropped": final.get("frames_dropped"),
            "firmware_host": bye.get("host"),
            "phases": phases,
            "axes_while_running": axes_running,
            "axes_at_end": {n: a["state"] for n, a in bye.get("axes", {}).items()},
            "watchdog_trips": watchdog_trips,
            "controller_final_phase": final.get("phase"),
            "fault_cause": final.get("fault_cause"),
            "trials_completed": len(trial_dicts),
            "reflexes": final.get("reflexes"),
            "weights_l1": None if weights is None else float(np.abs(np.asarray(weights)).sum()),
            "exit_codes": {"controller": rc_controller, "firmware_sim": rc_firmware},
            "error": error,
        },
    }
    if fs is not None:
        metrics["hil"]["leg_channel"] = faults.leg_channel
        metrics["fault"] = fs.section(where=where, bye=bye, final=final, rc_controller=rc_controller,
                                      recorder=recorder, out=out)
    tmp = out / "metrics.json.tmp"
    tmp.write_text(json.dumps(metrics, indent=1) + "\n")
    tmp.replace(out / "metrics.json")
    return metrics


def session_ok(m: dict[str, Any], trials: int) -> list[str]:
    """What went wrong in a session (empty: nothing)."""
    h = m["hil"]
    problems = []
    if h["error"]:
        problems.append(h["error"])
    if h["trials_completed"] != trials:
        problems.append(f"{h['trials_completed']} of {trials} trials completed")
    if h["watchdog_trips"] != 0:
        problems.append(f"watchdog trips: {h['watchdog_trips']}")
    if "fault" in h["phases"]:
        problems.append(f"safe stop: {h['fault_cause']}")
    if not (h["bus"]["controller_to_leg"] and h["bus"]["leg_to_controller"]):
        problems.append("frames did not flow both ways")
    return problems


def _inner_argv(args, out: Path) -> list[str]:
    argv = [sys.executable, "-m", "hil.cli.main", "hil", "--trials", str(args.trials), "--seed", str(args.seed),
            "--out", str(out), "--channel", args.channel, "--obstacle-height-m", str(args.obstacle_height_m),
            "--range-noise-m", str(args.range_noise_m), "--log-format", args.log_format, "--where", "native"]
    if args.no_learning:
        argv.append("--no-learning")
    if args.quiet:
        argv.append("--quiet")
    if args.timeout is not None:
        argv += ["--timeout", str(args.timeout)]
    plan = _fault_plan(args)
    return argv + ([] if plan is None else plan.argv())


def _fault_plan(args) -> FaultPlan | None:
    """The session's fault plan from the ``hil`` options (None without any; also None for an
    argparse namespace from before the fault options existed)."""
    if not hasattr(args, "faults_to_leg"):
        return None
    from hil.faults.session import FaultPlan

    return FaultPlan.from_args(args)


def main_hil(args) -> int:
    from hil.uml.runner import VcanUnavailable, in_uml, instruction, native_vcan, run_in_uml, where

    plan = _fault_plan(args)
    try:
        place = where(args.where, args.channel)
        if plan is not None and place == "native" and not native_vcan(plan.leg_channel):
            if args.where != "auto" or in_uml():
                raise VcanUnavailable(f"the fault options need a second channel {plan.leg_channel!r}: "
                                      f"{instruction(plan.leg_channel, uml_considered=False)}")
            place = where("uml", args.channel)
    except VcanUnavailable as exc:
        print(f"elegant-stepping hil: {exc}", file=sys.stderr)
        return 3
    out = Path(args.out).resolve()
    if place == "uml" and not in_uml():
        out.mkdir(parents=True, exist_ok=True)
        budget = args.timeout if args.timeout is not None else 180.0 + 40.0 * args.trials
        t0 = time.time()
        if not args.quiet:
            print(f"hil: no vcan on this kernel; running the session inside User-Mode Linux", file=sys.stderr)
        result = run_in_uml(_inner_argv(args, out), timeout_s=budget + 60.0)
        metrics_path = out / "metrics.json"
        if metrics_path.exists():
            m = json.loads(metrics_path.read_text())
            if m["hil"].get("started_unix", 0) >= t0:
                m["hil"]["where"] = "uml"
                m["hil"]["uml"] = {"boot_to_session_s": m["hil"]["started_unix"] - t0, "wall_s": time.time() - t0,
                                   "exit_code": result.returncode}
                metrics_path.write_text(json.dumps(m, indent=1) + "\n")
        return result.returncode
    m = run_session(trials=args.trials, seed=args.seed, out=out, channel=args.channel,
                    obstacle_height_m=args.obstacle_height_m, range_noise_m=args.range_noise_m,
                    learning=not args.no_learning, log_format=args.log_format, timeout_s=args.timeout,
                    quiet=args.quiet, where="uml" if in_uml() else "native", faults=plan)
    if plan is not None:
        from hil.faults.session import fault_problems, fault_summary

        problems = fault_problems(m, args.trials)
        print(fault_summary(m), file=sys.stderr)
    else:
        problems = session_ok(m, args.trials)
    s, t = m["summary"], m["timing"]
    jit = t["period_jitter_us"] or {}
    c2f = t["command_to_feedback_us"]
    print(f"hil ({m['hil']['where']}, {args.channel}): {m['hil']['trials_completed']}/{args.trials} trials, "
          f"success {s.get('success_rate', 0) or 0:.0%}; frames {m['hil']['bus']['controller_to_leg']} to the leg, "
          f"{m['hil']['bus']['leg_to_controller']} from it; ticks {t['ticks']}, late {t['late_ticks']}, "
          f"skipped {t['skipped_ticks']}; jitter median/p99/max {jit.get('median')}/{jit.get('p99')}/"
          f"{None if jit.get('max') is None else round(jit['max'])} us; command->feedback median/p99 "
          f"{None if c2f['median'] is None else round(c2f['median'])}/"
          f"{None if c2f['p99'] is None else round(c2f['p99'])} us; watchdog trips {m['hil']['watchdog_trips']}; "
          f"wrote {out}/metrics.json and {Path(m['hil']['bus']['file']).name}", file=sys.stderr)
    for p in problems:
        print(f"elegant-stepping hil: {p}", file=sys.stderr)
    return 1 if problems else 0
