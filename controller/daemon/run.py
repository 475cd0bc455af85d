"""The ``controller`` process: the controller daemon at its fixed rate on a real CAN bus.

:class:`controller.loop.ControlLoop` (unchanged) ticks on the monotonic clock, paced by
:class:`controller.daemon.pacing.Pacer` (missed periods are skipped, never bunched). Everything it knows
comes from the bus. With ``records``, it writes its own records as JSON lines: ``phase``
(every phase change), ``step`` (each step cycle once complete: gated range, cell, burst change
asked for, burst length, swing), ``reflex`` (each reflex, with the weights' L1 norm after it)
and a ``final`` line at exit (loop counters, pacing, frames, weights). Times are the monotonic
clock of this machine (or VM), the clock the firmware-sim process stamps its ground truth with.

With ``weights``, learning resumes across restarts: the weights are loaded at start with
:func:`controller.stepping.weights.load_weights_or_fallback` (the file, else its ``.prev`` copy, else zeros,
each failure logged) into the premotor, saved while walking (:class:`controller.daemon.autosave.WeightAutosave`:
every ``save_every_s`` seconds of walking, when they changed, off the loop's thread) and at exit.

SIGTERM or SIGINT stops it cleanly, in order: every axis is sent Set_Axis_State(IDLE), then, with
``weights``, the learned weights are saved, then the records are closed. The ``final`` record
says why it stopped (``stopped_by``: ``"SIGTERM"``, ``"SIGINT"`` or ``"duration"``), where the
weights came from (``weights_source``: ``"file"``, ``"prev"``, ``"zeros"``, or None without
``weights``), how many saves succeeded and whether the last one did (``weights_saved``).

Under systemd (``Type=notify``, ``$NOTIFY_SOCKET`` set) it tells the service manager READY once the
axes are in closed loop (RAMP), its STATUS on each phase change, WATCHDOG pings from this loop
(every half of ``$WATCHDOG_USEC``, FAULT included) and STOPPING when the shutdown begins
(:mod:`controller.daemon.notify`); ``final["sd_notify"]`` counts what it sent. Without
``$NOTIFY_SOCKET`` none of it happens.
"""

from __future__ import annotations

import json
import logging
from array import array
import math
import os
import signal
import time
from pathlib import Path
from typing import Any, TextIO

import can
import numpy as np

from controller.config import ControllerConfig
from controller.stepping.learner import AdaptivePremotor
from controller.loop import ControlLoop, StepRecord
from controller.supervisor import Phase
from controller.stepping.weights import load_weights_or_fallback
from controller.daemon.autosave import AutosaveConfig, WeightAutosave
from controller.daemon.notify import DaemonNotify
from controller.daemon.fastbus import lean
from controller.daemon.pacing import Pacer
from protocol import AxisState

log = logging.getLogger(__name__)


def _num(x: float | None) -> float | None:
    return None if x is None or (isinstance(x, float) and math.isnan(x)) else x


def step_dict(s: StepRecord) -> dict[str, Any]:
    return {
        "kind": "step", "index": s.index, "onset_s": s.onset_s, "burst_s": _num(s.burst_s),
        "swing_s": _num(s.swing_s), "swing_start_s": _num(s.swing_start_s), "gated_range_m": s.gated_range_m,
        "cell": s.cell, "modulation_s": s.modulation_s, "amplitude": s.amplitude, "context": s.context,
    }


class Records:
    def __init__(self, path: str | Path | None) -> None:
        self.f: TextIO | None = open(path, "w", buffering=1 << 16) if path else None
        self.steps_written = 0
        self.reflexes_written = 0

    def write(self, obj: dict[str, Any]) -> None:
        if self.f is not None:
            self.f.write(json.dumps(obj) + "\n")

    def flush(self) -> None:
        if self.f is not None:
            self.f.flush()

    def close(self) -> None:
        if self.f is not None:
            self.f.close()
            self.f = None


def weights_of(premotor) -> np.ndarray | None:
    w = getattr(premotor, "weights", None)
    return None if w is None else np.asarray(w, dtype=float)


def run_controller(bus_kw: dict[str, Any], config: ControllerConfig = ControllerConfig(), *,
                   records: str | Path | None = None, weights: str | Path | None = None,
                   ticks: str | Path | None = None, duration_s: float | None = None,
                   save_every_s: float = AutosaveConfig.every_s) -> dict[str, Any]:
    """Run until SIGTERM/SIGINT or ``duration_s``. ``ticks``: write, for every tick, its clock and
    the number of frames it read from the bus (pairs of float64, native byte order; the count is
    -1 on a bus that does not count), so ``replay`` can tick as the live loop did. ``weights``:
    resume from and save to this file (see the module docstring); ``save_every_s``: seconds of
    walking between periodic saves."""
    stop: dict[str, Any] = {"flag": False, "by": "duration"}

    def on_signal(signum, frame):  # noqa: ARG001
        stop["flag"] = True
        stop["by"] = signal.Signals(signum).name

    autosave_config = AutosaveConfig(every_s=save_every_s)
    premotor = None
    source = None
    if weights is not None:
        initial, source = load_weights_or_fallback(weights, config.encoder.n_cells, config.encoder.cell_width_m)
        where = {"file": str(weights), "prev": f"{weights}.prev", "zeros": "zeros"}[source]
        log.info("weights: resuming from %s (failures were logged by controller.stepping.weights)", where)
        premotor = AdaptivePremotor(config.encoder.n_cells, config.cpg.burst_s, config.learner, weights=initial)

    previous_handlers = {s: signal.signal(s, on_signal) for s in (signal.SIGTERM, signal.SIGINT)}
    try:
        raw_bus = can.Bus(**bus_kw)
    except BaseException:
        for s, handler in previous_handlers.items():
            signal.signal(s, handler)
        raise
    bus = lean(raw_bus, timestamps=False)
    loop = ControlLoop(config, bus, premotor)
    # bus errors and bus-off: BusIO closes the bus and opens a new one with backoff
    loop.io.reopen = lambda: lean(can.Bus(**bus_kw), timestamps=False)
    autosave = None if weights is None else WeightAutosave(weights, config.encoder.cell_width_m, autosave_config,
                                                           saved=initial if source == "file" else None)
    rec = Records(records)
    pacer = Pacer(config.period_s, catch_up=False, late_factor=config.late_factor)
    notify = DaemonNotify()  # systemd's READY/WATCHDOG/STATUS/STOPPING; a no-op without NOTIFY_SOCKET
    phase = None
    stats = loop.stats
    flush_every = max(1, int(round(0.1 * config.rate_hz)))
    rec.write({"kind": "clock", "realtime_minus_monotonic_s": time.time() - time.monotonic()})
    tick_file = open(ticks, "wb") if ticks else None
    tick_buf = array("d")
    received = loop.io.received  # frames read by the loop, across bus reopens
    t0 = pacer.start()
    t_end = math.inf if duration_s is None else t0 + duration_s
    log.info("controller on %s at %.0f Hz", bus_kw, config.rate_hz)
    try:
        while not stop["flag"]:
            now = pacer.wait()
            if now >= t_end:
                break
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
                    tick_buf.tofile(tick_file)
                    del tick_buf[:]
            if loop.phase is not phase:
                phase = loop.phase
                notify.phase(phase, loop.supervisor.fault_cause)
                rec.write({"kind": "phase", "phase": phase.value, "t_s": now,
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
            time.sleep(0.01)
        if tick_file is not None:
            tick_buf.tofile(tick_file)
            tick_file.close()
        for s in stats.steps[rec.steps_written:]:
            rec.write(step_dict(s))
        w = weights_of(loop.premotor)
        saved = None if autosave is None else autosave.close(w)
        final = {
            "kind": "final",
            "phase": loop.phase.value,
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
            "weights_source": source,
            "weights_saves": None if autosave is None else autosave.saves,
            "weights_saved": saved,
            "sd_notify": notify.summary(),
        }
        rec.write(final)
        rec.close()
        if loop.io.bus is not bus:
            loop.io.bus.shutdown()
        raw_bus.shutdown()
        notify.close()
        for s, handler in previous_handlers.items():
            signal.signal(s, handler)
    return final


def read_records(path: str | Path) -> dict[str, list[dict[str, Any]]]:
    out: dict[str, list[dict[str, Any]]] = {"phase": [], "step": [], "reflex": [], "final": []}
    for line in Path(path).read_text().splitlines():
        if not line.strip():
            continue
        try:
            obj = json.loads(line)
        except ValueError:
            continue  # a line cut short by a kill
        out.setdefault(obj.get("kind", "other"), []).append(obj)
    return out


def phases_seen(path: str | Path) -> list[str]:
    try:
        return [r["phase"] for r in read_records(path)["phase"]]
    except FileNotFoundError:
        return []


__all__ = ["run_controller", "read_records", "phases_seen", "Phase"]
