"""Bring-up's move check: arm one axis, move it a little and slowly, move it back, disarm it.

For one axis (:func:`move_axis`): Clear_Errors, Set_Controller_Mode(POSITION_CONTROL,
PASSTHROUGH), Set_Limits (the axis's configured velocity and current limits, as the controller
arms), Set_Axis_State(CLOSED_LOOP_CONTROL), holding the measured position with
Set_Input_Pos from the first request on (the driver's 100 ms watchdog runs from the moment it
arms, which its next heartbeat reports up to 100 ms later); once a heartbeat reports
CLOSED_LOOP_CONTROL, a short settle, then a cosine ramp of ``step_rad`` over ``ramp_s`` (velocity
feed-forward from the ramp's slope), a hold, the same ramp back, a hold, and
Set_Axis_State(IDLE), repeated until a heartbeat reports IDLE. Targets go out at ``rate_hz``
(100-1000 Hz), every one through :meth:`controller.io.axis.AxisLink.pos_frame` (clamped into the
joint limits). The step is ``+step_rad`` unless that would end within ``limit_margin_rad`` of
the upper limit: then ``-step_rad``, towards the middle of the range.

Checklist items, per axis: ``closed loop`` (armed), ``move`` (the measured joint change after the
ramp and hold has the sign of the command and lies within ``follow_tolerance`` of it),
``move back`` (back within ``follow_tolerance`` of the step from where it started), ``IDLE``
(a heartbeat after the IDLE request reports IDLE with no error).

The move aborts (IDLE at once, the item FAILs with the cause) when a heartbeat reports the axis
out of closed loop or with an error, when the measured joint angle leaves ``[min_rad,
max_rad]``, or when encoder estimates (``feedback_timeout_s``) or heartbeats
(``heartbeat_timeout_s``) stop coming. The joint angle comes from the axis's own encoder through
the configured gear ratio, direction and zero offset: the check shows that the axis follows its
commands (armed, free to move, gains and current limit adequate); it cannot see a wrong
``direction`` or ``gear_ratio`` by itself, since the driver closes its loop on the same encoder.
Those show in the position check against the joint limits (:mod:`controller.bringup.procedure`).

May import: the standard library, python-can, ``protocol``, ``controller``.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Any, Callable

from controller.io.axis import AxisLink
from controller.bringup.bus import BusError, BusWatch
from controller.bringup.checklist import Checklist, Status
from protocol import AxisError, AxisState, ControlMode, InputMode, remote_frame

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class MoveConfig:
    """The move check.

    Attributes:
        step_rad: the joint move [rad]; default 0.1.
        ramp_s: duration of each cosine ramp (out and back) [s]; default 1.0.
        settle_s: hold after the axis reports closed loop, before the ramp [s]; default 0.2.
        hold_s: hold after each ramp before measuring [s]; default 0.3.
        rate_hz: Set_Input_Pos rate [Hz], 100-1000 (the driver's watchdog is 0.1 s); default 200.
        follow_tolerance: the measured change may differ from the command by this fraction of
            the step; default 0.5.
        limit_margin_rad: the move's end stays this far inside the joint limits [rad]; 0.02.
        state_timeout_s: wait this long for a heartbeat to report closed loop or IDLE [s]; 1.0.
        feedback_timeout_s: abort with no encoder estimate for this long [s]; default 0.2.
        heartbeat_timeout_s: abort with no heartbeat for this long [s]; default 1.0.
        poll_feedback_s: request encoder estimates (RTR) when the last is older than this [s]
            (for drivers whose cyclic encoder message is off); default 0.02.
    """

    step_rad: float = 0.1
    ramp_s: float = 1.0
    settle_s: float = 0.2
    hold_s: float = 0.3
    rate_hz: float = 200.0
    follow_tolerance: float = 0.5
    limit_margin_rad: float = 0.02
    state_timeout_s: float = 1.0
    feedback_timeout_s: float = 0.2
    heartbeat_timeout_s: float = 1.0
    poll_feedback_s: float = 0.02

    def __post_init__(self) -> None:
        bounds = {
            "step_rad": (0.001, 0.5), "ramp_s": (0.1, 10.0), "settle_s": (0.0, 5.0), "hold_s": (0.05, 5.0),
            "rate_hz": (100.0, 1000.0), "follow_tolerance": (0.01, 0.99), "limit_margin_rad": (0.0, 0.5),
            "state_timeout_s": (0.2, 10.0), "feedback_timeout_s": (0.01, 1.0), "heartbeat_timeout_s": (0.2, 10.0),
            "poll_feedback_s": (0.001, 1.0),
        }
        for name, (lo, hi) in bounds.items():
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and lo <= value <= hi):
                raise ValueError(f"MoveConfig.{name} must be in [{lo}, {hi}], got {value!r}")


def error_names(bits: int) -> str:
    """ODrive 0.6 error bits as names, e.g. "ESTOP_REQUESTED|WATCHDOG_TIMER_EXPIRED" ("none" for 0)."""
    if not bits:
        return "none"
    names = [e.name for e in AxisError if e.value and bits & e.value]
    unknown = bits & ~sum(e.value for e in AxisError)
    if unknown:
        names.append(f"unknown bits {unknown:#x}")
    return "|".join(names)


def cosine_ramp(t_s: float, duration_s: float, start_rad: float, delta_rad: float) -> tuple[float, float]:
    """(target [rad], velocity feed-forward [rad/s]) at ``t_s`` of a cosine ramp from ``start_rad``
    by ``delta_rad`` over ``duration_s``: zero velocity at both ends."""
    x = min(max(t_s / duration_s, 0.0), 1.0)
    q = start_rad + delta_rad * 0.5 * (1.0 - math.cos(math.pi * x))
    qd = 0.0 if x in (0.0, 1.0) else delta_rad * 0.5 * math.pi / duration_s * math.sin(math.pi * x)
    return q, qd


def choose_step(q_rad: float, min_rad: float, max_rad: float, config: MoveConfig) -> float | None:
    """The signed step from ``q_rad``: +step_rad if it ends at least ``limit_margin_rad`` inside
    the upper limit, else -step_rad (towards the middle) if that ends inside the lower; None if
    neither fits."""
    step, margin = config.step_rad, config.limit_margin_rad
    if min_rad + margin <= q_rad + step <= max_rad - margin:
        return step
    if min_rad + margin <= q_rad - step <= max_rad - margin:
        return -step
    return None


class _Aborted(Exception):
    """The move stopped: the axis left closed loop, reported an error, left its limits or fell silent."""


class AxisMove:
    """One axis's move check on a :class:`BusWatch` (see the module docstring)."""

    def __init__(self, watch: BusWatch, link: AxisLink, config: MoveConfig, checklist: Checklist) -> None:
        self.w = watch
        self.link = link
        self.cfg = config
        self.list = checklist
        self.node = link.config.node_id
        self.name = link.name
        self.info: dict[str, Any] = {}
        self.armed_s = math.inf  # heartbeats after this must report closed loop
        self.max_tracking_error_rad = 0.0
        self._enc_arb = link.encoder_id
        self._enc_dlc = watch.contract.codec("Get_Encoder_Estimates").dlc
        self._last_poll_s = -math.inf

    # -- what the axis reports -----------------------------------------------------------
    def q_rad(self) -> float:
        e = self.w.encoders.get(self.node)
        return math.nan if e is None else self.link.config.rev_to_rad(e.pos_rev)

    def _problem(self, now_s: float) -> str | None:
        """Why the move must stop now, or None."""
        c, cfg = self.link.config, self.cfg
        hb = self.w.heartbeats.get(self.node)
        if hb is not None and hb.t_s > self.armed_s and (hb.state != AxisState.CLOSED_LOOP_CONTROL or hb.error):
            return f"the axis left closed loop: heartbeat {hb.state_name}, errors {error_names(hb.error)}"
        if hb is None or now_s - hb.t_s > cfg.heartbeat_timeout_s:
            return f"no heartbeat for more than {cfg.heartbeat_timeout_s:g} s"
        e = self.w.encoders.get(self.node)
        if e is None or now_s - e.t_s > cfg.feedback_timeout_s:
            return f"no encoder estimate for more than {cfg.feedback_timeout_s:g} s"
        q = self.q_rad()
        if not c.min_rad <= q <= c.max_rad:
            return f"the measured angle {q:+.3f} rad left the joint limits [{c.min_rad:g}, {c.max_rad:g}] rad"
        return None

    # -- driving -------------------------------------------------------------------------
    def _drive(self, duration_s: float, target: Callable[[float], tuple[float, float]],
               until: Callable[[], bool] | None = None, check: Callable[[float], str | None] | None = None) -> bool:
        """Send ``target(t)`` (t from 0 [s]) at ``rate_hz`` for ``duration_s`` or until ``until()``;
        ``check(now)`` returning a reason raises :class:`_Aborted`. Returns whether ``until()``
        came true (True at the end of the duration when no ``until`` is given)."""
        w, period = self.w, 1.0 / self.cfg.rate_hz
        t0 = w.clock()
        next_s = t0
        while True:
            w.drain()
            now = w.clock()
            if check is not None:
                problem = check(now)
                if problem is not None:
                    raise _Aborted(problem)
            if until is not None and until():
                return True
            t = now - t0
            if t >= duration_s:
                return until is None
            q, qd = target(t)
            w.send(self.link.pos_frame(q, qd))
            q_meas = self.q_rad()
            if math.isfinite(q_meas):
                self.max_tracking_error_rad = max(self.max_tracking_error_rad, abs(self.link.last_target_rad - q_meas))
            e = w.encoders.get(self.node)
            poll_s = self.cfg.poll_feedback_s
            if (e is None or now - e.t_s > poll_s) and now - self._last_poll_s > poll_s:
                w.send(remote_frame(self._enc_arb, self._enc_dlc))
                self._last_poll_s = now
            next_s = max(next_s + period, w.clock())  # behind after a stall: skip, never bunch frames
            w.sleep(max(next_s - w.clock(), 0.0))

    def _hold_here(self) -> Callable[[float], tuple[float, float]]:
        """A target that follows the measured angle (while the axis arms)."""
        def target(_t: float) -> tuple[float, float]:
            q = self.q_rad()
            if not math.isfinite(q):
                raise _Aborted("no encoder estimate to hold")
            return q, 0.0
        return target

    # -- the check -----------------------------------------------------------------------
    def arm(self) -> bool:
        """Clear_Errors, mode, closed loop; hold until a heartbeat reports CLOSED_LOOP_CONTROL."""
        w, link, name = self.w, self.link, f"{self.name}: closed loop"
        if not math.isfinite(self.q_rad()):
            self.list.add(name, Status.FAIL, "not armed: no encoder estimate to hold")
            return False
        w.drain()  # heartbeats waiting now were sent before the request
        t_req = w.clock()
        for frame in (link.clear_errors_frame(), link.mode_frame(ControlMode.POSITION_CONTROL, InputMode.PASSTHROUGH),
                      link.limits_frame(), link.state_frame(AxisState.CLOSED_LOOP_CONTROL)):
            w.send(frame)

        def armed() -> bool:
            hb = w.heartbeats.get(self.node)
            return hb is not None and hb.t_s > t_req and hb.state == AxisState.CLOSED_LOOP_CONTROL and not hb.error

        def disarmed(_now: float) -> str | None:
            hb = w.heartbeats.get(self.node)
            if hb is not None and hb.t_s > t_req and hb.error:
                return f"it refused: heartbeat {hb.state_name}, errors {error_names(hb.error)}"
            return None

        try:
            ok = self._drive(self.cfg.state_timeout_s, self._hold_here(), until=armed, check=disarmed)
        except _Aborted as exc:
            w.send(link.state_frame(AxisState.IDLE))
            self.list.add(name, Status.FAIL, f"Set_Axis_State(CLOSED_LOOP_CONTROL) sent; {exc}")
            return False
        hb = w.heartbeats.get(self.node)
        if not ok:
            state = "no heartbeat" if hb is None else f"heartbeat {hb.state_name}, errors {error_names(hb.error)}"
            self.list.add(name, Status.FAIL, f"not in CLOSED_LOOP_CONTROL {self.cfg.state_timeout_s:g} s after the "
                                             f"request ({state}): is the motor calibrated, the encoder ready?")
            return False
        self.armed_s = hb.t_s
        self.info["arm_s"] = round(hb.t_s - t_req, 4)
        c = link.config
        self.list.add(name, Status.PASS, f"CLOSED_LOOP_CONTROL {hb.t_s - t_req:.2f} s after the request "
                                         f"(POSITION_CONTROL, PASSTHROUGH; limits {c.vel_limit_rev_s:g} rev/s, "
                                         f"{c.current_limit_a:g} A)")
        return True

    def _ramp_and_hold(self, start_rad: float, delta_rad: float) -> float:
        """Ramp the target from ``start_rad`` by ``delta_rad``, hold; the measured angle [rad]."""
        cfg = self.cfg
        self._drive(cfg.ramp_s, lambda t: cosine_ramp(t, cfg.ramp_s, start_rad, delta_rad), check=self._problem)
        end = start_rad + delta_rad
        self._drive(cfg.hold_s, lambda t: (end, 0.0), check=self._problem)
        return self.q_rad()

    def move(self) -> None:
        """Settle, move out, check, move back, check. Adds the ``move`` and ``move back`` items."""
        c, cfg = self.link.config, self.cfg
        hold = self.q_rad()
        name_out, name_back = f"{self.name}: move", f"{self.name}: move back"
        step = choose_step(hold, c.min_rad, c.max_rad, cfg)
        if step is None:
            self.list.add(name_out, Status.FAIL, f"no room for a {cfg.step_rad:g} rad move at {hold:+.3f} rad in "
                                                 f"[{c.min_rad:g}, {c.max_rad:g}] rad")
            self.list.add(name_back, Status.SKIP, "no move out")
            return
        stage = name_out
        try:
            self._drive(cfg.settle_s, lambda t: (hold, 0.0), check=self._problem)
            q0 = self.q_rad()
            q1 = self._ramp_and_hold(hold, step)
            change = q1 - q0
            self.info.update(start_rad=round(q0, 5), step_rad=step, out_rad=round(q1, 5), change_rad=round(change, 5))
            ratio = change / step
            detail = (f"commanded {step:+.3f} rad over {cfg.ramp_s:g} s from {q0:+.3f} rad, measured {change:+.3f} rad "
                      f"({ratio:.0%})")
            if ratio <= 0.0:
                self.list.add(name_out, Status.FAIL, f"{detail}: it moved the other way or not at all (blocked? "
                                                     "encoder and motor disagree?)")
            elif abs(ratio - 1.0) > cfg.follow_tolerance:
                self.list.add(name_out, Status.FAIL, f"{detail}: outside {1 - cfg.follow_tolerance:.0%}-"
                                                     f"{1 + cfg.follow_tolerance:.0%} (blocked, gains, current limit?)")
            else:
                self.list.add(name_out, Status.PASS, detail)
            stage = name_back
            q2 = self._ramp_and_hold(hold + step, -step)
            self.info.update(back_rad=round(q2, 5), max_tracking_error_rad=round(self.max_tracking_error_rad, 5))
            off = q2 - q0
            detail = (f"back to {q2:+.3f} rad, {off:+.3f} rad from the start; tracking error up to "
                      f"{self.max_tracking_error_rad:.3f} rad")
            ok = abs(off) <= cfg.follow_tolerance * abs(step)
            self.list.add(name_back, Status.PASS if ok else Status.FAIL,
                          detail if ok else f"{detail}: more than {cfg.follow_tolerance:.0%} of the step")
        except _Aborted as exc:
            self.w.send(self.link.state_frame(AxisState.IDLE))
            self.info["aborted"] = str(exc)
            self.list.add(stage, Status.FAIL, f"aborted, IDLE sent: {exc}")
            if stage == name_out:
                self.list.add(name_back, Status.SKIP, "the move out was aborted")

    def disarm(self) -> None:
        """IDLE, repeated every 0.1 s, until a heartbeat reports it; adds the ``IDLE`` item."""
        w, name = self.w, f"{self.name}: IDLE"
        w.drain()
        t_req = w.clock()
        deadline = t_req + self.cfg.state_timeout_s
        while True:
            sent_s = w.clock()
            w.send(self.link.state_frame(AxisState.IDLE))
            if w.wait(lambda: self._idle_after(t_req), 0.1):
                break
            if w.clock() >= deadline:
                hb = w.heartbeats.get(self.node)
                state = "no heartbeat" if hb is None or hb.t_s <= sent_s else f"heartbeat {hb.state_name}"
                self.list.add(name, Status.FAIL, f"not IDLE {self.cfg.state_timeout_s:g} s after "
                                                 f"Set_Axis_State(IDLE) ({state}): cut its power")
                return
        hb = w.heartbeats[self.node]
        if hb.error:
            self.list.add(name, Status.FAIL, f"IDLE, with errors {error_names(hb.error)}")
        else:
            self.list.add(name, Status.PASS, f"IDLE {hb.t_s - t_req:.2f} s after the request, no error")

    def _idle_after(self, t_s: float) -> bool:
        hb = self.w.heartbeats.get(self.node)
        return hb is not None and hb.t_s > t_s and hb.state == AxisState.IDLE


def move_axis(watch: BusWatch, link: AxisLink, config: MoveConfig, checklist: Checklist) -> dict[str, Any]:
    """Arm, move out and back, disarm one axis; items as in the module docstring. The axis is sent
    IDLE whatever happens (an exception included). Returns the measurements."""
    m = AxisMove(watch, link, config, checklist)
    try:
        if m.arm():
            m.move()
        else:
            for suffix in ("move", "move back"):
                checklist.add(f"{link.name}: {suffix}", Status.SKIP, "not in closed loop")
    finally:
        try:
            m.disarm()
        except BusError:
            log.error("could not send IDLE to %s (node %d)", link.name, link.config.node_id)
            raise
    return m.info
