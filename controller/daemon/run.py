"""The ``controller`` process: the controller daemon at its fixed rate on a real CAN bus.

:class:`controller.loop.ControlLoop` ticks on the monotonic clock, paced by
:class:`controller.daemon.pacing.Pacer` (missed periods are skipped, never bunched). Everything it knows
comes from the bus. With ``records``, it writes its own records as JSON lines: first a ``format`` line (the stamp of
:mod:`controller.errors`: ``{"kind": "format", "format": "controller-records", "format_version": 1,
"project_version": ...}``), then ``clock``, ``phase``
(every phase change), ``command`` (every command from the control socket, accepted or refused),
``step`` (each step cycle once complete: gated range, cell, burst change asked for, burst length,
swing), ``reflex`` (each reflex, with the weights' L1 norm after it), ``weights`` (a file set aside)
and a ``final`` line at exit (loop counters, pacing, frames, weights). Times are the monotonic
clock of this machine (or VM), the clock the firmware-sim process stamps its ground truth with.
With ``records_max_bytes`` the records and the ticks file rotate (:mod:`controller.daemon.rotate`:
``FILE`` the newest, ``FILE.1`` ... ``FILE.<records_keep>`` older ones, each beginning with the format
line and the clock; a restarted daemon rotates the previous run's file instead of overwriting it).
:func:`read_records` reads one such file back: it checks the format line (a file without one, from
before the stamp, is version 0 and read the same way), refuses an unknown version
(:class:`~controller.errors.InputError`) and a damaged line (by its line number), and drops a torn
last line (a kill while writing) with a warning.

The lifecycle: the daemon opens its bus and its control socket and waits for its nodes
(WAIT_NODES); once every node is heard it is **inactive** (INACTIVE, axes IDLE) and tells systemd
READY. It arms only when a person asks (``elegant-stepping-leg arm``, through the control socket,
:mod:`controller.daemon.control`), or by itself with ``auto_arm`` (the simulated leg). With a
configuration file (``deploy``), ``ControlLoop.arm_blocked`` is its
:meth:`~controller.settings.file.DeployConfig.armable_reason` (a calibration nobody confirmed is
never armed). Commands from the control socket are queued by its threads and executed here, by
this loop's thread, at the start of a tick, before :meth:`ControlLoop.tick`.

With ``weights``, learning resumes across restarts, and weights are never destroyed:

- at start the weights' folder must be writable (else the daemon refuses to start: exit 3);
- :func:`controller.stepping.weights.resume_weights` loads the first good generation (the file,
  ``.prev``, ``.prev2``, ...: ``weights_generations`` in all); a file that is intact but does not fit
  this configuration (another shape or cell width) is renamed aside to
  ``FILE.incompatible-<UTC timestamp>``, logged at ERROR and listed in the final record
  (``weights_set_aside``); with no good generation the run starts from zeros;
- the weights are saved while walking (:class:`controller.daemon.autosave.WeightAutosave`, every
  ``save_every_s`` seconds of walking, when they changed, off the loop's thread) and at exit, but
  only if they differ from what the run started from: a run that never learned (never walked)
  writes nothing, so the file stays byte-identical, and zeros are never written over anything;
- each save keeps ``weights_generations`` good files, rotated atomically.

Stopping: SIGTERM, SIGINT, SIGHUP and SIGUSR1 all stop it the same way, in order: STOPPING to
systemd, every axis sent Set_Axis_State(IDLE) (three times), the control socket closed (and its
file removed), the remaining records, the weights saved (if they changed), the final record, exit
0. SIGHUP does **not** reload the configuration: a configuration change needs a restart, on
purpose (the calibration, the limits and the bus are read once, at start, and checked then). A
second signal while the stop runs changes nothing (it is counted in ``final["signals"]``). The
``final`` record says why it stopped (``stopped_by``: ``"SIGTERM"``, ``"SIGINT"``, ``"SIGHUP"``,
``"SIGUSR1"``, ``"duration"`` or ``"event"``), where the weights came from (``weights_source``:
``"file"``, ``"prev"``, ``"prev2"``, ..., ``"zeros"``, or None without ``weights``), how many saves
succeeded and whether the last one did (``weights_saved``: True, False, or None when there was
nothing to write).

Failures at start, each one line and nothing left running (:mod:`controller.errors`): a bus that
cannot be opened is a :class:`~controller.errors.BusError` (exit 4: :func:`controller.daemon.openbus.open_bus`,
naming the interface, the channel and the system's reason); a weights folder that is not writable,
a weights file that cannot be set aside, a control socket that cannot be made
(:class:`~controller.daemon.control.ControlSocketError`), a records or ticks file that cannot be
written are a :class:`StartError`, an :class:`~controller.errors.InputError` (exit 3). The daemon
never exits by itself because the leg stopped (a latched FAULT keeps the loop running and the axes
IDLE, waiting for a person); only ``duration_s`` can end a run in FAULT, which the command line
reports as a safety stop (exit 5, :mod:`controller.cli.run`).

The tick clock and the sleep between ticks are ``clock`` and ``sleep`` (default the monotonic clock
and ``time.sleep``): a test runs the daemon in lockstep with a simulated leg by stepping the leg
inside ``sleep``, so what it asserts about time is simulated time.

Under systemd (``Type=notify``, ``$NOTIFY_SOCKET`` set) it tells the service manager READY once
inactive and healthy, its STATUS (lifecycle and phase) on each phase change, WATCHDOG pings from
this loop (every half of ``$WATCHDOG_USEC``, FAULT included) and STOPPING when the shutdown begins
(:mod:`controller.daemon.notify`); ``final["sd_notify"]`` counts what it sent. Without
``$NOTIFY_SOCKET`` none of it happens.
"""

from __future__ import annotations

import json
import logging
import math
import os
import signal
import tempfile
import threading
import time
from array import array
from pathlib import Path
from typing import Any

from typing import Callable

import can
import numpy as np

from controller.config import ControllerConfig
from controller.daemon.autosave import AutosaveConfig, WeightAutosave
from controller.daemon.control import ControlServer
from controller.daemon.fastbus import lean
from controller.daemon.notify import DaemonNotify
from controller.daemon.openbus import open_bus
from controller.daemon.pacing import Pacer
from controller.daemon.rotate import RotatingFile
from controller.errors import InputError, check_stamp, stamp
from controller.loop import ControlLoop, StepRecord
from controller.stepping.learner import AdaptivePremotor
from controller.stepping.weights import resume_weights
from controller.supervisor import Phase
from protocol import AxisState

log = logging.getLogger(__name__)

STOP_SIGNALS = (signal.SIGTERM, signal.SIGINT, signal.SIGHUP, signal.SIGUSR1)
"""Every one of them stops the daemon the same way (SIGHUP included: no reload)."""


RECORDS_FORMAT = "controller-records"
"""The ``format`` of the records file's first line (:func:`controller.errors.stamp`)."""
RECORDS_VERSION = 1
"""The records' format version this daemon writes: 1 since the format line; 0 is a file without it."""
RECORDS_VERSIONS = (0, 1)
"""The records' format versions :func:`read_records` reads (0: written before the format line)."""


class StartError(InputError):
    """The daemon refuses to start (one line; exit 3: an input the person must fix, no traceback)."""


def _version() -> str:
    try:
        from importlib.metadata import version

        return version("elegant-stepping")
    except Exception:  # noqa: BLE001 - not installed (a clone on sys.path)
        return "unknown"


def _num(x: float | None) -> float | None:
    return None if x is None or (isinstance(x, float) and math.isnan(x)) else x


def step_dict(s: StepRecord) -> dict[str, Any]:
    return {
        "kind": "step", "index": s.index, "onset_s": s.onset_s, "burst_s": _num(s.burst_s),
        "swing_s": _num(s.swing_s), "swing_start_s": _num(s.swing_start_s), "gated_range_m": s.gated_range_m,
        "cell": s.cell, "modulation_s": s.modulation_s, "amplitude": s.amplitude, "context": s.context,
    }


def records_format_line() -> dict[str, Any]:
    """The first line of every records file: ``{"kind": "format", "format": "controller-records",
    "format_version": 1, "project_version": ...}``."""
    return {"kind": "format", **stamp(RECORDS_FORMAT, RECORDS_VERSION)}


class Records:
    """The records file (JSON lines), rotated within ``max_bytes`` (None: one file, overwritten at
    start). Each new file begins with the format line, the clock line and the current phase.
    ``monotonic``: the clock the records' times are on (the daemon's tick clock)."""

    def __init__(self, path: str | Path | None, max_bytes: int | None = None, keep: int = 3,
                 monotonic: Callable[[], float] = time.monotonic, sim_time: bool = False) -> None:
        self.format = records_format_line()
        self.clock: dict[str, Any] = {"kind": "clock", "realtime_minus_monotonic_s": time.time() - monotonic()}
        if sim_time:  # the records' times are the plant's simulated time: no wall clock to convert to
            self.clock = {"kind": "clock", "clock": "sim", "realtime_minus_monotonic_s": None}
        self.last_phase: dict[str, Any] | None = None
        self.out = None if not path else RotatingFile(path, max_bytes, keep, header=self._header,
                                                      rotate_at_start=True)
        self.steps_written = 0
        self.reflexes_written = 0
        if self.out is not None:
            self.out.write(json.dumps(self.format) + "\n")
        self.write(self.clock)

    @property
    def f(self):
        return None if self.out is None else self.out.f

    def _header(self) -> list[str]:
        return [json.dumps(x) + "\n" for x in (self.format, self.clock, self.last_phase) if x is not None]

    def write(self, obj: dict[str, Any]) -> None:
        if obj.get("kind") == "phase":
            self.last_phase = obj
        if self.out is not None:
            self.out.write(json.dumps(obj) + "\n")

    def flush(self) -> None:
        if self.out is not None:
            self.out.flush()

    def close(self) -> None:
        if self.out is not None:
            self.out.close()
            self.out = None


def weights_of(premotor) -> np.ndarray | None:
    w = getattr(premotor, "weights", None)
    return None if w is None else np.asarray(w, dtype=float)


def check_writable_folder(folder: Path, what: str) -> None:
    """Refuse to start (:class:`StartError`) unless a file can be created in ``folder`` (made if missing)."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(prefix=".write-check.", dir=folder)
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        raise StartError(f"{what} folder {folder} is not writable ({exc.strerror or exc}): the daemon would lose "
                         f"what it learns; fix its permissions or the configuration's path") from None


def _file_age_s(path: Path | None) -> float | None:
    if path is None:
        return None
    try:
        return max(0.0, time.time() - path.stat().st_mtime)
    except OSError:
        return None


def run_controller(bus_kw: dict[str, Any], config: ControllerConfig = ControllerConfig(), *,
                   records: str | Path | None = None, weights: str | Path | None = None,
                   ticks: str | Path | None = None, duration_s: float | None = None,
                   save_every_s: float = AutosaveConfig.every_s, deploy=None,
                   control_socket: str | Path | None = None, control_group: str = "",
                   records_max_bytes: int | None = None, records_keep: int = 3,
                   weights_generations: int = 3, stop_event: threading.Event | None = None,
                   restore_signals: bool = True, clock: Callable[[], float] | None = None,
                   sleep: Callable[[float], None] | None = None, sim_time: bool = False,
                   bursts: str | Path | None = None) -> dict[str, Any]:
    """Run until a stop signal (SIGTERM, SIGINT, SIGHUP, SIGUSR1), ``duration_s`` or ``stop_event``.

    ``ticks``: write, for every tick, its clock and the number of frames it read from the bus
    (pairs of float64, native byte order; the count is -1 on a bus that does not count), so
    ``replay`` can tick as the live loop did. ``weights``: resume from and save to this file (see
    the module docstring), ``weights_generations`` good files kept; ``save_every_s``: seconds of
    walking between periodic saves. ``deploy``: the configuration file's
    :class:`~controller.settings.file.DeployConfig` (its ``armable_reason`` blocks arming).
    ``control_socket``: the control socket's path (None: none), ``control_group`` its group.
    ``records_max_bytes``/``records_keep``: rotation of ``records`` and ``ticks`` (None: none).
    Signal handlers are installed only on the main thread (elsewhere stop with ``stop_event`` or
    ``duration_s``); ``restore_signals=False`` leaves them in place after the return, so a late
    signal still changes nothing (the command line's ``run``). ``clock``/``sleep``: the tick clock
    and the sleep between ticks and between the stop's IDLE frames (default ``time.monotonic`` and
    ``time.sleep``; a test steps a simulated leg inside ``sleep``). ``bursts``: write, for every
    tick, its clock and the CPG's burst length after it [s] (pairs of float64, native byte order,
    not rotated: for figures of a session, ``hil --clock sim``'s traces). ``sim_time``: tick on the
    plant's simulated time instead (``--clock sim``, :mod:`controller.daemon.simclock`: once per
    ``ES_Sim_Sync``, with its time as the clock, answered with ``ES_End_Of_Period``; never on a
    real leg); ``duration_s`` then counts simulated seconds from the first tick.
    Raises :class:`StartError` (an :class:`~controller.errors.InputError`, nothing started) when
    the weights' folder is not writable, the control socket cannot be made, the weights cannot be
    set aside, or the records or ticks file cannot be written; :class:`controller.errors.BusError`
    when the bus cannot be opened."""
    clock = time.monotonic if clock is None else clock
    sleep = time.sleep if sleep is None else sleep
    t_start = time.time()
    stop: dict[str, Any] = {"flag": False, "by": "duration", "signals": []}

    def on_signal(signum, frame):  # noqa: ARG001 - no logging here: only flags
        name = signal.Signals(signum).name
        stop["signals"].append(name)
        if not stop["flag"]:
            stop["flag"] = True
            stop["by"] = name

    autosave_config = AutosaveConfig(every_s=save_every_s)
    premotor = None
    resumed = None
    source = None
    initial = None
    if weights is not None:
        weights = Path(weights)
        check_writable_folder(weights.parent, "the weights'")
        try:
            resumed = resume_weights(weights, config.encoder.n_cells, config.encoder.cell_width_m,
                                     generations=weights_generations)
        except ValueError as exc:
            raise StartError(str(exc)) from None
        initial, source = resumed.weights, resumed.source
        log.info("weights: resuming from %s (failures were logged by controller.stepping.weights)",
                 resumed.path if resumed.path is not None else "zeros")
        premotor = AdaptivePremotor(config.encoder.n_cells, config.cpg.burst_s, config.learner, weights=initial)

    server = None
    if control_socket:
        server = ControlServer(control_socket, control_group)
        try:
            server.start()
        except ValueError as exc:
            raise StartError(str(exc)) from None

    main_thread = threading.current_thread() is threading.main_thread()
    previous_handlers = {s: signal.signal(s, on_signal) for s in STOP_SIGNALS} if main_thread else {}

    def give_back() -> None:
        if restore_signals:
            for s, handler in previous_handlers.items():
                signal.signal(s, handler)

    try:
        raw_bus = open_bus(bus_kw)  # controller.errors.BusError (one line) when it cannot be opened
    except BaseException:
        give_back()
        if server is not None:
            server.close()
        raise
    bus = lean(raw_bus, timestamps=False)
    sim_clock = None
    if sim_time:
        from controller.daemon.simclock import SimClockBus

        sim_clock = bus = SimClockBus(bus)
    loop = ControlLoop(config, bus, premotor)
    if deploy is not None:
        loop.drivers_watchdog_timeout_s = deploy.drivers.watchdog_timeout_s  # written through RxSdo at arming
        loop.arm_blocked = deploy.armable_reason()
        if loop.arm_blocked:
            log.warning("arming blocked: %s", loop.arm_blocked)
    # bus errors and bus-off: BusIO closes the bus and opens a new one with backoff
    loop.io.reopen = lambda: lean(can.Bus(**bus_kw), timestamps=False)
    if sim_clock is not None:  # a bus reopened in simulated time is read through a clock of its own
        loop.io.reopen = lambda: SimClockBus(lean(can.Bus(**bus_kw), timestamps=False))
    autosave = None if weights is None else WeightAutosave(weights, config.encoder.cell_width_m, autosave_config,
                                                           saved=initial, generations=weights_generations)
    rec = tick_file = burst_file = None
    try:
        what = records
        rec = Records(records, records_max_bytes, records_keep, monotonic=clock, sim_time=sim_time)
        what = ticks
        tick_file = None if not ticks else RotatingFile(ticks, records_max_bytes, records_keep, binary=True,
                                                        rotate_at_start=True)
        what = bursts
        burst_file = None if not bursts else open(bursts, "wb")
    except BaseException as exc:
        give_back()
        if tick_file is not None:
            tick_file.close()
        if rec is not None:
            rec.close()
        if server is not None:
            server.close()
        raw_bus.shutdown()
        if isinstance(exc, OSError):
            raise StartError(f"cannot write {what}: {exc.strerror or exc} (check --records/--ticks and the folder's "
                             f"permissions)") from None
        raise
    for old, moved, why in ([] if resumed is None else resumed.set_aside):
        rec.write({"kind": "weights", "event": "set_aside", "file": old, "moved_to": moved, "reason": why})
    pacer = Pacer(config.period_s, catch_up=False, late_factor=config.late_factor, clock=clock, sleep=sleep)
    notify = DaemonNotify()  # systemd's READY/WATCHDOG/STATUS/STOPPING; a no-op without NOTIFY_SOCKET
    phase = None
    stats = loop.stats
    flush_every = max(1, int(round(0.1 * config.rate_hz)))
    tick_buf = array("d")
    burst_buf = array("d")
    received = loop.io.received  # frames read by the loop, across bus reopens
    version = _version()
    tick_now = {"now": math.nan}
    commands: list[dict[str, Any]] = []

    def daemon_status() -> dict[str, Any]:
        st = loop.status()
        st.update({
            "version": version, "pid": os.getpid(), "uptime_s": time.time() - t_start, "bus": dict(bus_kw),
            "rate_hz": config.rate_hz, "pacing": {"ticks": pacer.ticks, "late_ticks": pacer.late_ticks,
                                                  "skipped": pacer.skipped,
                                                  "max_period_us": pacer.max_period_s * 1e6},
            "weights": None if weights is None else {
                "file": str(weights), "source": source, "loaded_from": None if resumed.path is None else str(resumed.path),
                "age_s": _file_age_s(Path(weights)), "saves": autosave.saves, "failures": autosave.failures,
                "set_aside": [m for _, m, _ in resumed.set_aside]},
            "records": None if records is None else str(records),
        })
        return st

    def execute(verb: str) -> tuple[str | None, dict[str, Any]]:
        now = tick_now["now"]
        refused = None
        if verb == "arm":
            refused = loop.request_arm(now)
        elif verb == "disarm":
            refused = loop.request_disarm(now)
        elif verb == "estop":
            refused = loop.request_estop(now)
        elif verb == "clear-faults":
            refused = loop.request_clear_faults(now)
        if verb != "status":
            rec.write({"kind": "command", "verb": verb, "t_s": now, "accepted": refused is None, "refused": refused})
            commands.append({"verb": verb, "t_s": now, "refused": refused})
            (log.info if refused is None else log.warning)("command %s: %s", verb,
                                                           "accepted" if refused is None else f"refused: {refused}")
        return refused, daemon_status()

    t0 = pacer.start()
    t_end = math.inf if duration_s is None else t0 + duration_s
    log.info("controller %s on %s at %.0f Hz%s%s", version, bus_kw, config.rate_hz,
             "" if server is None else f", control socket {server.path}",
             ", on the plant's simulated time" if sim_clock is not None else "")
    sync = None
    no_sync_since = clock()
    try:
        while not stop["flag"]:
            if sim_clock is not None:
                if sync is not None:
                    sim_clock.end_period(sync, loop.phase.value)  # the tick's records are written
                    sync = None
                sync = sim_clock.wait_sync(0.1)  # short waits: a stop signal is seen within 0.1 s
                if sync is None:
                    if clock() - no_sync_since > 5.0:
                        log.warning("no sync from the plant for %.0f s", clock() - no_sync_since)
                        no_sync_since = clock()
                    if stop_event is not None and stop_event.is_set():
                        stop["by"] = "event"
                        break
                    continue
                no_sync_since = clock()
                now = sync.t_s
                if now <= 0.0:  # the opening sync: answered, no tick (no time has passed)
                    continue
                if duration_s is not None and math.isinf(t_end):
                    t_end = now + duration_s
            else:
                now = pacer.wait()
            if now >= t_end:
                break
            if stop_event is not None and stop_event.is_set():
                stop["by"] = "event"
                break
            if server is not None:
                tick_now["now"] = now
                server.run_pending(execute)  # the operator's commands, on this thread, before the tick
            loop.tick(now)
            notify.tick(now)  # WATCHDOG=1 when due: from this loop only, so a stuck loop stops pinging
            if autosave is not None:
                autosave.tick(now, loop.phase is Phase.WALK, weights_of(loop.premotor))
            if tick_file is not None:
                got = loop.io.received
                tick_buf.append(now)
                tick_buf.append(float(got - received))
                received = got
                if len(tick_buf) >= 512:
                    tick_file.write_array(tick_buf)
                    del tick_buf[:]
            if burst_file is not None:
                burst_buf.append(now)
                burst_buf.append(loop.cpg.burst_s)
                if len(burst_buf) >= 512:
                    burst_buf.tofile(burst_file)
                    del burst_buf[:]
            if loop.phase is not phase:
                phase = loop.phase
                notify.phase(phase, loop.supervisor.fault_cause)
                rec.write({"kind": "phase", "phase": phase.value, "lifecycle": loop.lifecycle, "t_s": now,
                           "fault_cause": loop.supervisor.fault_cause or None})
                rec.flush()
            steps = stats.steps
            while rec.steps_written < len(steps) - 1:  # the last one is still being lived
                rec.write(step_dict(steps[rec.steps_written]))
                rec.steps_written += 1
            reflexes = stats.reflexes
            if rec.reflexes_written < len(reflexes):
                w = weights_of(loop.premotor)
                while rec.reflexes_written < len(reflexes):
                    r = reflexes[rec.reflexes_written]
                    rec.write({"kind": "reflex", "reflex": r.kind, "t_s": r.t_s, "cause": r.cause, "swing": r.swing,
                               "phase": r.phase, "weights_l1": None if w is None else float(np.abs(w).sum())})
                    rec.reflexes_written += 1
            if stats.ticks % flush_every == 0:
                rec.flush()
    finally:
        notify.stopping(stop["by"])
        # A clean stop: the axes go to IDLE on our word, not on their watchdogs.
        for _ in range(3):
            for a in loop.axes:
                try:
                    loop.io.bus.send(a.state_frame(AxisState.IDLE))  # the bus in use (maybe reopened)
                except can.CanError:
                    pass
            sleep(0.01)
        if server is not None:
            server.close()  # no command runs after the axes were sent IDLE
        if tick_file is not None:
            tick_file.write_array(tick_buf)
            tick_file.close()
        if burst_file is not None:
            burst_buf.tofile(burst_file)
            burst_file.close()
        for s in stats.steps[rec.steps_written:]:
            rec.write(step_dict(s))
        w = weights_of(loop.premotor)
        saved = None if autosave is None else autosave.close(w)
        if autosave is not None and autosave.unchanged and autosave.saves == 0:
            saved = None  # nothing learned: nothing written, the file untouched
        if len(stop["signals"]) > 1:
            log.info("stop: %d more signal(s) during the stop (%s), ignored", len(stop["signals"]) - 1,
                     ", ".join(stop["signals"][1:]))
        final = {
            "kind": "final",
            "phase": loop.phase.value,
            "lifecycle": loop.lifecycle,
            "fault_cause": loop.supervisor.fault_cause or None,
            "ticks": stats.ticks,
            "command_ticks": stats.command_ticks,
            "late_ticks": stats.late_ticks,
            "max_period_us": stats.max_period_s * 1e6,
            "pacing": pacer.summary(),
            "cpu_s": sum(os.times()[:2]),
            "steps": len(stats.steps),
            "reflexes": len(stats.reflexes),
            "frames_tx": dict(sorted(loop.io.tx.items())),
            "frames_rx": dict(sorted(loop.io.rx.items())),
            "frames_dropped": dict(sorted(loop.io.dropped.items())),
            "bus_events": dict(sorted(loop.io.bus_events.items())),
            "weights": None if w is None else w.tolist(),
            "stopped_by": stop["by"],
            "signals": list(stop["signals"]),
            "commands": commands,
            "control": None if server is None else server.summary(),
            "weights_source": source,
            "weights_saves": None if autosave is None else autosave.saves,
            "weights_saved": saved,
            "weights_unchanged": None if autosave is None else autosave.unchanged,
            "weights_set_aside": None if resumed is None else [
                {"file": old, "moved_to": moved, "reason": why} for old, moved, why in resumed.set_aside],
            "records_rotations": None if rec.out is None else rec.out.rotations,
            "sd_notify": notify.summary(),
        }
        rec.write(final)
        rec.close()
        if loop.io.bus is not bus:
            loop.io.bus.shutdown()
        raw_bus.shutdown()
        notify.close()
        give_back()
    return final


def read_records(path: str | Path, *, live: bool = False) -> dict[str, list[dict[str, Any]]]:
    """The records file at ``path`` (one part: ``FILE`` or a rotated ``FILE.k``), its lines by kind:
    ``{"phase": [...], "step": [...], "reflex": [...], "final": [...], "clock": [...], ...}`` (the four
    first always present, in file order; the format line is checked, not returned).
    A records file begins with its format line or, before it existed (version 0), its clock line.

    The format: a first line ``{"kind": "format", "format": "controller-records", "format_version": 1,
    ...}``; a file without it (written before it existed) is version 0 and read the same way.
    A last line that is not whole JSON (the daemon killed while writing it) is dropped with a
    warning; with ``live`` (a file the running daemon is still writing, polled) it is dropped
    quietly: its end is still to come. Raises :class:`~controller.errors.InputError` naming the
    file for another kind of file or a version this reader does not know, and naming the line for
    a damaged line before the last; ``FileNotFoundError`` when there is no file."""
    path = Path(path)
    out: dict[str, list[dict[str, Any]]] = {"phase": [], "step": [], "reflex": [], "final": []}
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        line_no = path.read_bytes()[: exc.start].count(b"\n") + 1
        raise InputError(f"{path}: line {line_no}: not UTF-8 text: a damaged controller records file") from None
    lines = text.splitlines()
    last = max((i for i, line in enumerate(lines) if line.strip()), default=-1)
    first = True
    for i, line in enumerate(lines):
        if not line.strip():
            continue
        try:
            obj = json.loads(line)
        except (ValueError, RecursionError):
            obj = None
        if not isinstance(obj, dict):
            if i == last:
                (log.debug if live else log.warning)("%s: line %d is not a whole record (%s): dropped", path, i + 1,
                                                     "still being written" if live else "cut short by a kill?")
                continue
            raise InputError(f"{path}: line {i + 1}: not a JSON record ({line[:40]!r}...): a damaged controller "
                             f"records file (the damage starts there)")
        kind = obj.get("kind", "other")
        if first:
            first = False
            if kind != "format" and kind != "clock":  # version 0 began with its clock line
                raise InputError(f"{path}: not a controller records file (line {i + 1} is neither its format line "
                                 f"nor its clock line)")
        if kind == "format":
            check_stamp(obj, RECORDS_FORMAT, RECORDS_VERSIONS, source=str(path))
            continue
        out.setdefault(kind if isinstance(kind, str) else "other", []).append(obj)
    return out


def phases_seen(path: str | Path) -> list[str]:
    """The phases in the records at ``path`` so far (a file the daemon is writing: ``live``); [] without a file."""
    try:
        return [r["phase"] for r in read_records(path, live=True)["phase"]]
    except FileNotFoundError:
        return []


__all__ = ["run_controller", "read_records", "phases_seen", "Phase", "StartError", "STOP_SIGNALS", "RECORDS_FORMAT",
           "RECORDS_VERSION", "RECORDS_VERSIONS"]
