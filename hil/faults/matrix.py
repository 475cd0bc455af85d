"""The fault-injection matrix: every failure mode, injected in lockstep, and what happened.

A row is one fault case on one seed (:class:`FaultCase`). Two kinds of case:

- **Rate faults** (``drop``, ``delay``, ``duplicate``, ``reorder``, ``corrupt``, and ``none`` as
  the control): a learning run (:class:`hil.experiments.learn.LearningRun`) with a faulty link
  (:class:`hil.faults.model.FaultyBus`) between the controller and the bus from the first trial on,
  in one or both directions. The controller saves its weights every ``save_every_s`` of walking,
  as the daemon does. ``success_last_50`` (:func:`hil.analysis.metrics.success_last`) is the
  learning outcome under that fault; if the controller stopped safely, the run ends there, with
  ``stopped_at_trial`` and the cause, and ``success_last_50`` is None.
- **Lifecycle rows** (:mod:`hil.faults.lifecycle`: a latched e-stop or driver error at start, a
  second master, a restart without walking, an incompatible weights file, SIGHUP, SIGUSR1): each
  starts what it needs (lockstep, or the daemon with the simulated leg in one process) and reports
  its own figure; they are in the default matrix and can be named with ``--only``.
- **Events** (``silence`` of one node, ``kill`` of the controller, ``cut`` of its cable,
  ``bus_off`` of its CAN interface for ``outage_s``): the leg walks into a trial, the event
  happens 1.5 s in, and the leg runs on until every axis is IDLE (or for 3 s: an outage short
  enough to ride through leaves ``safe_state_ms`` None and ``still_walking`` True).
  ``safe_state_ms`` is the time from the event to every simulated axis in IDLE (ground truth);
  ``heartbeat_idle_ms`` when every axis's Heartbeat on the bus first reported IDLE (what a CAN
  analyser would see). After a kill, the weights file must load to the last save.

Every row: ``commands_outside_limits`` (Set_Input_Pos frames the controller itself put on the
bus with a target outside its joint limits, audited before any fault), and
``driver_targets_outside_limits`` (targets outside the limits that reached the drivers: a link
that corrupts frames can make these without the controller ever sending one). ``data_lost``:
the weights file in the case's folder does not load back to the weights last saved.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable

import can
import numpy as np

from controller.atomic import write_json_atomic, write_text_atomic
from controller.supervisor import Phase
from hil.faults.audit import CommandAudit
from hil.faults.model import FAULT_KINDS, NODE_IDS, FaultSpec
from hil.session.legwatch import Beat, safe_state
from protocol import BusContract

log = logging.getLogger(__name__)

EVENTS = ("silence", "kill", "cut", "bus_off")
DIRECTIONS = ("both", "to_leg", "from_leg")
EVENT_AFTER_S = 1.5  # an event happens this long into its trial [s]
SAFE_WAIT_S = 3.0  # how long the leg runs on after an event, waiting for every axis in IDLE [s]


@dataclass(frozen=True)
class FaultCase:
    """One row of the matrix.

    Attributes:
        fault: ``none``, one of :data:`hil.faults.model.FAULT_KINDS`, or one of :data:`EVENTS`.
        rate: the fault's probability per frame (rate faults), None for events and ``none``.
        direction: which way the rate fault applies: ``both``, ``to_leg`` (what the controller
            sends) or ``from_leg`` (what it receives); default ``both``.
        node: the node silenced (``hip``, ``knee``, ``sensor_board``; ``silence`` only).
        seed: the run's seed (start distances, sensor noise, and the faults' own generator).
        outage_s: how long the controller's bus is off [s] (``bus_off`` only).
    """

    fault: str
    rate: float | None = None
    direction: str = "both"
    node: str | None = None
    seed: int = 0
    outage_s: float | None = None

    def __post_init__(self) -> None:
        if self.fault not in ("none", *FAULT_KINDS, *EVENTS):
            raise ValueError(f"unknown fault {self.fault!r}: none, {', '.join(FAULT_KINDS + EVENTS)}")
        if self.fault in FAULT_KINDS and not (self.rate is not None and 0.0 < self.rate <= 1.0):
            raise ValueError(f"fault {self.fault} needs a rate in (0, 1], got {self.rate!r}")
        if self.direction not in DIRECTIONS:
            raise ValueError(f"direction must be one of {DIRECTIONS}, got {self.direction!r}")
        if (self.fault == "silence") != (self.node is not None) or (self.node and self.node not in NODE_IDS):
            raise ValueError(f"silence takes a node ({', '.join(NODE_IDS)}); other faults none, got {self.node!r}")
        if (self.fault == "bus_off") != (self.outage_s is not None) or (self.outage_s is not None and
                                                                        not 0.0 < self.outage_s <= 10.0):
            raise ValueError(f"bus_off takes an outage in (0, 10] s; other faults none, got {self.outage_s!r}")

    @property
    def name(self) -> str:
        parts = [self.fault]
        if self.rate is not None:
            parts.append(f"{self.rate:g}")
        if self.fault in FAULT_KINDS and self.direction != "both":
            parts.append(self.direction)
        if self.node:
            parts.append(self.node)
        if self.outage_s is not None:
            parts.append(f"{self.outage_s:g}s")
        return "_".join(parts) + f"_seed{self.seed}"

    def specs(self) -> tuple[FaultSpec, FaultSpec]:
        """(to_leg, from_leg) fault specs of a rate fault."""
        if self.fault not in FAULT_KINDS:
            return FaultSpec(), FaultSpec()
        spec = FaultSpec(**{self.fault: self.rate})
        return (spec if self.direction in ("both", "to_leg") else FaultSpec(),
                spec if self.direction in ("both", "from_leg") else FaultSpec())


def default_cases(seeds: Iterable[int] = (0,), loss_seeds: Iterable[int] = ()) -> list[FaultCase]:
    """The matrix: the control, each rate fault at a low and a high rate, each event; the 5 %
    frame-loss case again on every seed of ``loss_seeds``."""
    cases: list[FaultCase] = []
    for seed in seeds:
        cases.append(FaultCase("none", seed=seed))
        for rate in (0.01, 0.05):
            cases.append(FaultCase("drop", rate, seed=seed))
        cases += [FaultCase("delay", 0.05, seed=seed), FaultCase("duplicate", 0.05, seed=seed),
                  FaultCase("reorder", 0.05, seed=seed),
                  FaultCase("corrupt", 0.01, "from_leg", seed=seed), FaultCase("corrupt", 0.001, "to_leg", seed=seed)]
        cases += [FaultCase("silence", node=n, seed=seed) for n in NODE_IDS]
        cases += [FaultCase("kill", seed=seed), FaultCase("cut", seed=seed),
                  FaultCase("bus_off", seed=seed, outage_s=0.03), FaultCase("bus_off", seed=seed, outage_s=0.5)]
    have = {c.name for c in cases}
    cases += [c for c in (FaultCase("drop", 0.05, seed=s) for s in loss_seeds) if c.name not in have]
    return cases


class HeartbeatWatch:
    """A third node on the lockstep's bus that keeps the axes' heartbeats once ``armed``, as
    :class:`hil.session.legwatch.Beat` on the simulated clock, for :func:`hil.session.legwatch.safe_state` (the
    HIL watcher's computation). Before it is armed it only drains its queue."""

    def __init__(self, bus: can.BusABC, node_ids: dict[str, int]) -> None:
        contract = BusContract.load()
        self.bus = bus
        self._unpack = contract.codec("Heartbeat").unpack
        self._ids = {contract.odrive_id(n, "Heartbeat"): name for name, n in node_ids.items()}
        self.axes = list(node_ids)
        self.beats: list[Beat] = []
        self.armed = False

    def poll(self, now_s: float) -> None:
        msg = self.bus.recv(timeout=0.0)
        while msg is not None:
            name = self._ids.get(msg.arbitration_id)
            if name is not None and self.armed:
                error, state = self._unpack(msg.data)[:2]
                self.beats.append(Beat(now_s, name, int(state), int(error)))
            msg = self.bus.recv(timeout=0.0)


def _load_back(path: Path, expected: np.ndarray | None, n_cells: int, cell_width_m: float) -> bool:
    """True if data was lost: the file does not load to ``expected`` (None: nothing was saved)."""
    from controller.stepping.weights import WeightsError, load_weights

    if expected is None:
        return False
    try:
        got = load_weights(path, n_cells, cell_width_m)
    except WeightsError as exc:
        log.error("weights lost: %s", exc)
        return True
    return not np.array_equal(got, expected)


def run_case(case: FaultCase, trials: int, out_dir: str | Path, save_every_s: float = 10.0) -> dict[str, Any]:
    """Run one case; write its row to ``out_dir/<name>/row.json`` and return it."""
    from controller.stepping.weights import save_weights
    from hil.analysis.metrics import mistakes_101_150, success_last, window_success
    from hil.experiments.learn import LearnConfig, LearningRun

    out = Path(out_dir) / case.name
    out.mkdir(parents=True, exist_ok=True)
    weights_path = out / "weights.npz"
    weights_path.unlink(missing_ok=True)
    config = LearnConfig(trials=trials if case.fault not in EVENTS else 1, seed=case.seed)
    run = LearningRun(config)
    ls, loop = run.ls, run.ls.loop
    ctl = config.controller
    audit = CommandAudit.from_config(ctl)
    node_ids = {a.name: a.node_id for a in ctl.axes}
    watch: HeartbeatWatch | None = None  # opened only when needed: an unread bus end fills up
    row: dict[str, Any] = {**dataclasses.asdict(case), "where": "lockstep", "safe_state_ms": None,
                           "heartbeat_idle_ms": None, "success_last_50": None}
    saved: dict[str, Any] = {"w": None, "t": -math.inf}

    def save(now_s: float) -> None:
        w = np.array(loop.premotor.weights, dtype=float)
        if saved["w"] is None or not np.array_equal(w, saved["w"]):
            save_weights(weights_path, w, ctl.encoder.cell_width_m)
            saved["w"] = w
        saved["t"] = now_s

    try:
        run.bring_up()
        to_leg, from_leg = case.specs()
        ls.inject_faults(to_leg, from_leg, seed=case.seed + 1000, on_send=audit)
        save(ls.t_s)
        if case.fault in EVENTS:
            watch = HeartbeatWatch(ls.observer(), node_ids)
            row.update(_event(case, run, watch, save, save_every_s))
        else:
            stopped = None
            for i in range(trials):
                try:
                    run.trials.append(run.trial(i, on_step=lambda _ls: _periodic(save, _ls, saved, save_every_s)))
                except RuntimeError as exc:
                    stopped = (i, str(exc))
                    break
            if stopped is None:
                save(ls.t_s)
                row["success_last_50"] = success_last(run.trials, 50)
                row["mistakes_101_150"] = mistakes_101_150(run.trials)
            else:
                row["stopped_at_trial"], row["stop_cause"] = stopped
                t_fault = loop.supervisor.fault_t_s
                watch = HeartbeatWatch(ls.observer(), node_ids)
                watch.armed = True
                t_idle = _run_until_idle(ls, watch)
                row["safe_state_ms"] = None if t_idle is None else (t_idle - t_fault) * 1e3
            row["trials_completed"] = len(run.trials)
            row["success_all"] = window_success(run.trials, 1, len(run.trials))
        fb = ls.faulty
        row["faults_applied"] = fb.counts() if fb is not None else {}
    finally:
        row["commands_checked"] = audit.checked
        row["commands_outside_limits"] = audit.outside
        row["driver_targets_outside_limits"] = sum(a.targets_outside_limits for a in ls.leg.axes.values())
        row["controller_dropped"] = dict(loop.io.dropped)
        row["final_phase"] = loop.phase.value
        row["fault_cause"] = loop.supervisor.fault_cause or None
        row["weights_saved"] = saved["w"] is not None
        row["data_lost"] = _load_back(weights_path, saved["w"], ctl.encoder.n_cells, ctl.encoder.cell_width_m)
        if watch is not None:
            watch.bus.shutdown()
        run.close()
    write_json_atomic(out / "row.json", row, indent=1)
    write_json_atomic(out / "trials.json", run.trials, indent=None)
    return row


def _periodic(save, ls, saved: dict[str, Any], every_s: float) -> None:
    if ls.controller_alive and ls.loop.phase is Phase.WALK and ls.t_s - saved["t"] >= every_s:
        save(ls.t_s)


def _run_until_idle(ls, watch: HeartbeatWatch) -> float | None:
    """Step until every simulated axis is IDLE; the simulated time then, or None after SAFE_WAIT_S."""
    t_end = ls.t_s + SAFE_WAIT_S
    while not ls.axes_idle():
        if ls.t_s > t_end:
            return None
        ls.step()
        watch.poll(ls.t_s)
    return ls.t_s


def _event(case: FaultCase, run, watch: HeartbeatWatch, save, save_every_s: float) -> dict[str, Any]:
    """Walk into a trial, make the event happen, and time the way to every axis in IDLE."""
    from firmware_sim.plant import Obstacle

    ls = run.ls
    plant = ls.plant
    plant.add_obstacle(Obstacle(plant.carriage_x_m + 2.5, 0.08, 0.10))
    saved = {"t": ls.t_s}
    t_event = ls.t_s + EVENT_AFTER_S
    while ls.t_s < t_event:
        ls.step()
        watch.poll(ls.t_s)  # keeps the observer's queue empty
        if ls.t_s - saved["t"] >= save_every_s:
            save(ls.t_s)
            saved["t"] = ls.t_s
    if ls.loop.phase is not Phase.WALK:
        raise RuntimeError(f"not walking when the event was due: {ls.loop.supervisor.fault_cause}")
    save(ls.t_s)  # the daemon's periodic save, just before the event
    watch.armed = True
    t0 = ls.t_s
    if case.fault == "kill":
        ls.kill_controller()
    elif case.fault == "cut":
        ls.cut_bus()
    elif case.fault == "bus_off":
        ls.bus_off(case.outage_s)
    else:
        ls.silence([NODE_IDS[case.node]])
    t_idle = _run_until_idle(ls, watch)
    for _ in range(250):  # a little longer, for the last heartbeats to be seen
        ls.step()
        watch.poll(ls.t_s)
    beats = safe_state(watch.beats, watch.axes, t0)
    extra = {}
    if case.fault == "bus_off":
        extra = {"bus_events": dict(ls.loop.io.bus_events), "still_walking": ls.loop.phase is Phase.WALK}
    return {**extra,
        "safe_state_ms": None if t_idle is None else (t_idle - t0) * 1e3,
        "heartbeat_idle_ms": beats["safe_state_ms"],
        "axes_idle_ms_by_heartbeat": {k: v for k, v in beats["axes_idle_ms"].items() if v is not None},
        "controller_fault_ms": None if math.isnan(ls.loop.supervisor.fault_t_s) else
        (ls.loop.supervisor.fault_t_s - t0) * 1e3,
        "driver_errors": {n: hex(int(a.errors | a.disarm_reason)) for n, a in ls.leg.axes.items()},
    }


def _task(case: FaultCase, trials: int, out_dir: str) -> dict[str, Any]:
    logging.basicConfig(level=logging.WARNING)
    try:
        return run_case(case, trials, out_dir)
    except Exception as exc:  # noqa: BLE001 - one broken case must not lose the others
        log.exception("case %s failed", case.name)
        return {**dataclasses.asdict(case), "where": "lockstep", "error": repr(exc)}


def run_matrix(cases: list[FaultCase], trials: int, out_dir: str | Path, workers: int = 2,
               progress: bool = True) -> list[dict[str, Any]]:
    """Run every case (finished ones, with a ``row.json`` from the same trial count, are read back)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rows: dict[str, dict[str, Any]] = {}
    todo = []
    for c in cases:
        done = out / c.name / "row.json"
        if done.exists():
            row = json.loads(done.read_text())
            if row.get("trials_completed") is None or row.get("trials_completed") == trials or row.get("stopped_at_trial") is not None:
                rows[c.name] = row
                continue
        todo.append(c)
    bar = None
    if progress and todo:
        from tqdm import tqdm

        bar = tqdm(total=len(todo), unit="case", desc="faults")
    if workers <= 1:
        for c in todo:
            rows[c.name] = _task(c, trials, str(out))
            if bar is not None:
                bar.update(1)
    else:
        with ProcessPoolExecutor(max_workers=workers) as pool:
            futures = {pool.submit(_task, c, trials, str(out)): c for c in todo}
            for f in as_completed(futures):
                rows[futures[f].name] = f.result()
                if bar is not None:
                    bar.update(1)
    if bar is not None:
        bar.close()
    return [rows[c.name] for c in cases]


def killsave_row(kills: int, seed: int, out_dir: str | Path) -> dict[str, Any]:
    """The ``kill -9`` during a weight save row (:mod:`hil.faults.killsave`)."""
    from hil.faults.killsave import kill_during_saves

    folder = Path(out_dir) / f"killsave_seed{seed}"
    folder.mkdir(parents=True, exist_ok=True)
    counts = kill_during_saves(kills, folder, seed)
    return {"fault": "kill_during_save", "rate": None, "direction": None, "node": None, "seed": seed,
            "where": "process", "safe_state_ms": None, "commands_outside_limits": 0,
            "data_lost": counts["corrupt_loads"] > 0, "success_last_50": None, "killsave": counts}


WATCHDOGS_STOPPED = "the drivers' watchdogs stopped the axes"


def _fmt(value: Any, unit: str = "") -> str:
    if value is None:
        return "-"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return f"{value:.0%}" if unit == "%" else f"{value:.0f}{unit}"
    return f"{value}{unit}"


def table(rows: list[dict[str, Any]]) -> str:
    """The matrix as a Markdown table."""
    lines = ["| fault | rate | direction / node | where | seed | safe_state_ms | heartbeat IDLE ms | commands outside "
             "limits (controller / at drivers) | data lost | success, last 50 | notes |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        if "error" in r:
            notes = f"error: {r['error']}"
        elif r.get("stopped_at_trial") is not None and r["fault"] in EVENTS:  # HIL: the event ends the session
            notes = (f"event in trial {r['stopped_at_trial'] + 1}; "
                     f"{r.get('fault_cause') or WATCHDOGS_STOPPED}")
        elif r.get("stopped_at_trial") is not None:
            notes = f"safe stop in trial {r['stopped_at_trial'] + 1}: {r.get('fault_cause')}"
        elif r.get("killsave"):
            k = r["killsave"]
            notes = ", ".join(f"{key} {k[key]}" for key in ("kills", "loads_ok_from_file", "loads_from_prev", "zeros",
                                                            "corrupt_loads") if key in k)
        elif r.get("mistakes_101_150") is not None:
            m = r["mistakes_101_150"]
            notes = f"{m} mistake{'' if m == 1 else 's'} in trials 101-150"
        elif r.get("still_walking"):
            ev = r.get("bus_events", {})
            notes = f"ridden through: bus reopened after {ev.get('bus_reopen_failures', 0) + 1} attempt(s), still walking"
        elif r["fault"] == "kill":
            notes = WATCHDOGS_STOPPED
        elif r["fault"] in FAULT_KINDS and r.get("trials_completed") is not None and r["trials_completed"] < 50:
            notes = f"{r['trials_completed']} trials from zero weights: the success column is over all of them"
        else:
            notes = r.get("fault_cause") or ""
        where = r.get("node") or (r.get("direction") if r.get("rate") is not None else "") or ""
        if r.get("outage_s") is not None:
            where = f"outage {r['outage_s']:g} s"
        outside = f"{_fmt(r.get('commands_outside_limits'))} / {_fmt(r.get('driver_targets_outside_limits'))}"
        rate = "-" if r.get("rate") is None else f"{r['rate']:g}"
        lines.append(f"| {r['fault']} | {rate} "
                     f"| {where} | {r.get('where')} | {r.get('seed')} | {_fmt(r.get('safe_state_ms'))} "
                     f"| {_fmt(r.get('heartbeat_idle_ms'))} | {outside} | {_fmt(r.get('data_lost'))} "
                     f"| {_fmt(r.get('success_last_50'), '%')} | {notes} |")
    return "\n".join(lines) + "\n"


def known_rows() -> list[str]:
    """Every name ``faults --only`` takes: the control, the rate faults, the events, the kill
    during a weight save and the lifecycle rows."""
    from hil.faults.lifecycle import ROWS as LIFECYCLE_ROWS

    return ["none", *FAULT_KINDS, *EVENTS, "kill_during_save", *LIFECYCLE_ROWS]


def parse_only(text: str) -> list[str]:
    """The rows ``--only`` names (comma separated; empty: every row).

    Raises:
        UsageError: a name that is not a row (all of them named, with the known ones), or a list
            of nothing but commas.
    """
    from controller.errors import UsageError

    if not text:
        return []
    wanted = [w.strip() for w in text.split(",") if w.strip()]
    known = known_rows()
    unknown = [w for w in wanted if w not in known]
    if unknown or not wanted:
        raise UsageError(f"--only: unknown row(s) {', '.join(unknown) or '(none given)'}; known: {', '.join(known)}")
    return wanted


def main_faults(args) -> int:
    """``elegant-stepping faults``: run the matrix, write the rows as JSON and a Markdown table.
    Every option is checked before any case runs: an unknown ``--only`` row or a malformed seed
    list is a usage error (exit 2), an output path that cannot be written an input error (3)."""
    from controller.cli.common import check_output_file, check_output_folder
    from controller.errors import UsageError
    from hil.experiments.sweep import parse_seeds

    from hil.faults.lifecycle import ROWS as LIFECYCLE_ROWS, run_rows

    wanted = parse_only(args.only)
    seeds = {}
    for option, text in (("--seeds", args.seeds), ("--loss-seeds", args.loss_seeds)):
        try:
            seeds[option] = parse_seeds(text) if text else ()
        except ValueError as exc:
            raise UsageError(f"{option}: {exc}") from None
        if any(seed < 0 for seed in seeds[option]):
            raise UsageError(f"{option}: seeds are non-negative, got {text!r}")
    if not seeds["--seeds"]:
        raise UsageError(f"--seeds: no seed in {args.seeds!r}")
    check_output_folder(args.out, "--out")
    check_output_file(args.json, "--json")
    out = Path(args.out)
    cases = default_cases(seeds["--seeds"], seeds["--loss-seeds"])
    lifecycle = list(LIFECYCLE_ROWS)
    if wanted:
        cases = [c for c in cases if c.fault in wanted]
        lifecycle = [name for name in lifecycle if name in wanted]
    rows = run_matrix(cases, args.trials, out, workers=args.workers, progress=not args.quiet) if cases else []
    if args.kills and (not wanted or "kill_during_save" in wanted):
        rows.append(killsave_row(args.kills, 0, out))
    rows += run_rows(lifecycle, out / "lifecycle")
    if args.hil:  # read back when done before with as many trials, like the lockstep cases
        done = out / "hil" / "rows.json"
        hil = json.loads(done.read_text()) if done.exists() else None
        if not hil or hil.get("trials") != args.hil_trials:
            from hil.faults.session import hil_rows

            hil = {"trials": args.hil_trials, "rows": hil_rows(out / "hil", seed=0, trials=args.hil_trials)}
            done.parent.mkdir(parents=True, exist_ok=True)
            write_json_atomic(done, hil, indent=1)
        rows += hil["rows"]
    text = json.dumps(rows, indent=1) + "\n"
    if args.json in (None, "-"):
        print(text)
    else:
        path = Path(args.json)
        path.parent.mkdir(parents=True, exist_ok=True)
        write_text_atomic(path, text)
    write_text_atomic(out / "report.md", table(rows))
    print(table(rows), file=__import__("sys").stderr)
    bad = [r for r in rows if "error" in r or r.get("commands_outside_limits") or r.get("data_lost")]
    return 1 if bad else 0
