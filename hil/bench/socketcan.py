"""``elegant-stepping bench --hil``: the HIL timing figures, each beside the platform's floor.

In one session on one SocketCAN bus (natively where the kernel has vcan, else inside one User-Mode
Linux VM, :mod:`hil.uml.runner`), three runs one after the other:

1. ``bare_loop``: a process ticking at the controller's rate with the controller's pacing code
   (:class:`controller.daemon.pacing.Pacer`, missed periods skipped) and doing no work but noting each tick's
   clock: the jitter and late ticks this platform gives a loop that does nothing.
2. ``echo``: one process, paced the same way, sends one Set_Input_Pos frame per axis each tick
   and drains what it receives; another answers each with a Get_Encoder_Estimates frame at once
   (blocking receive, then send). The harness's bus recorder (:class:`hil.session.recorder.BusRecorder`,
   kernel receive timestamps) measures command-to-feedback exactly as in the HIL session: the
   floor of that latency on this bus.
3. ``hil``: the real pair, the ``firmware-sim`` process and the ``controller`` daemon, as in
   ``elegant-stepping hil`` (same controller configuration, same recorder), walking on flat
   ground for ``seconds`` once the controller reports ``walk``.

Jitter and late ticks of both loops come from every tick's clock (the controller's ``--ticks``
file and the bare loop's, same format), over the walking window for the controller, through one
function (:func:`tick_figures`): period = wake-up to wake-up; jitter = |period - nominal|
(median, p99, max, nearest rank); a tick is late when its period exceeds ``late_factor``
nominal periods (the controller's rule); late per 10,000 = late / periods * 10,000.

Each figure is reported beside its floor with ``ratio`` = figure / floor (None when the floor is
0) and ``excess`` = figure - floor. Like the rest of ``bench``: no threshold is asserted on these.

Inside User-Mode Linux the session writes its figures to a file for the host's side to read
(``python -m hil.bench.socketcan session --out FILE``): stamped ``format: "bench-hil"``,
``format_version`` :data:`SESSION_VERSION` (:func:`controller.errors.stamp`), checked by
:func:`read_session` (another kind or version: one line, no figures).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import subprocess
import sys
import tempfile
import time
import uuid
from array import array
from pathlib import Path
from typing import Any, Sequence
from hil.bench.floor import side_by_side  # noqa: F401 - also this module's, for its readers

SESSION_KIND = "bench-hil"
SESSION_VERSION = 1  # the session file's format version: raise it when a reader of the old one could misread it
NODES = (0, 1)  # the two axes' node ids (ControllerConfig's defaults)
FIGURES = ("period_jitter_p99_us", "period_jitter_median_us", "period_jitter_max_us", "late_ticks_per_10k",
           "command_to_feedback_median_us", "command_to_feedback_p99_us")  # keys of ``figures``


# -- figures -------------------------------------------------------------------------------------
def _nearest_rank(ordered: Sequence[float], q: float) -> float | None:
    n = len(ordered)
    if n == 0:
        return None
    return ordered[max(0, min(n - 1, int(math.ceil(q * n)) - 1))]


def tick_figures(tick_times_s: Sequence[float], period_s: float, late_factor: float = 1.5) -> dict[str, Any]:
    """Jitter and late ticks of a fixed-rate loop from its ticks' clocks (monotonic seconds)."""
    periods = [b - a for a, b in zip(tick_times_s, tick_times_s[1:])]
    jitter_us = sorted(abs(p - period_s) * 1e6 for p in periods)
    late = sum(1 for p in periods if p > late_factor * period_s)
    n = len(periods)
    return {
        "ticks": len(tick_times_s),
        "periods": n,
        "late_ticks": late,
        "late_per_10k": late / n * 10_000 if n else None,
        "period_jitter_us": {"median": _nearest_rank(jitter_us, 0.5), "p99": _nearest_rank(jitter_us, 0.99),
                             "max": jitter_us[-1] if jitter_us else None},
        "max_period_us": max(periods) * 1e6 if periods else None,
        "span_s": tick_times_s[-1] - tick_times_s[0] if len(tick_times_s) > 1 else 0.0,
    }




def compare(hil: dict[str, Any], floor_loop: dict[str, Any], echo: dict[str, Any]) -> dict[str, Any]:
    """The headline figures, each beside its floor."""
    hj, fj = hil["ticks"]["period_jitter_us"], floor_loop["period_jitter_us"]
    hc, fc = hil["command_to_feedback_us"], echo["command_to_feedback_us"]
    return {
        "period_jitter_p99_us": side_by_side(hj["p99"], fj["p99"]),
        "period_jitter_median_us": side_by_side(hj["median"], fj["median"]),
        "period_jitter_max_us": side_by_side(hj["max"], fj["max"]),
        "late_ticks_per_10k": side_by_side(hil["ticks"]["late_per_10k"], floor_loop["late_per_10k"]),
        "command_to_feedback_median_us": side_by_side(hc["median"], fc["median"]),
        "command_to_feedback_p99_us": side_by_side(hc["p99"], fc["p99"]),
    }


def read_ticks(path: str | Path, since_s: float = -math.inf) -> list[float]:
    """Tick clocks from a ``--ticks`` file (pairs of float64: clock, frames read), from ``since_s``."""
    a = array("d")
    data = Path(path).read_bytes()
    a.frombytes(data[: len(data) // 16 * 16])
    return [t for t in a[0::2] if t >= since_s]


# -- the floor's processes ------------------------------------------------------------------------
def bare_loop(seconds: float, ticks_path: str | Path, rate_hz: float = 500.0, late_factor: float = 1.5) -> dict:
    """The controller's pacing, no work: note each tick's clock in the controller's format."""
    from controller.daemon.pacing import Pacer

    pacer = Pacer(1.0 / rate_hz, catch_up=False, late_factor=late_factor)
    buf = array("d")
    t_end = pacer.start() + seconds
    while True:
        now = pacer.wait()
        if now >= t_end:
            break
        buf.append(now)
        buf.append(0.0)
    with open(ticks_path, "wb") as f:
        buf.tofile(f)
    return pacer.summary()


def echo_sender(channel: str, seconds: float, rate_hz: float = 500.0) -> dict:
    """Paced like the controller: each tick one Set_Input_Pos per axis, then drain the bus."""
    import can

    from controller.daemon.fastbus import lean
    from controller.daemon.pacing import Pacer
    from hil.session.recorder import SET_INPUT_POS

    raw = can.Bus(interface="socketcan", channel=channel)
    bus = lean(raw, timestamps=False)
    pacer = Pacer(1.0 / rate_hz, catch_up=False)
    frames = [can.Message(arbitration_id=(n << 5) | SET_INPUT_POS, data=bytes(8), is_extended_id=False) for n in NODES]
    sent = got = 0
    try:
        t_end = pacer.start() + seconds
        while True:
            now = pacer.wait()
            if now >= t_end:
                break
            while bus.recv(0) is not None:
                got += 1
            for f in frames:
                bus.send(f)
                sent += 1
    finally:
        raw.shutdown()
    return {"sent": sent, "received": got, "pacing": pacer.summary()}


def echo_responder(channel: str, idle_timeout_s: float = 2.0) -> dict:
    """Answer each Set_Input_Pos with a Get_Encoder_Estimates from the same node, at once; stop
    after ``idle_timeout_s`` without a frame (once the first has come) or on SIGTERM."""
    import signal

    import can

    from hil.session.recorder import GET_ENCODER_ESTIMATES, SET_INPUT_POS
    from protocol.contract import CMD_ID_MASK

    stop = {"flag": False}
    signal.signal(signal.SIGTERM, lambda *_: stop.update(flag=True))
    bus = can.Bus(interface="socketcan", channel=channel)
    print("ready", flush=True)
    answered = 0
    first = True
    try:
        while not stop["flag"]:
            msg = bus.recv(timeout=30.0 if first else idle_timeout_s)
            if msg is None:
                break
            first = False
            arb = msg.arbitration_id
            if arb & CMD_ID_MASK == SET_INPUT_POS:
                bus.send(can.Message(arbitration_id=(arb & ~CMD_ID_MASK) | GET_ENCODER_ESTIMATES, data=bytes(msg.data),
                                     is_extended_id=False))
                answered += 1
    finally:
        bus.shutdown()
    return {"answered": answered}


# -- the session ----------------------------------------------------------------------------------
def _py(*args: str) -> list[str]:
    return [sys.executable, "-m", "hil.bench.socketcan", *args]


def _child_json(proc: subprocess.Popen, timeout_s: float) -> dict:
    out, err = proc.communicate(timeout=timeout_s)
    lines = [ln for ln in (out or "").splitlines() if ln.startswith("{")]
    if proc.returncode != 0 or not lines:
        raise RuntimeError(f"{proc.args[3:5]} exited {proc.returncode}: {(err or '')[-1500:]}")
    return json.loads(lines[-1])


def run_floor_loop(seconds: float, work: Path, rate_hz: float, late_factor: float) -> dict[str, Any]:
    ticks = work / "bare.ticks"
    proc = subprocess.Popen(_py("bare-loop", "--seconds", str(seconds), "--ticks", str(ticks), "--rate-hz",
                                str(rate_hz), "--late-factor", str(late_factor)),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, stdin=subprocess.DEVNULL)
    pacer = _child_json(proc, seconds + 120.0)
    return {**tick_figures(read_ticks(ticks), 1.0 / rate_hz, late_factor), "pacer_summary": pacer}


def run_floor_echo(seconds: float, work: Path, channel: str, rate_hz: float) -> dict[str, Any]:
    from hil.session.recorder import BusRecorder

    recorder = BusRecorder(channel, work / "echo.log")
    recorder.start()
    responder = subprocess.Popen(_py("echo-responder", "--channel", channel), stdout=subprocess.PIPE,
                                 stderr=subprocess.PIPE, text=True, stdin=subprocess.DEVNULL)
    try:
        if responder.stdout.readline().strip() != "ready":  # its socket is open: no frame goes unanswered
            raise RuntimeError(f"the echo responder did not start: {responder.communicate(timeout=30)[1][-1500:]}")
        sender = subprocess.Popen(_py("echo-sender", "--channel", channel, "--seconds", str(seconds), "--rate-hz",
                                      str(rate_hz)), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                  stdin=subprocess.DEVNULL)
        sent = _child_json(sender, seconds + 120.0)
        responder.terminate()
        answered = _child_json(responder, 30.0)
    finally:
        if responder.poll() is None:
            responder.kill()
            responder.wait(10)
        time.sleep(0.05)
        recorder.stop()
    bus = recorder.summary()
    return {"command_to_feedback_us": bus["command_to_feedback_us"], "frames": bus["frames"],
            "sender": {k: sent[k] for k in ("sent", "received")}, "answered": answered["answered"],
            "sender_pacing": sent["pacing"], "recorder_error": bus["error"]}


def run_hil_pair(seconds: float, work: Path, channel: str, seed: int, bringup_timeout_s: float = 180.0) -> dict[str, Any]:
    """The controller daemon and the firmware-sim process walking for ``seconds``."""
    from controller.settings.file import write_config
    from controller.settings.daemon import session_config
    from controller.daemon.run import read_records
    from hil.session.outcome import HilError
    from hil.session.recorder import BusRecorder
    from hil.session.run import session_controller_config, session_envs, stop_session
    from hil.profile import current as current_profile
    from hil.session.scenario import ScenarioClient
    from hil.experiments.learn import LearnConfig

    ctl_config = session_controller_config(LearnConfig(trials=1, seed=seed))  # auto_arm: it arms by itself
    write_config(work / "controller.toml", session_config(ctl_config, channel, work / "control.sock",
                                                        current_profile().driver_watchdog_s),
                 header="the controller's configuration in this bench --hil run (written by hil.bench.socketcan)")
    records_path, ticks_path = work / "controller.jsonl", work / "controller.ticks"
    recorder = BusRecorder(channel, work / "bus.log")
    recorder.start()
    py = [sys.executable, "-m", "hil.cli"]
    bus_args = ["--interface", "socketcan", "--channel", channel]
    addr = f"@elegant-stepping-bench-{os.getpid()}-{uuid.uuid4().hex[:8]}"
    env, fw_env = session_envs()
    fw_log, ctl_log = open(work / "firmware.log", "w"), open(work / "controller.log", "w")
    t0 = time.monotonic()
    firmware = subprocess.Popen([*py, "firmware-sim", *bus_args, "--seed", str(seed), "--scenario", addr],
                                stdout=fw_log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, env=fw_env)
    controller = client = None
    bye: dict[str, Any] = {}
    error = None
    walk_mono = None
    window_latency: list[float] = []
    rc = {}

    def alive() -> bool:
        return firmware.poll() is None and (controller is None or controller.poll() is None)

    try:
        client = ScenarioClient(addr, bringup_timeout_s, alive)
        controller = subprocess.Popen(
            [*py, "controller", *bus_args, "--config", str(work / "controller.toml"), "--records", str(records_path),
             "--ticks", str(ticks_path)],
            stdout=ctl_log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, env=env)
        while walk_mono is None:
            recs = read_records(records_path)["phase"] if records_path.exists() else []
            walk = [r for r in recs if r["phase"] == "walk"]
            if walk:
                walk_mono = walk[0]["t_s"]
                break
            if any(r["phase"] == "fault" for r in recs) or not alive():
                raise HilError(f"the controller did not come up (phases {[r['phase'] for r in recs]})")
            if time.monotonic() - t0 > bringup_timeout_s:
                raise HilError("the controller did not reach walk in time")
            time.sleep(0.2)
        recorder.latency_s = window_latency = []  # from here on: the walking window (swapped atomically)
        time.sleep(max(0.0, walk_mono + seconds - time.monotonic()))
        recorder.latency_s = []  # end of the window
    except (HilError, OSError, ValueError) as exc:
        error = str(exc)
    finally:
        rc["controller"], rc["firmware_sim"], bye = stop_session(controller, client, firmware, bye=bye)
        recorder.stop()
        fw_log.close()
        ctl_log.close()
    records = read_records(records_path) if records_path.exists() else {}
    final = (records.get("final") or [{}])[-1]
    t_end = walk_mono + seconds if walk_mono is not None else math.inf
    ticks = [t for t in read_ticks(ticks_path, walk_mono if walk_mono is not None else math.inf) if t <= t_end] \
        if ticks_path.exists() else []
    lat = sorted(window_latency)
    return {
        "ticks": tick_figures(ticks, ctl_config.period_s, ctl_config.late_factor),
        "command_to_feedback_us": {"median": None if not lat else _nearest_rank(lat, 0.5) * 1e6,
                                   "p99": None if not lat else _nearest_rank(lat, 0.99) * 1e6, "n": len(lat)},
        "walk_after_s": None if walk_mono is None else walk_mono - t0,
        "walking_s": seconds,
        "phases": [r["phase"] for r in records.get("phase", [])],
        "controller_pacer_summary": final.get("pacing"),  # the whole run, bring-up included
        "firmware_pacing": bye.get("pacing"),
        "watchdog_trips": bye.get("watchdog_trips"),
        "frames": recorder.frames,
        "exit_codes": rc,
        "error": error,
    }


def session(seconds: float, seed: int = 0, channel: str = "vcan0", where: str = "native") -> dict[str, Any]:
    """The three runs, here (a kernel with ``channel`` up)."""
    from controller.config import ControllerConfig

    started_unix = time.time()
    cfg = ControllerConfig()
    base = "/dev/shm" if os.path.isdir("/dev/shm") and os.access("/dev/shm", os.W_OK) else None
    work = Path(tempfile.mkdtemp(prefix="es-bench-hil-", dir=base))
    try:
        floor = run_floor_loop(seconds, work, cfg.rate_hz, cfg.late_factor)
        echo = run_floor_echo(seconds, work, channel, cfg.rate_hz)
        hil = run_hil_pair(seconds, work, channel, seed)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return {
        "available": True,
        "ran": True,
        "where": where,
        "channel": channel,
        "seconds": seconds,
        "rate_hz": cfg.rate_hz,
        "late_factor": cfg.late_factor,
        "started_unix": started_unix,
        "figures": compare(hil, floor, echo),
        "detail": {"hil": hil, "floor_loop": floor, "floor_echo": echo},
        "error": hil["error"],
    }


def hil_availability(channel: str = "vcan0", mode: str = "auto") -> dict[str, Any]:
    """The ``hil`` section when ``--hil`` was not asked for: where it would run, nothing measured."""
    from hil.uml.runner import INSTALL, VcanUnavailable, where

    try:
        return {"available": True, "ran": False, "where": where(mode, channel),
                "note": "pass --hil to measure the HIL figures beside their floor"}
    except VcanUnavailable as exc:
        return {"available": False, "ran": False, "error": str(exc), "install": INSTALL}


def run_hil_bench(seconds: float = 10.0, seed: int = 0, channel: str = "vcan0", mode: str = "auto") -> dict[str, Any]:
    """The ``hil`` section of ``bench``: natively where ``channel`` can be had, else in one UML VM.
    Never raises for a missing bus: ``available`` is False and ``error``/``install`` say why."""
    from hil.profile import current
    from hil.uml.runner import INSTALL, VcanUnavailable, run_in_uml, where

    try:
        place = where(mode, channel)
    except VcanUnavailable as exc:
        return {"available": False, "ran": False, "error": str(exc), "install": INSTALL}
    if place == "native" or current().uml:
        return session(seconds, seed, channel, current().name)
    t0 = time.time()
    out_dir = Path(tempfile.mkdtemp(prefix="es-bench-hil-out-"))
    out = out_dir / "hil.json"
    try:
        done = run_in_uml(_py("session", "--seconds", str(seconds), "--seed", str(seed), "--channel", channel,
                              "--out", str(out)), timeout_s=3 * seconds + 400.0, capture=True)
        wall = time.time() - t0
        if not out.exists():
            return {"available": False, "ran": False, "where": "uml", "error": f"the session inside User-Mode Linux wrote no "
                    f"figures (exit {done.returncode}): {(done.stdout or '')[-1500:]}", "install": INSTALL}
        try:
            result = read_session(out)
        except ValueError as exc:  # InputError included: one line, in the hil section
            return {"available": False, "ran": False, "where": "uml", "error": str(exc), "install": INSTALL}
    finally:
        shutil.rmtree(out_dir, ignore_errors=True)
    result["where"] = "uml"
    result["uml"] = {"boot_to_session_s": result["started_unix"] - t0, "wall_s": wall, "exit_code": done.returncode}
    return result


def write_session(path: str | Path, result: dict[str, Any]) -> None:
    """The session's figures, stamped (:data:`SESSION_KIND`, :data:`SESSION_VERSION`), atomically."""
    from controller.atomic import write_json_atomic
    from controller.errors import stamp

    write_json_atomic(path, {**stamp(SESSION_KIND, SESSION_VERSION), **result}, indent=1)


def read_session(path: str | Path) -> dict[str, Any]:
    """The figures :func:`write_session` wrote, without the stamp.

    Raises:
        InputError: not JSON, another kind of file or another format version (one line).
    """
    from controller.errors import read_stamped_json

    return read_stamped_json(path, SESSION_KIND, {SESSION_VERSION})


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m hil.bench.socketcan", description="the processes of bench --hil")
    sub = p.add_subparsers(dest="cmd", required=True)
    b = sub.add_parser("bare-loop")
    b.add_argument("--seconds", type=float, required=True)
    b.add_argument("--ticks", required=True)
    b.add_argument("--rate-hz", type=float, default=500.0)
    b.add_argument("--late-factor", type=float, default=1.5)
    s = sub.add_parser("echo-sender")
    s.add_argument("--channel", default="vcan0")
    s.add_argument("--seconds", type=float, required=True)
    s.add_argument("--rate-hz", type=float, default=500.0)
    r = sub.add_parser("echo-responder")
    r.add_argument("--channel", default="vcan0")
    se = sub.add_parser("session", help="the three runs here; JSON to --out")
    se.add_argument("--seconds", type=float, default=10.0)
    se.add_argument("--seed", type=int, default=0)
    se.add_argument("--channel", default="vcan0")
    se.add_argument("--out", required=True)
    a = p.parse_args(argv)
    if a.cmd == "bare-loop":
        print(json.dumps(bare_loop(a.seconds, a.ticks, a.rate_hz, a.late_factor)))
    elif a.cmd == "echo-sender":
        print(json.dumps(echo_sender(a.channel, a.seconds, a.rate_hz)))
    elif a.cmd == "echo-responder":
        print(json.dumps(echo_responder(a.channel)))
    else:
        from hil.profile import current

        write_session(a.out, session(a.seconds, a.seed, a.channel, current().name))
    return 0


if __name__ == "__main__":
    sys.exit(main())
