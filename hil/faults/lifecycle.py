"""The fault matrix's lifecycle rows: what a leg that a person arms must refuse, and must keep.

Each row starts what it needs and returns a row of the matrix (``fault``, ``where``,
``commands_outside_limits``, ``data_lost`` and its own figures):

- ``estop_latched_at_start``, ``driver_error_latched_at_start``: the simulated drivers hold a
  latched ESTOP_REQUESTED (both) or a gate-driver fault, DRV_FAULT (the knee) before the controller starts
  (lockstep, ``auto_arm`` on): the controller must never arm, never send Clear_Errors, and say
  why (``refused``).
- ``second_master``: while walking (lockstep), a third node sends Set_Input_Pos to the hip, one
  frame a millisecond for 1.5 s: the controller must fault in the tick that drains the first one
  (``ticks_to_fault``), and every axis be IDLE (``safe_state_ms``, ground truth).
- ``restart_without_walking``: the daemon (:mod:`hil.faults.daemonleg`: the real daemon and the
  simulated leg in one process) started twice on a weights file and stopped without being armed:
  every weights file byte for byte as before (``files_unchanged``).
- ``weights_incompatible``: the daemon started on a file of another cell width: the file is kept
  aside, byte for byte (``set_aside``), and nothing is written in its place.
- ``over_temperature``, ``bus_undervoltage``: while walking (lockstep), the hip's motor winding
  starts to dissipate 150 W without current (a winding fault: the simulated motor heats toward
  325 C, :mod:`firmware_sim.thermal`), or both drivers' supply drops from 24 V to 15 V (a
  battery giving out): the controller must stop the leg on the drivers' cyclic readings
  (:mod:`controller.io.health`), a latched FAULT naming the reading and the bound
  (``safe_state_ms``: from the bound crossed, ground truth, to every axis IDLE).
- ``sighup``, ``sigusr1``: the daemon walking the simulated leg (``auto_arm``) gets the signal:
  exit 0, every axis IDLE on the daemon's word (no watchdog trip), the weights file intact
  (``stop_ms``: from the signal to the exit).

``data_lost`` is true when a weights file that should have been kept is gone or changed.

Each finished row is kept in ``OUT/NAME/row.json``, stamped ``format: "fault-row"``,
``format_version`` :data:`ROW_VERSION` (:func:`controller.errors.stamp`), and read back instead
of running the row again (:func:`read_row`: a file from before stamps is version 0, accepted;
another kind or version is refused in one line). The stamp is the file's, not the row's.
"""

from __future__ import annotations

import hashlib
import json
import os
import signal
import subprocess
import sys
import time
import uuid
from pathlib import Path
from typing import Any, Callable

import numpy as np

from controller.config import ControllerConfig
from hil.faults.audit import CommandAudit

ROW_KIND = "fault-row"
ROW_VERSION = 1  # row.json's format version: raise it when a reader of the old one could misread it
SECONDS_AT_START = 3.0  # how long the latched-at-start rows let the controller try [s]
FOREIGN_FRAMES = 1500  # the second master's frames, one per physics step


class _Tap:
    """The controller's bus, with every frame it sends shown to ``on_send`` first."""

    def __init__(self, bus, on_send: Callable) -> None:
        self._bus = bus
        self._on_send = on_send

    def send(self, msg, timeout=None):
        self._on_send(msg)
        return self._bus.send(msg, timeout)

    def __getattr__(self, name: str):
        return getattr(self._bus, name)


def _lockstep(seed: int = 0):
    """A lockstep session whose controller's frames are audited and counted by command."""
    from hil.lockstep.harness import Lockstep, LockstepConfig
    from protocol import BusContract, split_arbitration_id

    ls = Lockstep(LockstepConfig(seed=seed))
    audit = CommandAudit.from_config(ls.loop.config)
    contract = BusContract.load()
    names = {c.cmd_id: c.name for c in contract.odrive.values()}
    sent: dict[str, int] = {}

    def on_send(msg) -> None:
        audit(msg)
        name = names.get(split_arbitration_id(msg.arbitration_id)[1], hex(msg.arbitration_id))
        sent[name] = sent.get(name, 0) + 1

    ls.loop.io.bus = _Tap(ls.loop.io.bus, on_send)
    return ls, audit, sent


def _row(fault: str, where: str, **figures: Any) -> dict[str, Any]:
    return {"fault": fault, "rate": None, "direction": None, "node": None, "seed": 0, "where": where,
            "safe_state_ms": None, "heartbeat_idle_ms": None, "success_last_50": None, **figures}


def latched_at_start(fault: str, error_name: str, axes: tuple[str, ...]) -> dict[str, Any]:
    """A driver error latched before the controller starts: it must never arm."""
    from protocol import AxisError, AxisState

    ls, audit, sent = _lockstep()
    try:
        for name in axes:
            ls.leg.axes[name].latch_error(AxisError[error_name])
        armed = False
        while ls.t_s < SECONDS_AT_START:
            ls.step()
            armed |= any(a.state is AxisState.CLOSED_LOOP_CONTROL for a in ls.leg.axes.values())
        refused = ls.loop.request_arm(ls.t_s)
        return _row(fault, "lockstep", armed=armed, phase=ls.loop.phase.value, refused=refused,
                    clear_errors_sent=sent.get("Clear_Errors", 0), frames_sent=sent,
                    commands_outside_limits=audit.outside, data_lost=False,
                    fault_cause=f"never armed: {refused}" if not armed else "ARMED")
    finally:
        ls.close()


def second_master(seed: int = 0) -> dict[str, Any]:
    """Another master commands the hip while the leg walks: a latched fault in one tick."""
    import can

    from controller.supervisor import Phase
    from protocol import BusContract

    ls, audit, _ = _lockstep(seed)
    try:
        while ls.loop.phase is not Phase.WALK and ls.t_s < 10.0:
            ls.step()
        walk_t = ls.t_s
        while ls.t_s < walk_t + 1.0:
            ls.step()
        contract = BusContract.load()
        hip = next(a for a in ls.loop.config.axes if a.name == "hip")
        foreign = can.Message(arbitration_id=contract.odrive_id(hip.node_id, "Set_Input_Pos"), is_extended_id=False,
                              data=contract.codec("Set_Input_Pos").pack(0.9, 0.0, 0.0))
        other = ls.observer()
        t0, ticks, ticks_to_fault, safe_ms = ls.t_s, 0, None, None
        for _ in range(FOREIGN_FRAMES):
            other.send(foreign)
            while other.recv(0) is not None:  # the observer hears everything: keep its queue short
                pass
            ticked = ls.step()
            ticks += ticked
            if ticks_to_fault is None and ls.loop.phase is Phase.FAULT:
                ticks_to_fault = ticks
            if safe_ms is None and ls.axes_idle():
                safe_ms = (ls.t_s - t0) * 1e3
        other.shutdown()
        cause = ls.loop.supervisor.fault_cause
        return _row("second_master", "lockstep", foreign_frames=FOREIGN_FRAMES, ticks_to_fault=ticks_to_fault,
                    safe_state_ms=safe_ms, fault_cause=f"{cause}: latched fault in tick {ticks_to_fault} after the "
                                                       f"first foreign frame ({FOREIGN_FRAMES} sent)",
                    commands_outside_limits=audit.outside, data_lost=False)
    finally:
        ls.close()


WINDING_FAULT_W = 150.0  # over_temperature: the hip winding's loss without current [W]
SAGGED_SUPPLY_V = 15.0  # bus_undervoltage: the supply's voltage after it drops [V]
HEALTH_ROW_MAX_S = 120.0  # simulated time a health row waits for the bound and the stop [s]


def health_row(fault: str, seed: int = 0) -> dict[str, Any]:
    """A driver reading beyond its bound while walking: a latched fault, every axis IDLE."""
    from controller.supervisor import Phase

    ls, audit, _ = _lockstep(seed)
    try:
        bounds = ls.loop.config.health
        while ls.loop.phase is not Phase.WALK and ls.t_s < 10.0:
            ls.step()
        walk_t = ls.t_s
        while ls.t_s < walk_t + 1.0:
            ls.step()
        thermals = [a.thermal for a in ls.leg.axes.values()]
        if fault == "over_temperature":
            hot = ls.leg.axes["hip"].thermal
            hot.extra_motor_loss_w = WINDING_FAULT_W
            crossed = lambda: hot.motor_c > bounds.max_motor_temp_c  # noqa: E731
            condition = f"hip winding dissipating {WINDING_FAULT_W:g} W"
        else:
            for th in thermals:
                th.source_voltage_v = SAGGED_SUPPLY_V
            crossed = lambda: any(th.bus_voltage_v < bounds.min_bus_voltage_v for th in thermals)  # noqa: E731
            condition = f"supply dropped to {SAGGED_SUPPLY_V:g} V"
        t0, t_cross, t_fault, t_idle, ticks, ticks_to_fault = ls.t_s, None, None, None, 0, None
        while ls.t_s < t0 + HEALTH_ROW_MAX_S and t_idle is None:
            ticks += ls.step()
            if t_cross is None and crossed():
                t_cross, ticks = ls.t_s, 0
            if t_fault is None and ls.loop.phase is Phase.FAULT:
                t_fault, ticks_to_fault = ls.t_s, ticks
            if t_fault is not None and ls.axes_idle():
                t_idle = ls.t_s
        cause = ls.loop.supervisor.fault_cause
        safe_ms = None if t_cross is None or t_idle is None else round((t_idle - t_cross) * 1e3, 1)
        detect_ms = None if t_cross is None or t_fault is None else round((t_fault - t_cross) * 1e3, 1)
        return _row(fault, "lockstep", safe_state_ms=safe_ms, detect_ms=detect_ms, ticks_to_fault=ticks_to_fault,
                    read_period_s=bounds.read_period_s,
                    bound_crossed_s=None if t_cross is None else round(t_cross - t0, 3),
                    max_motor_temp_c=round(max(th.motor_c for th in thermals), 2),
                    min_bus_voltage_v=round(min(th.bus_voltage_v for th in thermals), 2),
                    commands_outside_limits=audit.outside, data_lost=False,
                    fault_cause=(f"{condition}: {cause or 'NO FAULT'}; bound crossed "
                                 f"{'never' if t_cross is None else f'{t_cross - t0:.3f} s'} after, every axis "
                                 f"IDLE {'never' if safe_ms is None else f'{safe_ms:g} ms'} after the crossing"))
    finally:
        ls.close()


# -- rows with the daemon --------------------------------------------------------------------
def _sha(path: Path) -> str | None:
    return hashlib.sha256(path.read_bytes()).hexdigest() if path.exists() else None


def _weights_files(path: Path) -> dict[str, str | None]:
    """Every generation of the weights file and any file set aside, by name, with its digest."""
    return {p.name: _sha(p) for p in sorted(path.parent.glob(path.name + "*")) if not p.name.endswith(".tmp")}


def _config(folder: Path, weights: Path, auto_arm: bool) -> Path:
    weights = weights.resolve()  # a relative path in the file would be taken from the file's folder
    path = folder / "leg.toml"
    path.write_text(f'[bus]\ninterface = "virtual"\nchannel = "unused"\n\n[controller]\nauto_arm = '
                    f'{"true" if auto_arm else "false"}\n\n[weights]\npath = "{weights}"\n\n'
                    '[calibration]\nconfirmed = true\nbringup = "the simulated leg (firmware_sim)"\n')
    return path


def _daemon(folder: Path, config: Path, *extra: str) -> subprocess.Popen:
    (folder / "leg.json").unlink(missing_ok=True)  # never an earlier run's report
    channel = f"lifecycle-{uuid.uuid4().hex[:8]}"
    argv = [sys.executable, "-m", "hil.faults.daemonleg", "--channel", channel, "--leg-report",
            str(folder / "leg.json"), "--", "--config", str(config), "--socket", "none",
            "--records", str(folder / "controller.jsonl"), *extra]
    return subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, stdin=subprocess.DEVNULL)


def _leg(folder: Path) -> dict[str, Any]:
    """What the daemon's process reported of the simulated leg and of the commands it audited."""
    from hil.faults.daemonleg import read_report

    return read_report(folder / "leg.json")


def _outside(folder: Path) -> int | None:
    return _leg(folder).get("commands_outside_limits")


def _final(err: str) -> dict[str, Any]:
    for line in reversed(err.strip().splitlines()):
        if line.startswith("{"):
            try:
                return json.loads(line)
            except json.JSONDecodeError:
                break
    return {}


def _some_weights(config: ControllerConfig, cell_width_m: float | None = None) -> tuple[np.ndarray, float]:
    n = config.encoder.n_cells
    return np.linspace(-0.05, 0.05, n), config.encoder.cell_width_m if cell_width_m is None else cell_width_m


def _fresh_weights(out: Path, cell_width_m: float | None = None) -> tuple[Path, np.ndarray, float]:
    """``out/weights.npz`` written anew (every older generation and set-aside file removed)."""
    from controller.stepping.weights import save_weights

    out.mkdir(parents=True, exist_ok=True)
    weights = out / "weights.npz"
    for p in out.glob("weights.npz*"):
        p.unlink()
    w, width = _some_weights(ControllerConfig(), cell_width_m)
    save_weights(weights, w, width)
    return weights, w, width


def restart_without_walking(out: Path) -> dict[str, Any]:
    from controller.stepping.weights import save_weights

    weights, w, width = _fresh_weights(out)
    save_weights(weights, w * 2, width)  # two generations: the file and .prev
    before = _weights_files(weights)
    config = _config(out, weights, auto_arm=False)
    codes, phases, sources, outside = [], [], [], 0
    for _ in range(2):
        proc = _daemon(out, config, "--seconds", "2")
        _, err = proc.communicate(timeout=120)
        codes.append(proc.returncode)
        final = _final(err)
        phases.append(final.get("phase"))
        sources.append(final.get("weights_source"))
        n = _outside(out)
        outside = None if n is None or outside is None else outside + n
    after = _weights_files(weights)
    unchanged = after == before and sources == ["file", "file"]  # the daemon did read that very file
    return _row("restart_without_walking", "daemon", restarts=2, exit_codes=codes, phases=phases,
                weights_sources=sources,
                files_unchanged=unchanged, files=sorted(after), commands_outside_limits=outside, data_lost=not unchanged,
                fault_cause=f"2 starts from the file (weights read from {sources}), never armed (phases "
                            f"{phases}): every weights file {'byte for byte as before' if unchanged else 'CHANGED'}")


def weights_incompatible(out: Path) -> dict[str, Any]:
    weights, _, _ = _fresh_weights(out, cell_width_m=ControllerConfig().encoder.cell_width_m * 2)
    original = _sha(weights)
    config = _config(out, weights, auto_arm=False)
    proc = _daemon(out, config, "--seconds", "2")
    _, err = proc.communicate(timeout=120)
    final = _final(err)
    aside = sorted(out.glob("weights.npz.incompatible-*"))
    kept = bool(aside) and _sha(aside[-1]) == original
    return _row("weights_incompatible", "daemon", exit_code=proc.returncode, set_aside=aside[-1].name if aside else None,
                weights_source=final.get("weights_source"), reported=final.get("weights_set_aside"),
                set_aside_intact=kept, written_in_its_place=weights.exists(), commands_outside_limits=_outside(out),
                data_lost=not kept, fault_cause=(f"kept aside as {aside[-1].name}, byte for byte" if kept else
                                                 "the incompatible file was NOT kept"))


def stop_signal(out: Path, signum: signal.Signals) -> dict[str, Any]:
    weights, w, width = _fresh_weights(out)
    config = _config(out, weights, auto_arm=True)
    records = out / "controller.jsonl"
    records.unlink(missing_ok=True)
    proc = _daemon(out, config)
    deadline = time.monotonic() + 90
    walking_since = None
    while proc.poll() is None and time.monotonic() < deadline:
        if walking_since is None and records.exists() and '"walk"' in records.read_text():
            walking_since = time.monotonic()
        if walking_since is not None and time.monotonic() - walking_since > 1.0:
            break
        time.sleep(0.05)
    t_signal = time.monotonic()
    if proc.poll() is None:
        os.kill(proc.pid, signum)
    try:
        _, err = proc.communicate(timeout=60)
    except subprocess.TimeoutExpired:
        proc.kill()
        _, err = proc.communicate()
    stop_ms = (time.monotonic() - t_signal) * 1e3
    final = _final(err)
    report = _leg(out)
    leg = report.get("axes", {})
    idle = bool(leg) and all(a["state"] == "IDLE" for a in leg.values())
    trips = sum(a["watchdog_trips"] for a in leg.values()) if leg else None
    try:
        from controller.stepping.weights import load_weights

        load_weights(weights, len(w), width)
        loads = True
    except Exception:  # noqa: BLE001 - any failure to load is data lost
        loads = False
    name = signum.name.lower()
    ok = (proc.returncode == 0 and idle and trips == 0 and final.get("stopped_by") == signum.name
          and final.get("weights_source") == "file")
    return _row(name, "daemon", walked=walking_since is not None, exit_code=proc.returncode,
                weights_source=final.get("weights_source"),
                stopped_by=final.get("stopped_by"), axes_idle=idle, watchdog_trips=trips,
                weights_saved=final.get("weights_saved"), stop_ms=round(stop_ms, 1),
                commands_checked=report.get("commands_checked"), commands_outside_limits=report.get("commands_outside_limits"),
                data_lost=not loads,
                fault_cause=(f"walking, then {signum.name}: exit {proc.returncode}, axes "
                             f"{'IDLE' if idle else 'NOT IDLE'} on the daemon's word ({trips} watchdog trips), "
                             f"weights file {'loads' if loads else 'LOST'}; {stop_ms:.0f} ms to exit"
                             + ("" if ok else " [FAILED]")))


ROWS: dict[str, Callable[[Path], dict[str, Any]]] = {
    "estop_latched_at_start": lambda out: latched_at_start("estop_latched_at_start", "ESTOP_REQUESTED",
                                                           ("hip", "knee")),
    "driver_error_latched_at_start": lambda out: latched_at_start("driver_error_latched_at_start",
                                                                  "DRV_FAULT", ("knee",)),
    "second_master": lambda out: second_master(),
    "over_temperature": lambda out: health_row("over_temperature"),
    "bus_undervoltage": lambda out: health_row("bus_undervoltage"),
    "restart_without_walking": restart_without_walking,
    "weights_incompatible": weights_incompatible,
    "sighup": lambda out: stop_signal(out, signal.SIGHUP),
    "sigusr1": lambda out: stop_signal(out, signal.SIGUSR1),
}
"""Every lifecycle row by name (``faults --only NAME``), the one place one is added."""


def write_row(path: str | Path, row: dict[str, Any]) -> None:
    """``row`` to ``path``, stamped (:data:`ROW_KIND`, :data:`ROW_VERSION`), atomically."""
    from controller.atomic import write_json_atomic
    from controller.errors import stamp

    write_json_atomic(path, {**stamp(ROW_KIND, ROW_VERSION), **row}, indent=1)


def read_row(path: str | Path) -> dict[str, Any]:
    """The row kept at ``path``, without the file's stamp (version 0, unstamped, accepted).

    Raises:
        InputError: not JSON, another kind of file or another format version (one line).
    """
    from controller.errors import read_stamped_json

    return read_stamped_json(path, ROW_KIND, {0, ROW_VERSION})


def run_rows(names: list[str], out_dir: str | Path) -> list[dict[str, Any]]:
    """Run the named rows, each in ``out_dir/NAME/`` (its ``row.json`` read back when there)."""
    rows = []
    for name in names:
        folder = Path(out_dir) / name
        done = folder / "row.json"
        if done.exists():
            rows.append(read_row(done))
            continue
        try:
            row = ROWS[name](folder)
        except Exception as exc:  # noqa: BLE001 - one broken row must not lose the others
            row = _row(name, "lifecycle", error=repr(exc))
        folder.mkdir(parents=True, exist_ok=True)
        if "error" not in row:
            write_row(done, row)
        rows.append(row)
    return rows
