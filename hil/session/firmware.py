"""The ``firmware-sim`` process: the simulated leg on a real CAN bus, paced to wall-clock time.

The PyBullet plant steps at its physics rate (1 kHz) on the monotonic clock (:class:`controller.daemon.pacing.
Pacer`, catching up when behind); each step the node host handles the frames waiting on the
bus, the drivers' loops run and the due cyclic frames are sent (:class:`firmware_sim.leg.
SimulatedLeg`, unchanged). The controller is another process on the same bus.

The scenario comes through a side channel of the simulation, never the bus: a Unix stream socket
(``--scenario ADDR``; an address starting with ``@`` is in the abstract namespace) carrying JSON
lines. Requests: ``{"op": "status"}``, ``{"op": "trial", "index", "start_m", "height_m",
"depth_m", "past_m"}`` (place an obstacle ``start_m`` ahead of the hip, walk until the hip is
``past_m`` past it, remove it) and ``{"op": "quit"}``. Replies: ``status``, ``trial_done`` with
the ground truth measured here on the plant (contact with the obstacle, footfalls, the
monotonic times of the trial's start, first footfall beyond the near edge and end), ``bye``.
``status`` and ``bye`` carry, per axis: its state, errors, whether its watchdog expired, the
Set_Input_Pos frames it took, the targets outside its limits it was sent, its position limits
[rev], and the monotonic time [s] it last entered IDLE (``idle_since_mono``, None while not IDLE:
checked at every wake-up of the plant, so to 1 ms natively, 2 ms inside User-Mode Linux).
"""

from __future__ import annotations

import logging
import math
import os
import signal
import time
from dataclasses import replace
from typing import Any


from firmware_sim.leg import LegHardware, SimulatedLeg
from firmware_sim.plant import Obstacle, RigConfig
from controller.daemon.fastbus import lean
from controller.daemon.openbus import open_bus
from hil.lockstep.groundtruth import FootfallTracker
from controller.daemon.pacing import Pacer
from hil.session.scenario import SideChannel
from protocol import AxisError, AxisState

log = logging.getLogger(__name__)

REWIND_AFTER_M = 150.0


class Scenario:
    """Trials placed through the side channel; ground truth measured on the plant."""

    def __init__(self, leg: SimulatedLeg) -> None:
        self.leg = leg
        self.plant = leg.plant
        self.tracker = FootfallTracker(leg.plant)
        self.request: dict[str, Any] | None = None
        self.state = "idle"  # idle | rewind | running
        self.trial: dict[str, Any] = {}
        self.tracking = False

    def start(self, request: dict[str, Any]) -> None:
        if self.state != "idle":
            raise RuntimeError("a trial is already running")
        self.request = request
        self.state = "rewind" if self.plant.carriage_x_m >= REWIND_AFTER_M else "place"

    def _place(self, now_mono: float) -> None:
        r, plant = self.request, self.plant
        x0 = plant.carriage_x_m
        near = x0 + float(r["start_m"])
        depth = float(r.get("depth_m", 0.10))
        plant.add_obstacle(Obstacle(near, float(r["height_m"]), depth))
        self.trial = {
            "index": r["index"], "near": near, "far": near + depth, "x0": x0, "past_m": float(r.get("past_m", 0.45)),
            "t0_sim": self.leg.t_s, "t0_mono": now_mono, "n_td0": len(self.tracker.footfalls_x_m),
            "contact": False, "crossing_mono": None, "height_m": float(r["height_m"]),
        }
        self.state = "running"

    def update(self, now_mono: float) -> dict[str, Any] | None:
        """After each physics step; returns the ground truth when a trial ends."""
        plant = self.plant
        n_before = len(self.tracker.footfalls_x_m)
        if self.tracking:
            self.tracker.update()
        if self.state == "idle":
            return None
        if self.state == "rewind":
            if plant.contacts()[0] or plant.foot_position()[1] < 0.02:
                return None
            plant.rewind_rail(REWIND_AFTER_M)
            self.state = "place"
        if self.state == "place":
            self._place(now_mono)
            return None
        tr = self.trial
        x = plant.carriage_x_m
        if not tr["contact"] and x > tr["near"] - 1.0:
            tr["contact"] = plant.obstacle_contact()
        if tr["crossing_mono"] is None and len(self.tracker.footfalls_x_m) > n_before \
                and self.tracker.footfalls_x_m[-1] >= tr["near"]:
            tr["crossing_mono"] = now_mono
        if x < tr["far"] + tr["past_m"]:
            return None
        plant.clear_obstacles()
        self.state = "idle"
        near = tr["near"]
        footfalls = self.tracker.footfalls_x_m[tr["n_td0"]:]
        return {
            "op": "trial_done",
            "index": tr["index"],
            "success": not tr["contact"],
            "start_distance_m": near - tr["x0"],
            "obstacle_height_m": tr["height_m"],
            "footfalls_m": [f - near for f in footfalls if f < near],
            "t0_mono": tr["t0_mono"],
            "crossing_mono": tr["crossing_mono"] if tr["crossing_mono"] is not None else now_mono,
            "end_mono": now_mono,
            "sim_s": self.leg.t_s - tr["t0_sim"],
        }


class IdleClock:
    """When each axis last entered IDLE, on the monotonic clock [s] (None while not IDLE), checked
    at every wake-up of the plant (1 ms natively, 2 ms inside User-Mode Linux)."""

    def __init__(self, leg: SimulatedLeg) -> None:
        self.axes = list(leg.axes.items())
        self.idle_since: dict[str, float | None] = {n: None for n, _ in self.axes}
        self.entries: dict[str, int] = {n: 0 for n, _ in self.axes}

    def update(self, now_mono: float) -> None:
        since = self.idle_since
        for name, axis in self.axes:
            idle = axis.state is AxisState.IDLE
            if idle != (since[name] is not None):
                since[name] = now_mono if idle else None
                self.entries[name] += idle


def axes_status(leg: SimulatedLeg, idle: IdleClock | None = None) -> dict[str, Any]:
    out = {}
    for name, axis in leg.axes.items():
        errors = int(axis.errors)
        out[name] = {
            "state": getattr(axis.state, "name", str(axis.state)),
            "errors": errors,
            "watchdog_expired": bool(errors & AxisError.WATCHDOG_TIMER_EXPIRED),
            "rx_set_input_pos": int(axis.stats["rx"].get("Set_Input_Pos", 0)),
            "targets_outside_limits": int(axis.stats.get("targets_outside_limits", 0)),
            "pos_limits_rev": [axis.config.pos_min_rev, axis.config.pos_max_rev],
            "idle_since_mono": None if idle is None else idle.idle_since[name],
            "idle_entries": None if idle is None else idle.entries[name],
        }
    return out


def run_firmware(bus_kw: dict[str, Any], *, seed: int = 0, gui: bool = False, scenario: str | None = None,
                 range_noise_m: float | None = None, range_dropout_prob: float | None = None,
                 duration_s: float | None = None, steps_per_wake: int | None = None) -> dict[str, Any]:
    """Run until SIGTERM/SIGINT, a ``quit`` on the side channel or ``duration_s`` of simulated
    time. ``steps_per_wake``: physics steps done at each wake-up (default 1; 2 inside User-Mode
    Linux, where a wake-up costs far more: physics stays at 1 kHz, paced in 2 ms slices).

    Raises:
        InputError: the side channel's address cannot be served (:class:`hil.session.scenario.SideChannel`).
        BusError: the bus cannot be opened (:func:`controller.daemon.openbus.open_bus`).
    """
    stop = {"flag": False}

    def on_signal(signum, frame):  # noqa: ARG001
        stop["flag"] = True

    hw = LegHardware()
    sensor = hw.sensor
    if range_noise_m is not None:
        sensor = replace(sensor, range_noise_m=range_noise_m)
    if range_dropout_prob is not None:
        sensor = replace(sensor, range_dropout_prob=range_dropout_prob)
    hw = replace(hw, sensor=sensor)
    rig = RigConfig()
    chan = SideChannel(scenario) if scenario else None  # first: a bad address costs no bus and no plant
    try:
        bus = open_bus(bus_kw)
        # from here on a stop signal ends the run in order (the plant's start-up included)
        signal.signal(signal.SIGTERM, on_signal)
        signal.signal(signal.SIGINT, on_signal)
        try:
            leg = SimulatedLeg(lean(bus, timestamps=False), rig=rig, hardware=hw, seed=seed, gui=gui)
        except BaseException:
            bus.shutdown()
            raise
    except BaseException:
        if chan is not None:
            chan.close()
        raise
    scen = Scenario(leg)
    if steps_per_wake is None:
        from hil.profile import current

        steps_per_wake = current().plant_steps_per_wake
    k = max(1, int(steps_per_wake))
    pacer = Pacer(leg.dt_s * k, catch_up=True)
    watchdog_trips = 0
    was_expired = {n: False for n in leg.axes}
    idle = IdleClock(leg)
    poll_every = max(1, int(round(0.005 / (leg.dt_s * k))))  # side channel every 5 ms
    steps = 0
    bye = False
    log.info("firmware-sim on %s: physics at %.0f Hz, real time", bus_kw, 1.0 / leg.dt_s)
    t_end = math.inf if duration_s is None else duration_s
    try:
        pacer.start()
        scen.tracking = True
        while not stop["flag"] and leg.t_s < t_end:
            now = pacer.wait()
            for _ in range(k):
                leg.step()
                done = scen.update(now)
                if done is not None and chan is not None:
                    chan.send(done)
            idle.update(now)
            steps += 1
            if steps % poll_every:
                continue
            for name, axis in leg.axes.items():
                expired = bool(int(axis.errors) & AxisError.WATCHDOG_TIMER_EXPIRED)
                if expired and not was_expired[name]:
                    watchdog_trips += 1
                    log.warning("watchdog expired on %s at t=%.3f s", name, leg.t_s)
                was_expired[name] = expired
            if chan is None:
                continue
            for req in chan.poll():
                op = req.get("op")
                if op == "status":
                    chan.send(status(leg, pacer, watchdog_trips, now, idle))
                elif op == "trial":
                    try:
                        scen.start(req)
                    except (RuntimeError, KeyError, ValueError) as exc:
                        chan.send({"op": "error", "error": str(exc)})
                elif op == "quit":
                    chan.send({**status(leg, pacer, watchdog_trips, now, idle), "op": "bye"})
                    bye = True
                    stop["flag"] = True
                elif op == "disconnected":
                    pass
                else:
                    chan.send({"op": "error", "error": f"unknown request {req!r}"})
    finally:
        final = status(leg, pacer, watchdog_trips, time.monotonic(), idle)
        if chan is not None:
            if not bye:
                chan.send({**final, "op": "bye"})
            chan.close()
        leg.close()
        bus.shutdown()
    return final


def status(leg: SimulatedLeg, pacer: Pacer, watchdog_trips: int, now: float,
           idle: IdleClock | None = None) -> dict[str, Any]:
    return {
        "op": "status",
        "t_s": leg.t_s,
        "mono": now,
        "axes": axes_status(leg, idle),
        "watchdog_trips": watchdog_trips,
        "host": dict(leg.host.stats),
        "pacing": pacer.summary(),
        "cpu_s": sum(os.times()[:2]),
    }
