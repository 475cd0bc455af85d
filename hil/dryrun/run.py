"""``elegant-stepping dryrun``: the exact deployment against the simulated leg, the last step
before a real leg.

It reads the unit file (``deploy/elegant-stepping-controller.service``), takes its ``ExecStart``
command line and changes only the ``--config`` value: the real leg's
``/etc/elegant-stepping/leg.toml`` (bus can0) becomes the simulated leg's ``configs/sim.toml``
(bus vcan0, the simulated drivers' values). Inside User-Mode Linux that file is first copied with
the node-silence timeout every ``hil`` session there uses (10 heartbeat periods instead of 3.5:
one virtual CPU near saturation), and the report says so. The program
``/usr/local/bin/elegant-stepping`` is used where it is installed (on the leg's computer after
``deploy/install.sh``), else this environment's ``elegant-stepping``. The unit's
``Environment=`` is applied. Then it plays systemd: ``firmware-sim`` on vcan0, a notify socket (:class:`hil.dryrun.notify_listener.
NotifyListener`), the daemon started with ``NOTIFY_SOCKET``, ``WATCHDOG_USEC`` from the unit's
``WatchdogSec`` and ``WATCHDOG_PID`` its own pid (set by a shell that then execs the command, as
systemd does), the unit's ``TimeoutStartSec`` for READY, ``seconds`` of running after READY, then
SIGTERM and the unit's ``TimeoutStopSec``. Where the kernel has no vcan, all of it runs inside
User-Mode Linux (:mod:`hil.uml.runner`), the notify socket included.

The checklist (``DIR/dryrun.json``, printed): READY seen from the daemon's own pid within
TimeoutStartSec; every notification from that pid (``NotifyAccess=main``); pings regular (at
least half the expected count, and no gap as long as WatchdogSec plus the platform's stalls
measured beside the daemon in this run, see below); walked (STATUS walking, steps
taken, still walking at SIGTERM); both axes in CLOSED_LOOP_CONTROL while it ran; STOPPING seen
after SIGTERM; exit code 0 within TimeoutStopSec; both axes IDLE at the end with no watchdog
trip (put there by the daemon, not by the drivers' watchdogs); no sd_notify send errors.

The pings are a safety outcome that exists only in real time: a ping comes late by as much as
the platform stalls the daemon's loop, and its arrival is stamped late by as much as it stalls
this harness. So a :class:`hil.bench.floor.FloorProbe` (a process ticking at 100 Hz doing no
work, at the daemon's priority) runs beside the daemons, and the longest gap allowed is
WatchdogSec plus :meth:`hil.profile.Profile.late_allowance_s` of that measured stall, once for
the daemon and once for the harness (``floor`` in the report); natively the stall is a few ms
and the limit is WatchdogSec. No fixed wall-clock budget is added anywhere.

``dryrun.json`` carries the stamp ``format: "dryrun"``, ``format_version`` :data:`REPORT_VERSION`
(:func:`controller.errors.stamp`); :func:`read_report` refuses another kind or version in one line.

Not reproduced here: ``ExecStartPre`` (it configures the real can0; vcan0 is up already),
``User=`` and the sandboxing options (this process's user and file system are used), and the
journal (the daemon's output goes to ``DIR/controller.log``).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import uuid
from pathlib import Path
from typing import TYPE_CHECKING, Any

from controller.atomic import write_json_atomic
from controller.errors import stamp

if TYPE_CHECKING:
    from hil.profile import Profile

REPORT_KIND = "dryrun"
REPORT_VERSION = 1  # dryrun.json's format version: raise it when a reader of the old one could misread it
REPO = Path(__file__).resolve().parents[2]


def _first(*paths: Path) -> Path:
    """The first of ``paths`` that exists (else the first: the error then names it)."""
    return next((p for p in paths if p.exists()), paths[0])


# In a checkout: the repository's files. Installed by deploy/install.sh (no checkout): the copies
# it put in place.
UNIT = _first(REPO / "deploy" / "elegant-stepping-controller.service",
              Path("/etc/systemd/system/elegant-stepping-controller.service"))
SIM_CONFIG = _first(REPO / "configs" / "sim.toml", Path("/usr/local/share/elegant-stepping/sim.toml"))
INSTALLED = "/usr/local/bin/elegant-stepping-leg"
WATCHDOG_PID_SHIM = 'WATCHDOG_PID=$$; export WATCHDOG_PID; exec "$@"'


# -- the command line ---------------------------------------------------------------------------
def program_argv(program: str) -> tuple[list[str], str]:
    """The program to run for the unit's ``program`` path (the leg's console script,
    ``elegant-stepping-leg``): itself where it exists, else this environment's script of the same
    name, else this interpreter with ``-m controller.cli`` (the same entry point)."""
    if os.path.exists(program) and os.access(program, os.X_OK):
        return [program], "as in the unit"
    script = Path(sys.executable).with_name(Path(program).name)
    if script.exists():
        return [str(script)], f"{program} is not installed here: this environment's {script}"
    return [sys.executable, "-m", "controller.cli"], f"{program} is not installed here: {sys.executable} -m controller.cli"


def swap_config(argv: list[str], config: str) -> tuple[list[str], str | None]:
    """``argv`` with its ``--config`` value replaced by ``config`` (added if absent); returns the
    new argv and the value it replaced."""
    out, old = list(argv), None
    for i, word in enumerate(out):
        if word == "--config" and i + 1 < len(out):
            old, out[i + 1] = out[i + 1], config
            return out, old
        if word.startswith("--config="):
            old, out[i] = word.split("=", 1)[1], f"--config={config}"
            return out, old
    return out + ["--config", config], None


@dataclasses.dataclass
class Deployment:
    """What the unit file says, and what the dry run runs instead where it must."""

    unit_path: str
    exec_start: list[str]  # the unit's command line, as written
    argv: list[str]  # what runs: the same with the program and the config swapped
    env: dict[str, str]  # the unit's Environment=
    watchdog_s: float
    start_timeout_s: float
    stop_timeout_s: float
    swaps: list[str]

    @classmethod
    def from_unit(cls, unit_path: str | Path, config: str) -> Deployment:
        from hil.dryrun.unitfile import command_line, environment, read_unit, time_span_s, value

        unit = read_unit(unit_path)
        if value(unit, "Service", "Type") != "notify":
            raise ValueError(f"{unit_path}: Type=notify expected, got {value(unit, 'Service', 'Type')!r}")
        exec_start = value(unit, "Service", "ExecStart")
        if exec_start is None:
            raise ValueError(f"{unit_path}: no ExecStart=")
        _, argv = command_line(exec_start)
        program, how = program_argv(argv[0])
        swapped, old = swap_config(argv[1:], config)
        env = environment(unit)
        swaps = [f"program: {how}", f"--config: {old} -> {config}"]
        watchdog = value(unit, "Service", "WatchdogSec")
        if watchdog is None:
            raise ValueError(f"{unit_path}: no WatchdogSec=")
        return cls(unit_path=str(unit_path), exec_start=argv, argv=program + swapped, env=env,
                   watchdog_s=time_span_s(watchdog),
                   start_timeout_s=time_span_s(value(unit, "Service", "TimeoutStartSec", "90s")),
                   stop_timeout_s=time_span_s(value(unit, "Service", "TimeoutStopSec", "90s")), swaps=swaps)


def platform_config(path: Path, folder: Path, channel: str) -> tuple[Path, list[str]]:
    """The simulated leg's config as the dry run runs it: a copy of ``path`` in ``folder`` in which
    the daemon waits for a person (``auto_arm`` off, as on a real leg: the dry run plays the person,
    :mod:`hil.dryrun.operator`), with its control socket in ``folder``, and inside User-Mode Linux
    the node-silence timeout of a ``hil`` session there (:attr:`hil.profile.Profile.min_silence_periods`).
    Checks that its bus is SocketCAN ``channel``. Returns the file and what was changed."""
    from controller.settings.file import load_config, write_config
    from hil.profile import current

    profile = current()
    config = load_config(path)
    if (config.bus.interface, config.bus.channel) != ("socketcan", channel):
        raise ValueError(f"{path}: the simulated leg's config must be on socketcan {channel}, "
                         f"not {config.bus.interface} {config.bus.channel}")
    ctl = config.controller
    socket = folder / "control.sock"
    if len(str(socket).encode()) > 100:  # a Unix socket's path has at most 107 bytes
        socket = Path(tempfile.gettempdir()) / f"es-dryrun-{os.getpid()}.sock"
    swaps = [f"auto_arm {str(ctl.auto_arm).lower()} -> false (the dry run plays the person who arms the leg)",
             f"control_socket {config.service.control_socket} -> {socket}"]
    least = profile.min_silence_periods
    if least is not None and ctl.silence_periods < least:
        swaps.append(f"inside User-Mode Linux: silence_periods {ctl.silence_periods:g} -> {least:g} "
                     "(as every hil session there)")
        ctl = profile.controller_config(ctl)
    copy = folder / f"{path.stem}-dryrun.toml"
    write_config(copy, dataclasses.replace(config, controller=dataclasses.replace(ctl, auto_arm=False),
                                           service=dataclasses.replace(config.service, control_socket=str(socket))),
                 header=f"{path} as the dry run runs it (hil.dryrun.run)")
    return copy, [f"{s}, in a copy {copy.name}" for s in swaps]


# -- the checklist ------------------------------------------------------------------------------
def final_record(log_text: str) -> dict[str, Any]:
    """The daemon's last words: the JSON line ``controller`` prints at exit (empty if none)."""
    for line in reversed(log_text.splitlines()):
        line = line.strip()
        if line.startswith("{") and '"stopped_by"' in line:
            try:
                return json.loads(line)
            except ValueError:
                continue
    return {}


def checklist(*, messages: list, pid: int, t_start: float, t_term: float | None, rc: int | None,
              final: dict[str, Any], status_running: dict[str, Any], bye: dict[str, Any],
              dep: Deployment, pids: list[int] | None = None, stall_s: float | None = None,
              profile: "Profile | None" = None) -> list[dict[str, Any]]:
    """The dry run's checks of the last daemon started (``pid``; ``pids``: every daemon the run
    started, each allowed to notify), in order: ``{"check", "ok", "detail"}`` each.

    ``stall_s``: the platform's longest stall measured beside the daemons in this run
    (:class:`hil.bench.floor.FloorProbe`; None: not measured). The longest ping gap allowed is
    WatchdogSec plus ``profile.late_allowance_s(stall_s, stall_s)`` (the daemon's loop and this
    harness's listener, each late by at most that stall; ``profile``: :func:`hil.profile.current`
    by default)."""
    from hil.profile import current

    items: list[dict[str, Any]] = []
    started = set(pids or [pid])
    every = messages
    messages = [m for m in every if m.pid == pid]

    def add(check: str, ok: bool, detail: str) -> None:
        items.append({"check": check, "ok": bool(ok), "detail": detail})

    ready = next((m for m in messages if m.has("READY", "1")), None)
    add("READY", ready is not None and ready.pid == pid and ready.t_s - t_start <= dep.start_timeout_s,
        "not seen" if ready is None else
        f"{ready.t_s - t_start:.1f} s after start (TimeoutStartSec {dep.start_timeout_s:g} s), from pid {ready.pid}: "
        f"{ready.fields.get('STATUS', '')!r}")
    foreign = [m.pid for m in every if m.pid not in started]
    add("NotifyAccess=main", bool(messages) and not foreign,
        f"{len(every)} notifications, all from the daemons' main pids {sorted(started)}" if not foreign else
        f"from other pids: {sorted(set(foreign))[:5]}")
    t_stop = next((m.t_s for m in messages if m.has("STOPPING", "1")), t_term if t_term is not None else math.inf)
    pings = [m.t_s for m in messages if m.has("WATCHDOG", "1") and m.t_s <= t_stop]
    period = dep.watchdog_s / 2.0
    gaps = [b - a for a, b in zip(pings, pings[1:])]
    span = (pings[-1] - pings[0]) if len(pings) > 1 else 0.0
    if ready is not None and t_term is not None:
        after = [t for t in pings if ready.t_s <= t <= t_term]
        expected = (t_term - ready.t_s) / period
    else:
        after, expected = [], math.inf
    max_gap = max(gaps) if gaps else math.inf
    allowance = (profile or current()).late_allowance_s(stall_s, stall_s)
    limit = dep.watchdog_s + allowance
    stall = "not measured" if stall_s is None else f"{stall_s:.3f} s"
    add("WATCHDOG pings regular", len(after) >= max(2.0, 0.5 * expected) and max_gap < limit,
        f"{len(pings)} pings, {len(after)} between READY and SIGTERM (about {expected:.0f} expected at "
        f"{period:g} s); median gap {sorted(gaps)[len(gaps) // 2] if gaps else math.nan:.3f} s, "
        f"longest {max_gap:.3f} s (limit {limit:.3f} s: WatchdogSec {dep.watchdog_s:g} s + {allowance:.3f} s for the "
        f"platform's longest stall beside the daemon, {stall}), over {span:.1f} s")
    statuses = [m.fields["STATUS"] for m in messages if "STATUS" in m.fields]
    seen = any(s.endswith("walking") for s in statuses)
    walked = seen and (final.get("steps") or 0) > 0 and final.get("phase") == "walk"
    add("walked", walked, f"STATUS walking {'seen' if seen else 'not seen'}, "
        f"{final.get('steps')} steps, phase at exit {final.get('phase')!r}"
        + (f", fault: {final.get('fault_cause')}" if final.get("fault_cause") else ""))
    running = {n: a.get("state") for n, a in status_running.get("axes", {}).items()}
    add("axes in closed loop while running", bool(running) and all(s == "CLOSED_LOOP_CONTROL" for s in running.values()),
        f"{running or 'no status'}")
    stopping = next((m for m in messages if m.has("STOPPING", "1")), None)
    add("STOPPING", stopping is not None and t_term is not None and stopping.t_s >= t_term,
        "not seen" if stopping is None else
        f"{stopping.t_s - (t_term or stopping.t_s):.3f} s after SIGTERM: {stopping.fields.get('STATUS', '')!r}")
    add("exit 0", rc == 0, f"exit code {rc}" + ("" if rc is not None else f" (still running after TimeoutStopSec "
                                                                              f"{dep.stop_timeout_s:g} s: killed)"))
    end = {n: a.get("state") for n, a in bye.get("axes", {}).items()}
    trips = bye.get("watchdog_trips")
    add("axes IDLE at the end", bool(end) and all(s == "IDLE" for s in end.values()) and trips == 0,
        f"{end or 'no status'}, driver watchdog trips {trips}")
    notify = final.get("sd_notify") or {}
    add("sd_notify errors", notify.get("errors") == 0, f"{notify or 'no sd_notify summary in the final record'}")
    return items


# -- the run ------------------------------------------------------------------------------------
def run_dryrun(*, unit: str | Path = UNIT, config: str | Path | None = None, seconds: float = 10.0,
               out: str | Path = "out/dryrun", channel: str = "vcan0", seed: int = 0,
               quiet: bool = False) -> dict[str, Any]:
    """The dry run on a vcan ``channel`` that is up (see the module docstring); writes
    ``out/dryrun.json``, ``out/controller.log``, ``out/firmware.log``; returns the report."""
    from hil.bench.floor import FloorProbe
    from hil.dryrun.notify_listener import NotifyListener
    from hil.dryrun.operator import Operator, axes_text
    from hil.profile import current
    from hil.session.outcome import HilError
    from hil.session.run import session_envs, stop_session
    from hil.session.scenario import ScenarioClient

    out = Path(out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    profile = current()
    work = profile.work_folder(out, "es-dryrun-")  # copied out at the end if elsewhere
    config, platform = platform_config(Path(SIM_CONFIG if config is None else config).resolve(), work, channel)
    dep = Deployment.from_unit(unit, str(config))
    dep.swaps += platform

    def say(text: str) -> None:
        if not quiet:
            print(f"dryrun: {text}", file=sys.stderr, flush=True)

    env, fw_env = session_envs()
    addr = f"@elegant-stepping-dryrun-{os.getpid()}-{uuid.uuid4().hex[:8]}"
    fw_log = open(work / "firmware.log", "w")
    ctl_log = open(work / "controller.log", "w")
    firmware = subprocess.Popen(
        [sys.executable, "-m", "hil.cli", "firmware-sim", "--interface", "socketcan", "--channel", channel,
         "--seed", str(seed), "--scenario", addr],
        stdout=fw_log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, env=fw_env)
    listener = NotifyListener()
    floor_probe: FloorProbe | None = None
    floor: dict[str, Any] = {}
    daemon: subprocess.Popen | None = None
    pids: list[int] = []
    client = None
    status_running: dict[str, Any] = {}
    bye: dict[str, Any] = {}
    error = None
    t_start = t_term = None
    rc = None
    from controller.settings.file import load_config

    operator = Operator(load_config(config).service.control_socket, say)
    try:
        client = ScenarioClient(addr, 120.0, lambda: firmware.poll() is None)
        say("firmware-sim up; starting the unit's command line: " + " ".join(dep.argv))
        listener.start()
        daemon_env = {**env, **dep.env, "NOTIFY_SOCKET": listener.address,
                      "WATCHDOG_USEC": str(int(round(dep.watchdog_s * 1e6)))}
        daemon_env.pop("WATCHDOG_PID", None)
        # This harness (and the operator's commands it runs) yields to the two real-time processes.
        # The daemons are started from here after that, so they undo it (``nice -n -N``, an exec:
        # the pid systemd would watch stays the daemon's), as firmware-sim runs; where lowering
        # the niceness is not permitted, nice says so in controller.log and they run as this
        # harness. The floor probe is started the same way: it measures at the daemons' priority.
        before = os.nice(0)
        try:
            os.nice(10)
        except OSError:
            pass
        yielded = os.nice(0) - before
        renice = ["nice", "-n", str(-yielded)] if yielded > 0 else []
        floor_probe = FloorProbe(prefix=renice).start()

        def start() -> tuple[subprocess.Popen, float, Any]:
            """The unit's command line, as systemd starts it; (process, start time, its READY)."""
            t0 = time.monotonic()
            proc = subprocess.Popen(["/bin/sh", "-c", WATCHDOG_PID_SHIM, "sh", *renice, *dep.argv], stdout=ctl_log,
                                    stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, env=daemon_env)
            pids.append(proc.pid)
            ready = listener.wait_for("READY", "1", dep.start_timeout_s,
                                      lambda: proc.poll() is None and firmware.poll() is None, pid=proc.pid)
            if ready is None:
                raise HilError(f"no READY=1 within TimeoutStartSec ({dep.start_timeout_s:g} s)"
                               + ("" if proc.poll() is None else f"; the daemon exited with {proc.poll()}"))
            return proc, t0, ready

        def stop(proc: subprocess.Popen) -> int | None:
            """SIGTERM, as ``systemctl stop``; SIGKILL after TimeoutStopSec. The exit code (None: killed)."""
            if proc.poll() is None:
                proc.send_signal(signal.SIGTERM)
            try:
                return proc.wait(dep.stop_timeout_s)
            except subprocess.TimeoutExpired:
                proc.kill()  # what systemd does after TimeoutStopSec (SIGKILL)
                proc.wait(10)
                return None

        # the first start: inactive, then a person arms it, walks, presses the e-stop
        daemon, t_start, ready = start()
        alive = lambda: daemon.poll() is None and firmware.poll() is None  # noqa: E731
        say(f"READY after {ready.t_s - t_start:.1f} s (inactive)")
        st = operator.status()
        operator.check("status while inactive", st.get("lifecycle") == "inactive" and set(st.get("axes", {})) ==
                       {"hip", "knee"}, f"lifecycle {st.get('lifecycle')}, phase {st.get('phase')}: {axes_text(st)}")
        code, _, err = operator.verb("arm")
        st = operator.wait_for("walk", 30.0, alive)
        operator.check("arm walks the leg", code == 0 and st.get("phase") == "walk",
                       f"arm exit {code}{': ' + err.strip() if code else ''}; then phase {st.get('phase')}: {axes_text(st)}")
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline and alive():
            time.sleep(0.1)
        if not alive():
            raise HilError(f"a process ended early (daemon {daemon.poll()}, firmware-sim {firmware.poll()})")
        status_running = client.request({"op": "status"}, expect="status")
        code, _, err = operator.verb("estop")
        st = operator.wait_for("fault", 10.0, alive)
        time.sleep(0.3)
        legs = {n: a.get("state") for n, a in client.request({"op": "status"}, expect="status").get("axes", {}).items()}
        operator.check("estop stops it", code == 0 and st.get("phase") == "fault" and legs and
                       all(s == "IDLE" for s in legs.values()),
                       f"estop exit {code}; phase {st.get('phase')} ({st.get('fault_cause')}); drivers {legs}")
        first_rc = stop(daemon)
        operator.check("first daemon stopped", first_rc == 0, f"exit code {first_rc} after SIGTERM")

        # the daemon restarted (a crash, a reboot): the e-stop must stay latched until a person clears it
        daemon, t_start, ready = start()
        say(f"restarted: READY after {ready.t_s - t_start:.1f} s")
        code, reply, err = operator.verb("arm")
        time.sleep(1.0)
        st = operator.status()
        operator.check("stays stopped across a restart", code == 1 and "ESTOP_REQUESTED" in (reply.get("refused") or err)
                       and st.get("phase") != "walk",
                       f"arm exit {code}: {(reply.get('refused') or err).strip()}; phase {st.get('phase')}: {axes_text(st)}")
        code, _, err = operator.verb("clear-faults")
        st = operator.wait_for("inactive", 15.0, alive)
        cleared = code == 0 and st.get("phase") == "inactive" and not any(a.get("error") for a in st.get("axes", {}).values())
        code2, _, err2 = operator.verb("arm")
        st = operator.wait_for("walk", 30.0, alive)
        operator.check("clear-faults, then arm walks again", cleared and code2 == 0 and st.get("phase") == "walk",
                       f"clear-faults exit {code}, arm exit {code2}{': ' + err2.strip() if code2 else ''}; "
                       f"phase {st.get('phase')}: {axes_text(st)}")
        deadline = time.monotonic() + 2.0
        while time.monotonic() < deadline and alive():
            time.sleep(0.1)
    except (HilError, OSError, ValueError, subprocess.TimeoutExpired) as exc:
        error = str(exc)
        say(f"error: {error}")
    finally:
        if daemon is not None:
            t_term = time.monotonic()
            if daemon.poll() is None:
                daemon.send_signal(signal.SIGTERM)
            try:
                rc = daemon.wait(dep.stop_timeout_s)
            except subprocess.TimeoutExpired:
                daemon.kill()  # what systemd does after TimeoutStopSec (SIGKILL)
                daemon.wait(10)
                rc = None
            time.sleep(0.3)  # longer than the drivers' watchdog: had the daemon not sent IDLE, they would trip
        _, _, bye = stop_session(None, client, firmware)
        if floor_probe is not None:
            floor = floor_probe.stop()
        listener.stop()
        fw_log.close()
        ctl_log.close()
    final = final_record((work / "controller.log").read_text())
    items = checklist(messages=listener.snapshot(), pid=daemon.pid if daemon else -1, t_start=t_start or 0.0,
                      t_term=t_term, rc=rc, final=final, status_running=status_running, bye=bye, dep=dep,
                      pids=pids, stall_s=floor.get("max_period_s"), profile=profile) + operator.items
    report = {
        **stamp(REPORT_KIND, REPORT_VERSION),
        "ok": error is None and all(i["ok"] for i in items),
        "checks": items,
        "error": error,
        "unit": dep.unit_path,
        "exec_start": dep.exec_start,
        "ran": dep.argv,
        "swaps": dep.swaps,
        "notes": ["not reproduced: ExecStartPre (configures the real can0), User= and the sandboxing "
                  "options, Nice= (the daemon runs at firmware-sim's priority, this harness below both), "
                  "the journal (see controller.log)"],
        "watchdog_usec": int(round(dep.watchdog_s * 1e6)),
        "seconds": seconds,
        "where": profile.name,
        "floor": floor or None,
        "notifications": [{"t_s": m.t_s - (t_start or 0.0), "pid": m.pid, **m.fields} for m in listener.snapshot()],
        "daemon_pids": pids,
        "operator": operator.transcript,
        "final": {k: v for k, v in final.items() if k != "weights"},
    }
    write_json_atomic(work / "dryrun.json", report, indent=1)
    if work != out:
        for f in work.iterdir():
            shutil.copy2(f, out / f.name)
        shutil.rmtree(work, ignore_errors=True)
    return report


def read_report(path: str | Path) -> dict[str, Any]:
    """A ``dryrun.json`` as written by this version (:data:`REPORT_VERSION`).

    Raises:
        InputError: not JSON, another kind of file or another format version (one line).
    """
    from controller.errors import read_stamped_json

    return read_stamped_json(path, REPORT_KIND, {REPORT_VERSION}, strip=False)


def format_report(report: dict[str, Any]) -> str:
    lines = [f"dryrun ({report['where']}): {' '.join(report['exec_start'])}"]
    lines += [f"  swapped {s}" for s in report["swaps"]]
    lines += [f"  [{'ok' if i['ok'] else 'FAIL'}] {i['check']}: {i['detail']}" for i in report["checks"]]
    lines += [f"  note: {n}" for n in report["notes"]]
    if report["error"]:
        lines.append(f"  error: {report['error']}")
    lines.append(f"dryrun: {'all checks passed' if report['ok'] else 'FAILED'}")
    return "\n".join(lines)


# -- the command --------------------------------------------------------------------------------
def add_dryrun_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--seconds", type=float, default=10.0, help="seconds to run after READY, then SIGTERM (10)")
    p.add_argument("--unit", default=str(UNIT), help="the unit file (default: deploy/elegant-stepping-controller.service)")
    p.add_argument("--config", default=None, metavar="FILE",
                   help="the simulated leg's config (TOML, bus on --channel), put in place of the unit's --config "
                        "(default: configs/sim.toml)")
    p.add_argument("--out", default="out/dryrun", help="folder for dryrun.json and the logs (out/dryrun)")
    p.add_argument("--channel", default="vcan0", help="the vcan channel of the simulated leg (vcan0)")
    p.add_argument("--where", choices=("auto", "native", "uml"), default="auto",
                   help="native vcan, User-Mode Linux, or auto: native if vcan can be had, else UML")
    p.add_argument("--quiet", action="store_true", help="only the checklist")


def main_dryrun(args: argparse.Namespace) -> int:
    from hil.profile import current
    from hil.uml.runner import VcanUnavailable, run_in_uml, where

    if not (math.isfinite(args.seconds) and args.seconds > 0):
        from controller.errors import UsageError

        raise UsageError(f"--seconds must be positive, got {args.seconds}")
    try:
        place = where(args.where, args.channel)
    except VcanUnavailable as exc:  # neither vcan here nor User-Mode Linux: this machine lacks it
        from controller.errors import MissingDependency

        raise MissingDependency(str(exc)) from None
    out = Path(args.out).resolve()
    if place == "uml" and not current().uml:
        from hil.dryrun.unitfile import read_unit, time_span_s, value

        unit = read_unit(args.unit)
        budget = 120.0 + args.seconds + sum(time_span_s(value(unit, "Service", k, "90s"))
                                            for k in ("TimeoutStartSec", "TimeoutStopSec"))
        argv = [sys.executable, "-m", "hil.cli", "dryrun", "--seconds", str(args.seconds), "--unit",
                str(Path(args.unit).resolve()), "--out", str(out), "--channel", args.channel, "--where", "native",
                "--quiet"]
        if args.config is not None:
            argv += ["--config", str(Path(args.config).resolve())]
        if not args.quiet:
            print("dryrun: no vcan on this kernel; running inside User-Mode Linux", file=sys.stderr)
        out.mkdir(parents=True, exist_ok=True)
        (out / "dryrun.json").unlink(missing_ok=True)
        result = run_in_uml(argv, timeout_s=budget, capture=True)
        path = out / "dryrun.json"
        if not path.exists():
            print(f"elegant-stepping dryrun: no report from inside User-Mode Linux (exit {result.returncode}):\n"
                  f"{(result.stdout or '')[-3000:]}", file=sys.stderr)
            return 1
        report = read_report(path)
        report["where"] = "uml"
    else:
        report = run_dryrun(unit=args.unit, config=args.config, seconds=args.seconds, out=out,
                            channel=args.channel, quiet=args.quiet)
    print(format_report(report))
    return 0 if report["ok"] else 1


__all__ = ["Deployment", "run_dryrun", "main_dryrun", "add_dryrun_args", "checklist", "swap_config",
           "program_argv", "final_record", "format_report", "read_report", "REPORT_KIND", "REPORT_VERSION"]
