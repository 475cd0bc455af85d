"""The ``firmware-sim --clock sim`` process: the simulated leg on a real CAN bus, on simulated time.

In simulated time the plant owns the clock (:mod:`controller.daemon.simclock` is the controller's
side, :class:`hil.lockstep.synced.SimTimePlant` this side): after each control period's physics
steps it sends ``ES_Sim_Sync`` with its time and steps on when the controller's
``ES_End_Of_Period`` for that time has arrived. Nothing here reads the wall clock except the
grace after which a silent controller is declared gone, so the same seed gives the same run,
however loaded the host is.

The experiment runs here, beside the plant, because only here is every physics step seen: the
learning run of :class:`hil.experiments.learn.LearningRun`, unchanged, with the controller in
the other process (its ``loop`` a :class:`~hil.lockstep.synced.RemoteLoop`: the phase from
``ES_Controller_State``). The trial schedule (bring-up, one second of walking, each obstacle's
start distance from the seed, rewinds, the trial's end) is therefore the in-process run's, at
the same simulated instants.

The side channel (:mod:`hil.session.scenario`, JSON lines; the bus carries none of it):

- request ``{"op": "learn", "trials", "seed", "obstacle_height_m", "range_noise_m", "learning",
  "trace_trials", "grace_s", "silence_node", "silence_at_trial", "event_after_s"}``: build the plant, open
  simulated time (the controller may start after this), run the trials;
- replies ``{"op": "trial_done", "trial": {...}, "times": {"t0_s", "crossing_s", "end_s"}}`` per
  trial (the plant's half of ``learn``'s trial dict; the controller's fields are filled from its
  records afterwards, :func:`hil.session.simsession.fill_from_records`), then ``{"op": "learn_done"}``
  with the plant's figures, or ``{"op": "error", "error"}``;
- after ``learn_done`` the plant stops stepping (simulated time stands still: the controller
  waits for a sync) until ``{"op": "quit"}`` (sent once the controller has been stopped): the leg
  then runs on alone for :data:`AFTER_STOP_S` (the controller's IDLE frames reach the drivers)
  and replies ``bye`` with its axes; or SIGTERM.

Node silence (``silence_node``, ``silence_at_trial``, ``event_after_s``): ``event_after_s`` of
simulated time into that trial the node's frames stop (:meth:`SimTimePlant.silence`, its
transmitter dead); the controller must stop safely. The plant then steps on for
:data:`AFTER_EVENT_S` of simulated time and reports when each axis entered IDLE, in simulated time
after the silence (``safe_state``): the same on a loaded and a quiet host.
"""

from __future__ import annotations

import functools
import logging
import os
import signal
import time
from typing import Any

from controller.daemon.fastbus import lean
from controller.daemon.openbus import open_bus
from protocol import AxisError, AxisState

log = logging.getLogger(__name__)

AFTER_EVENT_S = 1.0
"""After a silence, how long the plant steps on (simulated seconds) to see the safe state hold."""
AFTER_STOP_S = 0.1
"""After ``quit`` (the controller stopped), how long the leg runs on alone [simulated s] before
it reports its axes: the controller's last frames (IDLE) reach the drivers."""


def _axes(leg) -> dict[str, Any]:
    return {name: {"state": getattr(a.state, "name", str(a.state)), "errors": int(a.errors),
                   "watchdog_expired": bool(int(a.errors) & AxisError.WATCHDOG_TIMER_EXPIRED),
                   "rx_set_input_pos": int(a.stats["rx"].get("Set_Input_Pos", 0)),
                   "targets_outside_limits": int(a.stats.get("targets_outside_limits", 0)),
                   "pos_limits_rev": [a.config.pos_min_rev, a.config.pos_max_rev]}
            for name, a in leg.axes.items()}


def _figures(ls, wall0: float, cpu0: float) -> dict[str, Any]:
    axes = _axes(ls.leg)
    return {"t_s": ls.t_s, "axes": axes, "host": dict(ls.leg.host.stats), "sync": dict(ls.plant_bus.stats),
            "watchdog_expired": sum(a["watchdog_expired"] for a in axes.values()),
            "controller_phase": ls.plant_bus.controller_phase, "controller_gone": ls.gone,
            "wall_s": time.monotonic() - wall0, "wall_waiting_s": ls.wall_waits_s,
            "cpu_s": sum(os.times()[:2]) - cpu0}


class _Silence:
    """The on_step hook of the silenced trial: silence the node ``after_s`` into it, then note
    when every axis is IDLE (simulated time)."""

    def __init__(self, node: int, after_s: float) -> None:
        self.node, self.after_s = node, after_s
        self.t0: float | None = None
        self.at_s: float | None = None
        self.idle_s: dict[str, float | None] = {}

    def __call__(self, ls) -> None:
        if self.t0 is None:
            self.t0 = ls.t_s
        if self.at_s is None and ls.t_s - self.t0 >= self.after_s:
            ls.silence(self.node)
            self.at_s = ls.t_s
            self.idle_s = {name: None for name in ls.leg.axes}
        if self.at_s is not None:
            for name, a in ls.leg.axes.items():
                idle = a.state is AxisState.IDLE
                if idle and self.idle_s[name] is None:
                    self.idle_s[name] = ls.t_s
                elif not idle:
                    self.idle_s[name] = None

    def result(self) -> dict[str, Any]:
        if self.at_s is None:
            return {"node": self.node, "at_s": None}
        after = {n: None if t is None else (t - self.at_s) * 1e3 for n, t in self.idle_s.items()}
        return {"node": self.node, "at_s": self.at_s, "axes_idle_sim_ms": after,
                "safe_state_sim_ms": None if None in after.values() else max(after.values())}


def run_sim_plant(bus_kw: dict[str, Any], *, scenario: str, gui: bool = False) -> dict[str, Any]:
    """Serve one learning run in simulated time (see the module doc) until ``quit`` or a stop
    signal; returns the plant's figures.

    Raises:
        InputError: the side channel's address cannot be served.
        BusError: the bus cannot be opened.
    """
    from hil.experiments.learn import LearnConfig, LearningRun
    from hil.lockstep.synced import SimTimePlant
    from hil.session.scenario import SideChannel

    stop = {"flag": False}

    def on_signal(signum, frame):  # noqa: ARG001
        stop["flag"] = True

    chan = SideChannel(scenario)
    try:
        raw = open_bus(bus_kw)
    except BaseException:
        chan.close()
        raise
    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    bus = lean(raw, timestamps=False)
    run = None
    figures: dict[str, Any] = {}
    wall0, cpu0 = time.monotonic(), sum(os.times()[:2])
    try:
        request = _wait_for(chan, stop, ("learn", "quit"))
        if request is None or request["op"] == "quit":
            chan.send({"op": "bye"})
            return {}
        try:
            config = LearnConfig(trials=int(request["trials"]), seed=int(request["seed"]),
                                 obstacle_height_m=float(request["obstacle_height_m"]),
                                 range_noise_m=float(request["range_noise_m"]), learning=bool(request["learning"]),
                                 trace_trials=tuple(int(k) for k in request.get("trace_trials", ())))
        except (KeyError, TypeError, ValueError) as exc:
            chan.send({"op": "error", "error": f"bad learn request: {exc}"})
            return {}
        harness = functools.partial(SimTimePlant, bus=bus, grace_s=request.get("grace_s"), gui=gui,
                                    alive=lambda: not stop["flag"])
        try:
            run = LearningRun(config, harness=harness)  # opens simulated time: waits for the controller
        except RuntimeError as exc:
            chan.send({"op": "error", "error": str(exc)})
            return {}
        log.info("firmware-sim on %s: simulated time, %d trials, seed %d", bus_kw, config.trials, config.seed)
        silence = None
        if request.get("silence_node") is not None:
            silence = _Silence(int(request["silence_node"]), float(request.get("event_after_s", 1.0)))
        at_trial = request.get("silence_at_trial")
        error = None
        try:
            run.bring_up()
            for i in range(config.trials):
                if stop["flag"]:
                    error = "stopped by a signal"
                    break
                hook = silence if silence is not None and i == at_trial else None
                trial = run.trial(i, on_step=hook)
                chan.send({"op": "trial_done", "trial": trial, "times": dict(run.last_times)})
        except RuntimeError as exc:  # the controller stopped safely (LearningRun's "safe stop during trial")
            error = str(exc)
        if silence is not None and silence.at_s is not None:
            end = run.ls.t_s + AFTER_EVENT_S
            while run.ls.t_s < end and not stop["flag"]:
                run.ls.step()
                silence(run.ls)
        figures = _figures(run.ls, wall0, cpu0)
        if silence is not None:
            figures["silence"] = silence.result()
        chan.send({"op": "learn_done", "error": error, **figures})
        _wait_for(chan, stop, ("quit",))  # simulated time stands still until then
        # The controller has been stopped (its last frames, IDLE to every axis, are on the bus):
        # the leg runs on alone, without syncs, for AFTER_STOP_S so its drivers act on them.
        for _ in range(int(round(AFTER_STOP_S / run.ls.leg.dt_s))):
            run.ls.leg.step()
        figures = {**figures, **_figures(run.ls, wall0, cpu0)}
        chan.send({**figures, "op": "bye"})
    finally:
        if run is not None:
            run.close()
        chan.close()
        raw.shutdown()
    return figures


def _wait_for(chan, stop: dict[str, bool], ops: tuple[str, ...]) -> dict[str, Any] | None:
    """The next side-channel request whose op is in ``ops`` (others answered with an error), or
    None on a stop signal."""
    while not stop["flag"]:
        for req in chan.poll():
            op = req.get("op")
            if op in ops:
                return req
            if op not in ("disconnected", None):
                chan.send({"op": "error", "error": f"not now: {req!r}"})
        time.sleep(0.02)
    return None


__all__ = ["run_sim_plant", "AFTER_EVENT_S"]
