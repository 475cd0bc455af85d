"""The man-in-the-middle node: a faulty gateway between the controller's bus and the leg's.

``elegant-stepping mitm --controller-channel vcan0 --leg-channel vcan1 --to-leg SPEC --from-leg
SPEC --seed N [--clock {wall,sim}] [--silence-node ID --silence-after-s T | --silence-at-sim-s T]
[--json FILE]`` forwards every frame
between two SocketCAN channels, each direction through its own :class:`hil.faults.model.FaultInjector`
(``SPEC`` in :meth:`hil.faults.model.FaultSpec.parse` form, e.g. ``drop=0.05``; the two generators are
spawned from ``N`` as :class:`hil.faults.model.FaultyBus` spawns its own). It can silence one node: from
``T`` seconds after start, or from the moment it gets SIGUSR1, every frame the leg sends whose
``arbitration_id >> 5`` is that node is dropped (the leg -> controller direction only: the node
still hears the controller, as when its transmitter dies).

Simulated time (``--clock sim``, the mode of ``hil --clock sim``): the plant's ``ES_Sim_Sync``
frames are the faults' clock. **The rule.** A frame on one of the simulated-time ids
(:data:`~protocol.contract.SIM_TIME_IDS`: extended, not an error frame) never meets an injector or
the silence: it is forwarded untouched, right after every frame of its direction that is ready at
the current simulated time. That time is the ``Sim_Time`` of the last sync that passed from the leg
to the controller (0.0 before the first; a malformed sync, or a stale one earlier than the clock,
is forwarded and counted, never used as the clock: it never runs back). Both injectors run on it
(``delay_s``, ``reorder_max_s`` are simulated seconds), and when it moves on, each direction sends
what became due. Frames are taken one at a time (pushed, then what is ready sent), so the
wake-ups' batching plays no part. The silence starts at the
first sync whose time is at or past ``--silence-at-sim-s`` (SIGUSR1: at the next sync), and its
start is reported in simulated time (``silence.started_sim_s``). **The reason.** The controller
ticks on the frames before each sync and the plant steps on at each end-of-period
(:mod:`controller.daemon.simclock`), so which frames a period gets must depend on the frames
alone. On the wall clock a delay or a reorder timeout ends wherever the host's load puts it, and
a frame released one wake-up later lands in the next period: the 5%-loss row would differ between
a loaded and a quiet machine. Here the same frames in give the same frames out, in the same
order, however the wake-ups split them and whatever the wall time. (Each pump reads the
controller's side first; that is the frames' true order, since the controller answers a sync only
after this node has forwarded it.) ``--silence-after-s`` is wall time and refused in this mode.

Pacing, on the monotonic clock: the node waits in one ``poll()`` on both sockets until a frame
is there, reads every waiting frame from the non-blocking sockets (:func:`controller.daemon.fastbus.lean`: one
``recv`` per frame), sends what is due, then sleeps ``poll_s`` before it polls again, so the
frames that arrive meanwhile are handled in one batch. While the injectors hold frames (delayed,
held for reordering) it polls every ``poll_s`` to release them on time (on the wall clock only: in
simulated time a held frame waits for a sync, which wakes the node anyway). Never a spin. A frame
waits at most ``poll_s`` (plus any fault delay) in the node; a quiet bus costs 20 wake-ups/s.

``poll_s`` comes from the platform profile (:mod:`hil.profile`): 0.5 ms natively and 2 ms inside
User-Mode Linux, where every wake-up and system call is a host ptrace round trip on the one
virtual CPU that the controller and the plant share; a shorter poll there costs the controller
late ticks and period jitter. The plant's process also works in 2 ms slices there.

SIGTERM or SIGINT stops it (exit 0); the clock (``"clock"``: ``"wall"`` or ``"sim"``), the counts per
direction (frames in, forwarded, each fault, silenced, simulated-time frames passed through, send
errors), the silence start, the simulated clock's syncs and the pacing figures are written as JSON at exit
(stamped ``format: "mitm-counts"``, ``format_version`` :data:`COUNTS_VERSION`; :func:`read_counts`
checks it).
Traffic stays on the two CAN channels: no network address is ever opened.
"""

from __future__ import annotations

import logging
import math
import os
import signal
import struct
import time
from pathlib import Path
from typing import Any, Callable

import can
import numpy as np

from controller.atomic import write_json_atomic
from controller.errors import stamp
from hil.faults.model import FAULT_KINDS, FaultInjector, FaultSpec
from protocol.contract import SIM_SYNC_ID, SIM_TIME_IDS

log = logging.getLogger(__name__)

COUNTS_KIND = "mitm-counts"
COUNTS_VERSION = 1  # the counts file's format version: raise it when a reader of the old one could misread it

def default_poll_s() -> float:
    """The pause after each batch on this platform [s] (:attr:`hil.profile.Profile.mitm_poll_s`)."""
    from hil.profile import current

    return current().mitm_poll_s
IDLE_WAIT_MS = 50  # longest wait in poll() with nothing held [ms]: how soon a signal's flag is seen
CLOCKS = ("wall", "sim")  # the node's clocks: the monotonic clock, or the plant's syncs (module doc)
_SYNC_TIME = struct.Struct("<d")  # ES_Sim_Sync's Sim_Time: a little-endian float64, the whole 8 bytes


def is_sim_time_frame(msg: can.Message) -> bool:
    """Is ``msg`` a frame of the simulated-time protocol (sync, end-of-period, controller state)?"""
    return msg.is_extended_id and not msg.is_error_frame and msg.arbitration_id in SIM_TIME_IDS


def sync_time_s(msg: can.Message) -> float | None:
    """The ``Sim_Time`` [s] of an ``ES_Sim_Sync`` frame; None if it is malformed (a remote frame,
    not 8 bytes, or a time that is not finite), as :class:`controller.daemon.simclock.SimClockBus`
    judges it."""
    if msg.is_remote_frame or msg.dlc != _SYNC_TIME.size or len(msg.data) != _SYNC_TIME.size:
        return None
    (t_s,) = _SYNC_TIME.unpack(bytes(msg.data))
    return t_s if math.isfinite(t_s) else None


class Link:
    """One direction of the gateway: frames from ``src`` to ``dst`` through an injector.

    ``silenced(msg)`` (if given) says whether a frame is to vanish before the injector sees it.
    Counts: ``frames_in`` (read from ``src``), ``silenced``, ``forwarded`` (sent to ``dst``),
    ``sim_frames`` (simulated-time frames passed through untouched, in simulated time; also in
    ``forwarded``), ``send_errors`` (sends that failed; the frame is lost), plus the injector's
    own counts.
    """

    def __init__(self, name: str, src: can.BusABC, dst: can.BusABC, injector: FaultInjector,
                 silenced: Callable[[can.Message], bool] | None = None) -> None:
        self.name = name
        self.src = src
        self.dst = dst
        self.injector = injector
        self.silenced = silenced
        self.frames_in = 0
        self.silenced_frames = 0
        self.forwarded = 0
        self.sim_frames = 0
        self.send_errors = 0

    def pump(self, now_s: float) -> int:
        """Read every frame waiting on ``src``, send every frame due at ``now_s`` [s] to ``dst``;
        returns the number of frames read."""
        recv, push, silenced = self.src.recv, self.injector.push, self.silenced
        n = 0
        msg = recv(0)
        while msg is not None:
            n += 1
            if silenced is not None and silenced(msg):
                self.silenced_frames += 1
            else:
                push(msg, now_s)
            msg = recv(0)
        self.frames_in += n
        send = self.dst.send
        for out in self.injector.pop_ready(now_s):
            try:
                send(out)
                self.forwarded += 1
            except can.CanError as exc:
                self.send_errors += 1
                if self.send_errors <= 3:
                    log.warning("%s: send failed: %s", self.name, exc)
        return n

    def forward(self, msg: can.Message) -> None:
        """Send ``msg`` to ``dst`` (a failed send is counted and logged, the frame lost)."""
        try:
            self.dst.send(msg)
            self.forwarded += 1
        except can.CanError as exc:
            self.send_errors += 1
            if self.send_errors <= 3:
                log.warning("%s: send failed: %s", self.name, exc)

    def flush(self, now_s: float) -> None:
        """Send every frame the injector has ready at ``now_s`` [s], in its order."""
        if self.injector.in_flight:
            for out in self.injector.pop_ready(now_s):
                self.forward(out)

    def counts(self) -> dict[str, int]:
        faults = self.injector.counts
        return {"frames_in": self.frames_in, "forwarded": self.forwarded, "silenced": self.silenced_frames,
                "sim_frames": self.sim_frames, "send_errors": self.send_errors, "in_flight": self.injector.in_flight,
                **{k: int(faults.get(k, 0)) for k in FAULT_KINDS}}


class ManInTheMiddle:
    """The gateway's logic on two buses, without sockets or clocks of its own (testable on
    python-can's ``virtual`` buses): :meth:`pump` with the current time [s] moves frames both ways.

    ``to_leg`` applies to frames from ``controller_bus`` to ``leg_bus``, ``from_leg`` to the other
    way. ``silence_node``: the node :meth:`start_silence` silences (leg -> controller only).

    ``sim_time``: run in simulated time (the module doc's rule): the injectors' clock is the last
    sync's time (:attr:`sim_now_s`), ``pump``'s ``now_s`` only stamps the silence's start on the
    monotonic clock. ``silence_at_sim_s`` [s, simulated; only with ``sim_time``]: silence
    ``silence_node`` from the first sync whose time is at or past it.
    """

    def __init__(self, controller_bus: can.BusABC, leg_bus: can.BusABC, *, to_leg: FaultSpec = FaultSpec(),
                 from_leg: FaultSpec = FaultSpec(), seed: int = 0, silence_node: int | None = None,
                 sim_time: bool = False, silence_at_sim_s: float | None = None) -> None:
        if silence_node is not None and not 0 <= silence_node <= 0x3F:
            raise ValueError(f"silence_node must be a node id 0..63, got {silence_node!r}")
        if silence_at_sim_s is not None:
            if not sim_time:
                raise ValueError("silence_at_sim_s is simulated time: it needs sim_time=True")
            if not math.isfinite(silence_at_sim_s):
                raise ValueError(f"silence_at_sim_s must be finite, got {silence_at_sim_s!r}")
        tx_rng, rx_rng = np.random.default_rng(seed).spawn(2)
        self.specs = {"to_leg": to_leg, "from_leg": from_leg}
        self.seed = seed
        self.silence_node = silence_node
        self.silence_started_mono: float | None = None
        self.silence_started_unix: float | None = None
        self.silence_started_sim_s: float | None = None
        self._silencing = False
        self.sim_time = sim_time
        self.silence_at_sim_s = silence_at_sim_s
        self.sim_now_s = 0.0  # the simulated clock [s]: the last well-formed sync from the leg
        self.syncs = 0  # well-formed syncs from the leg (clock readings)
        self.malformed_syncs = 0  # syncs from the leg forwarded but not used as the clock: unreadable
        self.stale_syncs = 0  # ... or earlier than the clock (the clock never runs back)
        self._silence_next_sync = False
        self.to_leg = Link("to_leg", controller_bus, leg_bus, FaultInjector(to_leg, tx_rng))
        self.from_leg = Link("from_leg", leg_bus, controller_bus, FaultInjector(from_leg, rx_rng), self._is_silenced)

    def _is_silenced(self, msg: can.Message) -> bool:
        return self._silencing and not msg.is_extended_id and (msg.arbitration_id >> 5) == self.silence_node

    @property
    def silencing(self) -> bool:
        return self._silencing

    def start_silence(self, now_s: float) -> None:
        """Silence :attr:`silence_node` from ``now_s`` [s, monotonic] on (a no-op without one or
        when already silencing). In simulated time the start is also stamped with
        :attr:`sim_now_s`."""
        if self.silence_node is None or self._silencing:
            return
        self._silencing = True
        self.silence_started_mono = now_s
        self.silence_started_unix = time.time()
        if self.sim_time:
            self.silence_started_sim_s = self.sim_now_s
            log.warning("silencing node %d from t=%.3f s (simulated %.6f s)", self.silence_node, now_s,
                        self.sim_now_s)
        else:
            log.warning("silencing node %d from t=%.3f s", self.silence_node, now_s)

    def silence_at_next_sync(self) -> None:
        """In simulated time: silence :attr:`silence_node` from the next sync from the leg on (what
        SIGUSR1 does in this mode, so a silence starts on a period boundary as
        ``silence_at_sim_s`` does)."""
        if not self.sim_time:
            raise RuntimeError("silence_at_next_sync is for simulated time; use start_silence")
        self._silence_next_sync = True

    def pump(self, now_s: float) -> int:
        """Move frames both ways at ``now_s`` [s, monotonic]; returns the number of frames read.
        In simulated time ``now_s`` changes no frame (it only stamps a silence's start)."""
        if self.sim_time:
            return self._pump_sim(self.to_leg, now_s) + self._pump_sim(self.from_leg, now_s)
        return self.to_leg.pump(now_s) + self.from_leg.pump(now_s)

    def _pump_sim(self, link: Link, now_s: float) -> int:
        """One direction in simulated time, one frame at a time (the module doc's rule)."""
        recv, push, silenced = link.src.recv, link.injector.push, link.silenced
        n = 0
        msg = recv(0)
        while msg is not None:
            n += 1
            if is_sim_time_frame(msg):
                link.sim_frames += 1
                if link is self.from_leg and msg.arbitration_id == SIM_SYNC_ID:
                    self._on_sync(msg, now_s)
                link.flush(self.sim_now_s)  # what is ready goes first: the period's frames, then its mark
                link.forward(msg)
            elif silenced is not None and silenced(msg):
                link.silenced_frames += 1
            else:
                push(msg, self.sim_now_s)
                link.flush(self.sim_now_s)
            msg = recv(0)
        link.frames_in += n
        return n

    def _on_sync(self, msg: can.Message, now_s: float) -> None:
        """A sync from the leg: the clock moves to its time (unless it is malformed, or stale:
        earlier than the clock), the controller's direction sends what became due, the silence
        starts if its time has come."""
        t_s = sync_time_s(msg)
        if t_s is None:
            self.malformed_syncs += 1
            if self.malformed_syncs <= 3:
                log.warning("a malformed ES_Sim_Sync from the leg (%r): forwarded, not used as the clock", msg)
            return
        if t_s < self.sim_now_s:
            self.stale_syncs += 1
            return
        self.syncs += 1
        self.sim_now_s = t_s
        self.to_leg.flush(t_s)
        if not self._silencing and (self._silence_next_sync or (self.silence_at_sim_s is not None
                                                                and t_s >= self.silence_at_sim_s)):
            self.start_silence(now_s)

    def summary(self) -> dict[str, Any]:
        return {
            "clock": "sim" if self.sim_time else "wall",
            "seed": self.seed,
            "specs": {k: v.describe() for k, v in self.specs.items()},
            "to_leg": self.to_leg.counts(),
            "from_leg": self.from_leg.counts(),
            "silence": {"node": self.silence_node, "started_mono": self.silence_started_mono,
                        "started_unix": self.silence_started_unix, "started_sim_s": self.silence_started_sim_s,
                        "at_sim_s": self.silence_at_sim_s},
            "sim_clock": ({"syncs": self.syncs, "malformed_syncs": self.malformed_syncs,
                           "stale_syncs": self.stale_syncs, "last_sync_s": self.sim_now_s} if self.sim_time else None),
        }


def _open(channel: str) -> tuple[can.BusABC, can.BusABC]:
    """(python-can's SocketCAN bus, its lean front without timestamps)."""
    from controller.daemon.fastbus import lean

    raw = can.Bus(interface="socketcan", channel=channel)
    return raw, lean(raw, timestamps=False)


def _write_json(path: str | Path | None, data: dict[str, Any]) -> None:
    """The counts to ``path`` (if any), stamped (:data:`COUNTS_KIND`, :data:`COUNTS_VERSION`)."""
    if path is None:
        return
    write_json_atomic(path, {**stamp(COUNTS_KIND, COUNTS_VERSION), **data}, indent=1)


def read_counts(path: str | Path) -> dict[str, Any]:
    """The counts :func:`run_mitm` wrote to ``path``, without the stamp.

    Raises:
        InputError: not JSON, another kind of file or another format version (one line).
        OSError: the file cannot be read.
    """
    from controller.errors import read_stamped_json

    return read_stamped_json(path, COUNTS_KIND, {COUNTS_VERSION})


class WakeStats:
    """Wake-ups of the node's loop: how many, how many found frames, frames per busy wake-up, and
    the longest time from a busy wake-up to the next one [s] (with traffic flowing, a stall of the
    node or of the machine; quiet periods of the bus are left out)."""

    def __init__(self) -> None:
        self.wakes = 0
        self.busy_wakes = 0
        self.max_gap_s = 0.0
        self._last_busy = math.nan

    def record(self, now_s: float, frames: int) -> None:
        self.wakes += 1
        gap = now_s - self._last_busy
        if gap > self.max_gap_s:
            self.max_gap_s = gap
        if frames > 0:
            self.busy_wakes += 1
            self._last_busy = now_s
        else:
            self._last_busy = math.nan

    def summary(self, frames: int) -> dict[str, Any]:
        return {"wakes": self.wakes, "busy_wakes": self.busy_wakes, "max_gap_ms": self.max_gap_s * 1e3,
                "frames_per_busy_wake": frames / self.busy_wakes if self.busy_wakes else None}


def run_mitm(controller_channel: str, leg_channel: str, *, to_leg: FaultSpec = FaultSpec(),
             from_leg: FaultSpec = FaultSpec(), seed: int = 0, silence_node: int | None = None,
             silence_after_s: float | None = None, poll_s: float | None = None, duration_s: float | None = None,
             json_path: str | Path | None = None, ready_path: str | Path | None = None, clock: str = "wall",
             silence_at_sim_s: float | None = None) -> dict[str, Any]:
    """Forward between the two SocketCAN channels until SIGTERM/SIGINT or ``duration_s`` [s, wall].
    ``clock``: ``"wall"`` (faults on the monotonic clock) or ``"sim"`` (on the plant's syncs: the
    module doc's rule). SIGUSR1 starts silencing ``silence_node`` (in simulated time from the next
    sync); so does ``silence_after_s`` [s] after start (wall clock only) or the first sync at or
    past ``silence_at_sim_s`` [s] (simulated time only). ``poll_s``: the pause after each batch [s]
    (None: :func:`default_poll_s`). ``ready_path``: a file created once both channels are open.
    Returns the summary (also written to ``json_path``)."""
    import select

    poll_s = default_poll_s() if poll_s is None else poll_s

    if clock not in CLOCKS:
        raise ValueError(f"clock must be one of {', '.join(CLOCKS)}, got {clock!r}")
    sim = clock == "sim"
    if sim and silence_after_s is not None:
        raise ValueError("silence_after_s is wall time: in simulated time use silence_at_sim_s")
    if silence_at_sim_s is not None and not sim:
        raise ValueError("silence_at_sim_s is simulated time: it needs clock='sim'")
    if controller_channel == leg_channel:
        raise ValueError(f"the two channels must differ, got {controller_channel!r} twice")
    if not (math.isfinite(poll_s) and 0.0 < poll_s <= 0.1):
        raise ValueError(f"poll_s must be in (0, 0.1] s, got {poll_s!r}")
    flags = {"stop": False, "silence": False, "by": "duration"}

    def on_stop(signum, frame):  # noqa: ARG001
        flags["stop"] = True
        flags["by"] = signal.Signals(signum).name

    def on_silence(signum, frame):  # noqa: ARG001
        flags["silence"] = True

    for s in (signal.SIGTERM, signal.SIGINT):
        signal.signal(s, on_stop)
    signal.signal(signal.SIGUSR1, on_silence)
    ctl_raw, ctl_bus = _open(controller_channel)
    leg_raw, leg_bus = _open(leg_channel)
    node = ManInTheMiddle(ctl_bus, leg_bus, to_leg=to_leg, from_leg=from_leg, seed=seed, silence_node=silence_node,
                          sim_time=sim, silence_at_sim_s=silence_at_sim_s)
    poller = select.poll()
    for b in (ctl_bus, leg_bus):
        poller.register(b.socket, select.POLLIN)
    poll_ms = max(1, int(math.ceil(poll_s * 1e3)))  # poll()'s resolution is 1 ms
    wakes = WakeStats()
    monotonic = time.monotonic
    t0 = monotonic()
    t_silence = math.inf if silence_after_s is None else t0 + silence_after_s
    t_end = math.inf if duration_s is None else t0 + duration_s
    if ready_path is not None:
        Path(ready_path).write_text(f"{os.getpid()}\n")
    log.info("mitm: %s <-> %s, to the leg %s, from it %s, seed %d, %s clock", controller_channel, leg_channel,
             to_leg.describe(), from_leg.describe(), seed, clock)
    try:
        while not flags["stop"]:
            # In simulated time a held frame is released by a sync, never by the wall clock: no
            # need to wake for it.
            held = not sim and (node.to_leg.injector.in_flight or node.from_leg.injector.in_flight)
            poller.poll(poll_ms if held else IDLE_WAIT_MS)  # returns at once when a frame waits
            now = monotonic()
            if now >= t_end:
                break
            if sim:
                if flags["silence"]:
                    flags["silence"] = False
                    node.silence_at_next_sync()
            elif (flags["silence"] or now >= t_silence) and not node.silencing:
                node.start_silence(now)
            wakes.record(now, node.pump(now))
            time.sleep(poll_s)
    finally:
        frames = node.to_leg.frames_in + node.from_leg.frames_in
        summary = {"channels": {"controller": controller_channel, "leg": leg_channel}, **node.summary(),
                   "stopped_by": flags["by"], "wall_s": monotonic() - t0, "poll_s": poll_s,
                   "pacing": wakes.summary(frames), "cpu_s": sum(os.times()[:2])}
        ctl_raw.shutdown()
        leg_raw.shutdown()
        _write_json(json_path, summary)
    return summary


__all__ = ["Link", "ManInTheMiddle", "run_mitm", "default_poll_s", "read_counts", "is_sim_time_frame", "sync_time_s",
           "CLOCKS", "COUNTS_KIND", "COUNTS_VERSION"]
