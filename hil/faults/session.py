"""Fault injection in hardware-in-the-loop sessions, and the HIL rows of the fault matrix.

A session with a rate fault or a silence (:class:`FaultPlan`) puts the controller on one channel
(vcan0) and the firmware-sim process on another (vcan1), with the man-in-the-middle node
(:mod:`hil.faults.mitm`) forwarding between them through its per-direction fault injectors. A kill
alone needs no node between them (:attr:`FaultPlan.through_mitm`): the leg stays on the
controller's channel, and no forwarding process stands between the last command and the drivers'
watchdogs. (Inside User-Mode Linux the node was a fourth busy process on the one virtual CPU; it
stalled for 0.4-1.2 s there in December 2026 and so tripped the watchdogs before the kill came.)
The bus recorder records vcan0 (what the controller sees and sends); a :class:`hil.session.legwatch.
HeartbeatWatcher` watches the axes' Heartbeats on the leg's channel, as the leg sends them. Events,
at trial ``K``, ``event_after_s`` (1 s) after the trial was requested:

- ``kill``: SIGKILL to the controller process. ``safe_state_ms``: from the kill to the first
  moment every axis's Heartbeat on the leg's channel reports IDLE; the bound is the drivers' watchdog
  timeout plus one heartbeat period (0.1 + 0.1 s).
- ``silence``: the mitm drops every frame the node sends (SIGUSR1). The controller's supervisor
  calls the node lost after ``silence_periods`` heartbeat periods without a valid frame from it
  and stops safely (IDLE to every axis). ``safe_state_ms``: from the start of silencing to every
  axis's Heartbeat reporting IDLE; the bound is that timeout plus one heartbeat period.

After an event the session ends (no further trials): the firmware-sim process quits through the
side channel, the mitm and the recorders stop, and ``metrics.json`` gets a ``fault`` section
(:meth:`FaultSession.section`). Rate faults alone (drop, delay, duplicate, reorder, corrupt)
run every trial through the mitm; the section then carries the mitm's counts.

Times: heartbeats carry kernel receive timestamps, CLOCK_REALTIME; the event is stamped with
``time.time()`` as well as ``time.monotonic()`` (the firmware-sim process reports when each
driver entered IDLE on the monotonic clock, which every process of the session shares).

:func:`run_hil_fault` runs one such session (inside User-Mode Linux where the kernel has no
vcan, through ``elegant-stepping hil``) and returns a row of the fault matrix;
:func:`hil_rows` the rows ``elegant-stepping faults --hil`` adds.
"""

from __future__ import annotations

import json
import logging
import math
import os
import signal
import subprocess
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable

from hil.faults.audit import CommandAudit
from hil.faults.model import FAULT_KINDS, NODE_IDS, FaultSpec
from hil.profile import named as profile_named
from hil.session.legwatch import HeartbeatWatcher, safe_state
from hil.session.outcome import HilError, session_ok

if TYPE_CHECKING:
    from controller.config import ControllerConfig
    from hil.session.recorder import BusRecorder
    from hil.session.scenario import ScenarioClient

log = logging.getLogger(__name__)

LEG_CHANNEL = "vcan1"
EVENT_AFTER_S = 1.0  # an event happens this long after its trial was requested [s]
SAFE_WAIT_S = 3.0  # after the bound, how much longer to wait for every axis in IDLE [s]
# How far past the bound a safe state may come and still count as in time (``tolerance_ms``):
# the stalls measured in that very session of every process on the safe state's path, summed by
# hil.profile.Profile.late_allowance_s (:func:`safe_state_stalls_s`), never a fixed wall-clock
# budget. The drivers' watchdog and heartbeat run on the plant's simulated time, paced to the wall
# clock: when the plant's process is not scheduled, both come late by that stall (its longest
# period). The controller's IDLE after a silence (and the last command before a kill with rate
# faults) passes through the man-in-the-middle node, late by its longest busy gap; after a silence
# the controller's own loop decides, late by its longest period. The bound itself is not widened:
# ``within_bound`` reports against bound + tolerance; ``safe_state_ms``, ``bound_ms``,
# ``tolerance_ms`` and the ``stalls_ms`` behind it are all in the metrics.


def leg_axes() -> dict[str, int]:
    """The leg's axes: name -> CAN node id."""
    from firmware_sim.leg import LegHardware

    hw = LegHardware()
    return {"hip": hw.hip_node_id, "knee": hw.knee_node_id}


def driver_timing_s() -> tuple[float, float]:
    """(the drivers' command watchdog timeout in a session on this platform, their heartbeat
    period) [s]: the platform's allowance (:attr:`hil.profile.Profile.driver_watchdog_s`, which the
    session's controller writes to the drivers at arming), else the drivers' own."""
    from firmware_sim.leg import LegHardware
    from hil.profile import current

    d = LegHardware().driver
    return current().driver_watchdog_s or d.watchdog_timeout_s, d.heartbeat_period_s


@dataclass(frozen=True)
class FaultPlan:
    """The fault options of a HIL session.

    Attributes:
        to_leg, from_leg: :meth:`hil.faults.model.FaultSpec.parse` texts for the two directions of the
            mitm ("" = none).
        silence_node: the node id to silence (with ``silence_at_trial``).
        silence_at_trial: the trial (0-based) in which the node is silenced.
        kill_at_trial: the trial (0-based) in which the controller is killed (SIGKILL).
        event_after_s: how long into that trial the event happens [s]; default 1.0.
        seed: the mitm's fault seed.
        leg_channel: the leg's channel behind the mitm node; default vcan1 (a kill alone: unused,
            :attr:`through_mitm`).
    """

    to_leg: str = ""
    from_leg: str = ""
    silence_node: int | None = None
    silence_at_trial: int | None = None
    kill_at_trial: int | None = None
    event_after_s: float = EVENT_AFTER_S
    seed: int = 0
    leg_channel: str = LEG_CHANNEL

    def __post_init__(self) -> None:
        FaultSpec.parse(self.to_leg)
        FaultSpec.parse(self.from_leg)
        if (self.silence_node is None) != (self.silence_at_trial is None):
            raise ValueError("--silence-node and --silence-at-trial go together")
        if self.silence_at_trial is not None and self.kill_at_trial is not None:
            raise ValueError("one event per session: --silence-at-trial or --kill-controller-at-trial, not both")
        for name in ("silence_at_trial", "kill_at_trial"):
            k = getattr(self, name)
            if k is not None and k < 0:
                raise ValueError(f"{name} must be a trial index >= 0, got {k}")
        if self.silence_node is not None and not 0 <= self.silence_node <= 0x3F:
            raise ValueError(f"silence_node must be a node id 0..63, got {self.silence_node}")
        if not (math.isfinite(self.event_after_s) and 0.0 <= self.event_after_s <= 60.0):
            raise ValueError(f"event_after_s must be in [0, 60] s, got {self.event_after_s}")

    @property
    def kind(self) -> str:
        """``kill``, ``silence`` or ``rate``."""
        if self.kill_at_trial is not None:
            return "kill"
        if self.silence_at_trial is not None:
            return "silence"
        return "rate"

    @property
    def through_mitm(self) -> bool:
        """Does the session need the man-in-the-middle node between the controller and the leg? A
        rate fault or a silence does; a kill alone does not (the module docstring)."""
        return (self.kind != "kill" or FaultSpec.parse(self.to_leg).active
                or FaultSpec.parse(self.from_leg).active)

    @property
    def event_trial(self) -> int | None:
        return self.kill_at_trial if self.kill_at_trial is not None else self.silence_at_trial

    @classmethod
    def from_args(cls, args) -> "FaultPlan | None":
        """The plan of the ``hil`` command's options, or None without any fault option."""
        plan = cls(to_leg=args.faults_to_leg or "", from_leg=args.faults_from_leg or "",
                   silence_node=args.silence_node, silence_at_trial=args.silence_at_trial,
                   kill_at_trial=args.kill_controller_at_trial, seed=args.seed)
        active = (FaultSpec.parse(plan.to_leg).active or FaultSpec.parse(plan.from_leg).active
                  or plan.event_trial is not None)
        return plan if active else None

    def argv(self) -> list[str]:
        """The ``hil`` options that give this plan (the seed goes with ``--seed``)."""
        out = []
        if self.to_leg:
            out += ["--faults-to-leg", self.to_leg]
        if self.from_leg:
            out += ["--faults-from-leg", self.from_leg]
        if self.silence_node is not None:
            out += ["--silence-node", str(self.silence_node), "--silence-at-trial", str(self.silence_at_trial)]
        if self.kill_at_trial is not None:
            out += ["--kill-controller-at-trial", str(self.kill_at_trial)]
        return out


def add_hil_fault_args(p) -> None:
    """The fault options of ``elegant-stepping hil``."""
    p.add_argument("--faults-to-leg", default="", metavar="SPEC",
                   help="faults on frames to the leg, e.g. drop=0.05 (through a man-in-the-middle node on vcan1)")
    p.add_argument("--faults-from-leg", default="", metavar="SPEC", help="faults on frames from the leg, e.g. drop=0.05")
    p.add_argument("--silence-node", type=int, default=None, metavar="ID", help="silence this node (with --silence-at-trial)")
    p.add_argument("--silence-at-trial", type=int, default=None, metavar="K",
                   help="silence the node 1 s into trial K (0-based); the session ends at the safe stop")
    p.add_argument("--kill-controller-at-trial", type=int, default=None, metavar="K",
                   help="kill -9 the controller 1 s into trial K (0-based); the session ends at the safe state")


class FaultSession:
    """The fault side of one HIL session: the mitm process, the heartbeat watcher, the event."""

    def __init__(self, plan: FaultPlan, channel: str, work: Path, ctl_config: "ControllerConfig",
                 env: dict[str, str], say: Callable[[str], None] = lambda text: None, clock: str = "wall") -> None:
        if plan.through_mitm and plan.leg_channel == channel:
            raise ValueError(f"the leg's channel must differ from the controller's ({channel})")
        self.plan = plan
        self.leg_channel = plan.leg_channel if plan.through_mitm else channel  # the firmware-sim process's
        self.clock = clock  # "sim": the mitm runs on the simulated time of the syncs it forwards
        self.channel = channel
        self.work = work
        self.ctl_config = ctl_config
        self.env = env
        self.say = say
        self.axes = leg_axes()
        self.watchdog_s, self.heartbeat_s = driver_timing_s()
        self.watcher: HeartbeatWatcher | None = None
        self.mitm: subprocess.Popen | None = None
        self._mitm_log = None
        self.rc_mitm: int | None = None
        self.mitm_summary: dict[str, Any] = {}
        self.t_event_unix: float | None = None
        self.t_event_mono: float | None = None
        self.status_before: dict[str, Any] = {}
        self.status_after: dict[str, Any] = {}
        self.waited_ms: float | None = None
        self.walk_s_at_event: float | None = None

    # -- processes --------------------------------------------------------------------------
    def start(self, timeout_s: float = 30.0) -> None:
        """Start the heartbeat watcher on the leg's channel and, if the plan needs it, the mitm
        node; wait until the mitm has both channels open."""
        plan = self.plan
        self.watcher = HeartbeatWatcher(self.leg_channel, self.axes)
        self.watcher.start()
        if not plan.through_mitm:
            self.say(f"no mitm node: the leg shares {self.channel} with the controller")
            return
        ready = self.work / "mitm.ready"
        ready.unlink(missing_ok=True)
        cmd = [sys.executable, "-m", "hil.cli", "mitm", "--controller-channel", self.channel,
               "--leg-channel", plan.leg_channel, "--to-leg", plan.to_leg, "--from-leg", plan.from_leg,
               "--seed", str(plan.seed), "--json", str(self.work / "mitm.json"), "--ready-file", str(ready)]
        if plan.silence_node is not None:
            cmd += ["--silence-node", str(plan.silence_node)]
        if self.clock == "sim":
            cmd += ["--clock", "sim"]
        self._mitm_log = open(self.work / "mitm.log", "w")
        self.mitm = subprocess.Popen(cmd, stdout=self._mitm_log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                     env=self.env)
        deadline = time.monotonic() + timeout_s
        while not ready.exists():
            if self.mitm.poll() is not None:
                raise HilError(f"the mitm node ended at start (exit {self.mitm.returncode}); see mitm.log")
            if time.monotonic() > deadline:
                raise HilError(f"the mitm node was not up after {timeout_s:.0f} s")
            time.sleep(0.05)
        self.say(f"mitm up between {self.channel} and {plan.leg_channel} "
                 f"(to the leg {FaultSpec.parse(plan.to_leg).describe()}, from it {FaultSpec.parse(plan.from_leg).describe()})")

    def stop(self) -> None:
        """Stop the mitm (SIGTERM: it writes its counts) and the watcher."""
        if self.mitm is not None:
            if self.mitm.poll() is None:
                self.mitm.send_signal(signal.SIGTERM)
                try:
                    self.mitm.wait(15)
                except subprocess.TimeoutExpired:
                    self.mitm.kill()
                    self.mitm.wait(10)
            self.rc_mitm = self.mitm.returncode
        if self._mitm_log is not None:
            self._mitm_log.close()
        if self.watcher is not None:
            self.watcher.stop()
        if not self.plan.through_mitm:
            return
        from hil.faults.mitm import read_counts

        try:
            self.mitm_summary = read_counts(self.work / "mitm.json")
        except (OSError, ValueError) as exc:  # InputError (a wrong file) included
            self.mitm_summary = {"error": f"no counts from the mitm node: {exc}"}
        if self.plan.kind == "silence":  # the mitm's own clock of the silence start is the exact one
            s = self.mitm_summary.get("silence", {})
            if s.get("started_unix") is not None:
                self.t_event_unix, self.t_event_mono = s["started_unix"], s["started_mono"]

    def alive(self) -> bool:
        return self.mitm is None or self.mitm.poll() is None

    # -- the event --------------------------------------------------------------------------
    @property
    def bound_ms(self) -> float | None:
        """The safe state's bound [ms]: watchdog + one heartbeat period after a kill; the
        controller's silence timeout + one heartbeat period after a silence."""
        if self.plan.kind == "kill":
            return (self.watchdog_s + self.heartbeat_s) * 1e3
        if self.plan.kind == "silence":
            return (self.ctl_config.heartbeat_timeout_s + self.heartbeat_s) * 1e3
        return None

    def at_trial(self, index: int, client: "ScenarioClient", controller: subprocess.Popen,
                 firmware: subprocess.Popen, t_walk_mono: float | None = None) -> bool:
        """Called just after trial ``index`` was requested. In the event's trial: wait
        ``event_after_s``, make the event, wait for every axis's heartbeat to report IDLE (up to
        the bound plus :data:`SAFE_WAIT_S`). Returns True when the session must run no more trials."""
        plan = self.plan
        if plan.event_trial is None or index != plan.event_trial:
            return False
        time.sleep(plan.event_after_s)
        if controller.poll() is not None or firmware.poll() is not None or not self.alive():
            raise HilError("a process of the session ended before the event")
        self.status_before = client.request({"op": "status"}, expect="status")
        if plan.kind == "kill":
            self.t_event_unix, self.t_event_mono = time.time(), time.monotonic()
            os.kill(controller.pid, signal.SIGKILL)
            self.say(f"trial {index + 1}: controller killed (SIGKILL)")
        else:
            self.t_event_unix, self.t_event_mono = time.time(), time.monotonic()
            os.kill(self.mitm.pid, signal.SIGUSR1)
            self.say(f"trial {index + 1}: node {plan.silence_node} silenced")
        if t_walk_mono is not None:
            self.walk_s_at_event = self.t_event_mono - t_walk_mono
        deadline = time.monotonic() + self.bound_ms / 1e3 + SAFE_WAIT_S
        result = None
        while time.monotonic() < deadline:
            time.sleep(0.05)
            result = safe_state(self.watcher.snapshot(), list(self.axes), self.t_event_unix)
            if result["safe_state_ms"] is not None:
                break
        self.waited_ms = (time.monotonic() - self.t_event_mono) * 1e3
        time.sleep(2 * self.heartbeat_s)  # a heartbeat or two more: does the safe state hold?
        self.status_after = client.request({"op": "status"}, expect="status")
        if result is None or result["safe_state_ms"] is None:
            self.say(f"no safe state within {self.waited_ms:.0f} ms of the {plan.kind}")
        else:
            self.say(f"every axis IDLE {result['safe_state_ms']:.0f} ms after the {plan.kind} "
                     f"(bound {self.bound_ms:.0f} ms)")
        return True

    # -- the report -------------------------------------------------------------------------
    def section(self, *, where: str, bye: dict[str, Any], final: dict[str, Any], rc_controller: int | None,
                recorder: "BusRecorder", out: Path) -> dict[str, Any]:
        """The ``fault`` section of ``metrics.json``."""
        plan = self.plan
        beats = self.watcher.snapshot() if self.watcher is not None else []
        mitm = self.mitm_summary if plan.through_mitm else None  # None: no node ran
        sec: dict[str, Any] = {
            "kind": plan.kind,
            "plan": asdict(plan),
            "specs": {"to_leg": FaultSpec.parse(plan.to_leg).describe(),
                      "from_leg": FaultSpec.parse(plan.from_leg).describe()},
            "at_trial": plan.event_trial,
            "channels": {"controller": self.channel, "leg": self.leg_channel},
            "mitm": mitm,
            "mitm_exit_code": self.rc_mitm,
            "leg_heartbeats": {"seen": len(beats), "error": None if self.watcher is None else self.watcher.error},
            "watchdog_trips": bye.get("watchdog_trips"),
            "commands": command_audit(recorder, bye),
            "weights": weights_state(out / "weights.npz"),
            "controller_exit_code": rc_controller,
        }
        if plan.kind == "rate":
            sec["controller_exit_expected"] = rc_controller == 0
            return sec
        stalls = safe_state_stalls_s(plan.kind, bye, final, mitm)
        tolerance = profile_named(where).late_allowance_s(*stalls.values()) * 1e3
        hb = safe_state(beats, list(self.axes), self.t_event_unix) if self.t_event_unix is not None else {}
        ms = hb.get("safe_state_ms")
        drivers = {}
        for name, a in (bye.get("axes") or self.status_after.get("axes") or {}).items():
            since = a.get("idle_since_mono")
            drivers[name] = None if since is None or self.t_event_mono is None else (since - self.t_event_mono) * 1e3
        trips_before = self.status_before.get("watchdog_trips")
        sec.update({
            "event_after_s": plan.event_after_s,
            "t_event_unix": self.t_event_unix,
            "t_event_mono": self.t_event_mono,
            "safe_state_ms": ms,
            "axes_idle_ms": hb.get("axes_idle_ms"),
            "driver_idle_ms": drivers,
            "driver_safe_state_ms": max(drivers.values()) if drivers and None not in drivers.values() else None,
            "states_before": hb.get("states_before"),
            "heartbeats_after": hb.get("heartbeats_after"),
            "bound_ms": self.bound_ms,
            "tolerance_ms": tolerance,
            "stalls_ms": {k: None if v is None else v * 1e3 for k, v in stalls.items()},
            "within_bound": ms is not None and ms <= self.bound_ms + tolerance,
            "waited_ms": self.waited_ms,
            "walk_s_at_event": self.walk_s_at_event,
            "watchdog_trips_after_event": None if trips_before is None or bye.get("watchdog_trips") is None
            else bye["watchdog_trips"] - trips_before,
            "axes_after": {n: a.get("state") for n, a in self.status_after.get("axes", {}).items()},
            "controller_final_phase": final.get("phase"),
            "controller_fault_cause": final.get("fault_cause"),
        })
        if plan.kind == "kill":
            sec["t_kill"] = self.t_event_unix
            sec["controller_exit_expected"] = rc_controller == -signal.SIGKILL
            sec["note"] = "the controller's exit code is -9: killed by SIGKILL, as intended"
        else:
            sec["t_silence"] = self.t_event_unix
            # Stopped by SIGTERM after its safe stop: 0 (it stopped as asked) or 1 (it ended in FAULT).
            sec["controller_exit_expected"] = rc_controller in (0, 1)
        return sec


def safe_state_stalls_s(kind: str, bye: dict[str, Any], final: dict[str, Any],
                        mitm: dict[str, Any] | None) -> dict[str, float | None]:
    """The longest stall [s] measured in the session of each process on the safe state's path
    after a ``kind`` event (None: that process did not report): the plant (its pacer's longest
    period, from firmware-sim's ``bye``), the man-in-the-middle node if one ran (``mitm``: its
    counts, or None for a session without the node; its longest busy gap), and after a silence
    the controller (its loop's longest period, from its final record)."""

    def seconds(value: Any, scale: float) -> float | None:
        return float(value) * scale if isinstance(value, (int, float)) and not isinstance(value, bool) else None

    out = {"plant": seconds((bye.get("pacing") or {}).get("max_period_us"), 1e-6)}
    if mitm is not None:
        out["mitm"] = seconds((mitm.get("pacing") or {}).get("max_gap_ms"), 1e-3)
    if kind == "silence":
        out["controller"] = seconds(final.get("max_period_us"), 1e-6)
    return out


def command_audit(recorder: "BusRecorder", bye: dict[str, Any]) -> dict[str, Any]:
    """Set_Input_Pos targets outside the joint limits: those the controller put on its channel
    (audited on the recording, before any fault) and those the drivers counted (after the link)."""
    axes = bye.get("axes") or {}
    drivers = {n: a.get("targets_outside_limits") for n, a in axes.items()}
    by_node = {node: name for name, node in leg_axes().items()}
    controller: dict[str, int] | None = None
    commanded = getattr(recorder, "commanded", None)
    if commanded is not None and axes:
        limits = {node: tuple((axes.get(name) or {}).get("pos_limits_rev", [None, None]))
                  for node, name in by_node.items()}
        audit = CommandAudit(limits)
        for node, values in commanded.items():
            audit.check_all(node, values)
        controller = {by_node.get(node) or str(node): audit.by_node.get(node, 0) for node in commanded}
    return {
        "controller_outside_limits": None if controller is None else sum(controller.values()),
        "controller_by_axis": controller,
        "controller_audited": None if commanded is None else sum(len(v) for v in commanded.values()),
        "driver_targets_outside_limits": None if None in drivers.values() or not drivers else sum(drivers.values()),
        "driver_by_axis": drivers,
    }


def weights_state(path: Path) -> dict[str, Any]:
    """Is the weights file there, and does it load (schema, checksum, finite values)?"""
    from controller.stepping.weights import WeightsError, read_weights

    if not path.exists():
        return {"path": str(path), "exists": False, "loads": False, "error": None}
    try:
        w, cell = read_weights(path)
    except (WeightsError, OSError, ValueError) as exc:
        return {"path": str(path), "exists": True, "loads": False, "error": str(exc)}
    return {"path": str(path), "exists": True, "loads": True, "error": None, "shape": list(w.shape),
            "l1": float(abs(w).sum()), "cell_width_m": cell}


def fault_problems(m: dict[str, Any], trials: int) -> list[str]:
    """What went wrong in a fault session (empty: nothing); the expected outcomes of the fault
    itself (a controller killed with -9, a safe stop after a silence, watchdog trips after a
    kill, fewer trials after an event) are not problems."""
    f, h = m["fault"], m["hil"]
    problems = []
    if f.get("mitm") is not None and f.get("mitm_exit_code") != 0:
        problems.append(f"mitm node exit code {f.get('mitm_exit_code')}")
    if not f.get("controller_exit_expected"):
        problems.append(f"controller exit code {f.get('controller_exit_code')}")
    if h["exit_codes"].get("firmware_sim") != 0:
        problems.append(f"firmware-sim exit code {h['exit_codes'].get('firmware_sim')}")
    if f["kind"] == "rate":
        return problems + session_ok(m, trials)
    if h["error"]:
        problems.append(h["error"])
    if h["trials_completed"] != f["at_trial"]:
        problems.append(f"{h['trials_completed']} trials completed before the event in trial {f['at_trial']}")
    if f["safe_state_ms"] is None:
        problems.append(f"no safe state: not every axis's heartbeat reported IDLE after the {f['kind']}")
    elif not f["within_bound"]:
        problems.append(f"safe state after {f['safe_state_ms']:.0f} ms, over the bound of {f['bound_ms']:.0f} ms "
                        f"+ {f['tolerance_ms']:.0f} ms (the stalls measured on its path: {f.get('stalls_ms')})")
    if f["kind"] == "silence" and h["controller_final_phase"] != "fault":
        problems.append(f"the controller did not stop safely after the silence (phase {h['controller_final_phase']})")
    if f["weights"]["exists"] and not f["weights"]["loads"]:
        problems.append(f"the weights file does not load: {f['weights']['error']}")
    return problems


def fault_summary(m: dict[str, Any]) -> str:
    """One line on the fault side of a session, for the terminal."""
    f = m["fault"]
    mitm = f.get("mitm")

    def counts(direction: str) -> str:
        c = mitm.get(direction) or {}
        faults = ", ".join(f"{k} {c[k]}" for k in FAULT_KINDS if c.get(k))
        return f"{c.get('frames_in')} in, {c.get('forwarded')} out" + (f" ({faults})" if faults else "") + \
            (f", {c['silenced']} silenced" if c.get("silenced") else "")

    text = ("hil faults: no mitm node (the leg on the controller's channel)" if mitm is None else
            f"hil faults: mitm to the leg {counts('to_leg')}; from it {counts('from_leg')}")
    if f["kind"] != "rate":
        ms, drv = f.get("safe_state_ms"), f.get("driver_safe_state_ms")
        text += (f"; {f['kind']} in trial {f['at_trial'] + 1}: every axis's heartbeat IDLE after "
                 f"{'never' if ms is None else f'{ms:.0f} ms'} (drivers {'-' if drv is None else f'{drv:.0f} ms'}; "
                 f"bound {f['bound_ms']:.0f} + {f['tolerance_ms']:.0f} ms), watchdog trips {f.get('watchdog_trips')}, "
                 f"controller exit {f.get('controller_exit_code')}"
                 f"{' (expected)' if f.get('controller_exit_expected') else ''}")
    return text


# -- the fault matrix's HIL rows -------------------------------------------------------------------


def run_hil_fault(kind: str, rate: float | None, seed: int, out: str | Path, trials: int, *,
                  direction: str = "both", node: str = "hip", at_trial: int = 1,
                  where: str = "auto", timeout_s: float | None = None) -> dict[str, Any]:
    """One HIL session with one fault, run by ``elegant-stepping hil`` (inside User-Mode Linux
    where the kernel has no vcan); returns its row of the fault matrix. A kill -9 runs on the wall
    clock (what it measures is wall time); silence and rate faults in simulated time
    (``--clock sim``: the same row for a seed on any host, :func:`_sim_row`).

    ``kind``: ``kill``, ``silence`` (of ``node``) or a rate fault of :data:`hil.faults.model.FAULT_KINDS`
    at ``rate`` per frame in ``direction`` (``both``, ``to_leg``, ``from_leg``). Events happen in
    trial ``at_trial`` (0-based). ``trials``: trials of the session (events end it early).
    """
    out = Path(out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    argv = [sys.executable, "-m", "hil.cli", "hil", "--trials", str(trials), "--seed", str(seed), "--out", str(out),
            "--where", where, "--quiet"]
    sim = kind != "kill"  # only the kill -9 row measures the wall clock
    if sim:
        argv += ["--clock", "sim"]
    if kind == "kill":
        argv += ["--kill-controller-at-trial", str(at_trial)]
    elif kind == "silence":
        argv += ["--silence-node", str(NODE_IDS[node]), "--silence-at-trial", str(at_trial)]
    elif kind in FAULT_KINDS:
        if rate is None or not 0.0 < rate <= 1.0:
            raise ValueError(f"fault {kind} needs a rate in (0, 1], got {rate!r}")
        if direction not in ("both", "to_leg", "from_leg"):
            raise ValueError(f"direction must be both, to_leg or from_leg, got {direction!r}")
        spec = f"{kind}={rate:g}"
        if direction in ("both", "to_leg"):
            argv += ["--faults-to-leg", spec]
        if direction in ("both", "from_leg"):
            argv += ["--faults-from-leg", spec]
    else:
        raise ValueError(f"unknown HIL fault {kind!r}: kill, silence, {', '.join(FAULT_KINDS)}")
    if timeout_s is not None:
        argv += ["--timeout", str(timeout_s)]
    (out / "metrics.json").unlink(missing_ok=True)
    t0 = time.time()
    budget = (timeout_s or 180.0 + 40.0 * trials) + 120.0
    done = subprocess.run(argv, capture_output=True, text=True, stdin=subprocess.DEVNULL, timeout=budget)
    (out / "hil.stderr").write_text(done.stderr)
    row: dict[str, Any] = {"fault": kind, "rate": rate, "direction": direction if kind in FAULT_KINDS else None,
                           "node": node if kind == "silence" else None, "seed": seed, "where": "hil",
                           "clock": "sim" if sim else "wall", "exit_code": done.returncode}
    path = out / "metrics.json"
    if not path.exists():
        row["error"] = f"hil wrote no metrics (exit {done.returncode}): {done.stderr[-500:]}"
        return row
    from hil.analysis.metrics import success_last

    m = json.loads(path.read_text())
    if sim:
        return _sim_row(row, m, kind, done, path, time.time() - t0)
    f, h = m.get("fault", {}), m["hil"]
    cmds, weights = f.get("commands", {}), f.get("weights", {})
    event = kind in ("kill", "silence")
    # Weights: a file that is there must load. After a clean stop (silence, rate faults) the
    # controller saves them at exit; after a kill only a periodic save (every_s of walking) can
    # have written them, so the file is expected only if the leg walked that long (+1 s) before.
    from controller.daemon.autosave import AutosaveConfig

    walked = f.get("walk_s_at_event")
    expected = kind != "kill" or (walked is not None and walked >= AutosaveConfig.every_s + 1.0)
    data_lost = bool((weights.get("exists") and not weights.get("loads")) or (expected and not weights.get("exists")))
    weights = {**weights, "expected": expected,
               "note": None if kind != "kill" else
               f"killed after {walked:.1f} s of walking; periodic saves every {AutosaveConfig.every_s:g} s"
               if walked is not None else None}
    row.update({
        "platform": h.get("where"),
        # as in the lockstep rows: safe_state_ms when the drivers themselves were IDLE (their own
        # clock), heartbeat_idle_ms when every axis's heartbeat on the leg's bus said so
        "safe_state_ms": f.get("driver_safe_state_ms"),
        "heartbeat_idle_ms": f.get("safe_state_ms"),
        "driver_idle_ms": f.get("driver_safe_state_ms"),
        "bound_ms": f.get("bound_ms"),
        "within_bound": f.get("within_bound"),
        "commands_outside_limits": cmds.get("controller_outside_limits"),
        "driver_targets_outside_limits": cmds.get("driver_targets_outside_limits"),
        "data_lost": data_lost,
        "weights": weights,
        "success_last_50": None if event else success_last(m.get("trials", []), 50),
        "trials_completed": h.get("trials_completed"),
        "stopped_at_trial": f.get("at_trial") if event else None,
        "fault_cause": h.get("fault_cause"),
        "mitm": None if f.get("mitm") is None else {k: f["mitm"].get(k) for k in ("to_leg", "from_leg", "silence")},
        "watchdog_trips": h.get("watchdog_trips"),
        "wall_s": time.time() - t0,
        "details": str(path),
    })
    if done.returncode != 0:
        row["error"] = f"hil exit {done.returncode}: {done.stderr.strip().splitlines()[-1:] or ''}"
    return row


SIM_ROW_WALL_KEYS = ("wall_s", "details", "platform", "exit_code")
"""The keys of a simulated-time row that describe the host, not the run: every other key is the
same for a seed on a loaded and on a quiet machine."""


def _sim_row(row: dict[str, Any], m: dict[str, Any], kind: str, done: subprocess.CompletedProcess, path: Path,
             wall_s: float) -> dict[str, Any]:
    """A fault-matrix row of a ``--clock sim`` session (silence, rate faults): every figure in
    simulated time or counted in frames, so a seed gives the same row on any host
    (:data:`SIM_ROW_WALL_KEYS` aside)."""
    from hil.analysis.metrics import success_last

    f, h = m.get("fault", {}), m["hil"]
    event = kind == "silence"
    weights = weights_state(path.parent / "weights.npz")
    row.update({
        "platform": h.get("where"),
        "safe_state_ms": f.get("safe_state_sim_ms") if event else None,
        "axes_idle_ms": f.get("axes_idle_sim_ms") if event else None,
        "bound_ms": f.get("bound_ms") if event else None,
        "within_bound": f.get("within_bound") if event else None,
        "data_lost": bool(weights["exists"] and not weights["loads"]) or (not event and not weights["exists"]),
        "weights_l1": weights.get("l1"),
        "success_last_50": None if event else success_last(m.get("trials", []), 50),
        "successes": sum(t["success"] for t in m.get("trials", [])),
        "reflexes": h.get("reflexes"),
        "trials_completed": h.get("trials_completed"),
        "stopped_at_trial": f.get("at_trial") if event else None,
        "fault_cause": h.get("fault_cause"),
        "frames_silenced": f.get("frames_silenced") if event else None,
        "mitm": None if event else {k: _faulted_counts((f.get("mitm") or {}).get(k)) for k in ("to_leg", "from_leg")},
        "axes_at_end": h.get("axes_at_end"),
        "wall_s": wall_s,
        "details": str(path),
    })
    if done.returncode != 0:
        row["error"] = f"hil exit {done.returncode}: {done.stderr.strip().splitlines()[-1:] or ''}"
    return row


def _faulted_counts(c: dict[str, Any] | None) -> dict[str, Any] | None:
    """One direction's mitm counts without the simulated-time frames it passed untouched: how
    often the plant repeated its opening sync before the controller answered depends on when the
    controller process started (wall time); every other frame is the run's."""
    if not c:
        return None
    sim = c.get("sim_frames", 0)
    return {"frames": c["frames_in"] - sim, "forwarded": c["forwarded"] - sim,
            **{k: c.get(k) for k in (*FAULT_KINDS, "silenced", "send_errors")}}


def hil_rows(out: str | Path, seed: int = 0, trials: int = 10) -> list[dict[str, Any]]:
    """The HIL rows of the fault matrix: kill -9 of the controller (wall clock) and silence of the
    hip (simulated time; 3 trials, the event in trial 2), 5% frame loss both ways (simulated time,
    ``trials`` trials)."""
    out = Path(out)
    return [run_hil_fault("kill", None, seed, out / "kill", 3),
            run_hil_fault("silence", None, seed, out / "silence_hip", 3, node="hip"),
            run_hil_fault("drop", 0.05, seed, out / "drop_0.05", trials)]


__all__ = ["FaultPlan", "FaultSession", "add_hil_fault_args", "fault_problems", "run_hil_fault", "hil_rows",
           "safe_state_stalls_s"]
