"""The man-in-the-middle node: a faulty gateway between the controller's bus and the leg's.

``elegant-stepping mitm --controller-channel vcan0 --leg-channel vcan1 --to-leg SPEC --from-leg
SPEC --seed N [--silence-node ID --silence-after-s T] [--json FILE]`` forwards every frame
between two SocketCAN channels, each direction through its own :class:`hil.faults.model.FaultInjector`
(``SPEC`` in :meth:`hil.faults.model.FaultSpec.parse` form, e.g. ``drop=0.05``; the two generators are
spawned from ``N`` as :class:`hil.faults.model.FaultyBus` spawns its own). It can silence one node: from
``T`` seconds after start, or from the moment it gets SIGUSR1, every frame the leg sends whose
``arbitration_id >> 5`` is that node is dropped (the leg -> controller direction only: the node
still hears the controller, as when its transmitter dies).

Pacing, on the monotonic clock: the node waits in one ``poll()`` on both sockets until a frame
is there, reads every waiting frame from the non-blocking sockets (:func:`controller.daemon.fastbus.lean`: one
``recv`` per frame), sends what is due, then sleeps ``poll_s`` before it polls again, so the
frames that arrive meanwhile are handled in one batch. While the injectors hold frames (delayed,
held for reordering) it polls every ``poll_s`` to release them on time. Never a spin. A frame
waits at most ``poll_s`` (plus any fault delay) in the node; a quiet bus costs 20 wake-ups/s.

``poll_s`` comes from the platform profile (:mod:`hil.profile`): 0.5 ms natively and 2 ms inside
User-Mode Linux, where every wake-up and system call is a host ptrace round trip on the one
virtual CPU that the controller and the plant share; a shorter poll there costs the controller
late ticks and period jitter. The plant's process also works in 2 ms slices there.

SIGTERM or SIGINT stops it (exit 0); the counts per direction (frames in, forwarded, each fault,
silenced, send errors), the silence start and the pacing figures are written as JSON at exit
(stamped ``format: "mitm-counts"``, ``format_version`` :data:`COUNTS_VERSION`; :func:`read_counts`
checks it).
Traffic stays on the two CAN channels: no network address is ever opened.
"""

from __future__ import annotations

import logging
import math
import os
import signal
import time
from pathlib import Path
from typing import Any, Callable

import can
import numpy as np

from controller.atomic import write_json_atomic
from controller.errors import stamp
from hil.faults.model import FAULT_KINDS, FaultInjector, FaultSpec

log = logging.getLogger(__name__)

COUNTS_KIND = "mitm-counts"
COUNTS_VERSION = 1  # the counts file's format version: raise it when a reader of the old one could misread it

def default_poll_s() -> float:
    """The pause after each batch on this platform [s] (:attr:`hil.profile.Profile.mitm_poll_s`)."""
    from hil.profile import current

    return current().mitm_poll_s
IDLE_WAIT_MS = 50  # longest wait in poll() with nothing held [ms]: how soon a signal's flag is seen


class Link:
    """One direction of the gateway: frames from ``src`` to ``dst`` through an injector.

    ``silenced(msg)`` (if given) says whether a frame is to vanish before the injector sees it.
    Counts: ``frames_in`` (read from ``src``), ``silenced``, ``forwarded`` (sent to ``dst``),
    ``send_errors`` (sends that failed; the frame is lost), plus the injector's own counts.
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

    def counts(self) -> dict[str, int]:
        faults = self.injector.counts
        return {"frames_in": self.frames_in, "forwarded": self.forwarded, "silenced": self.silenced_frames,
                "send_errors": self.send_errors, "in_flight": self.injector.in_flight,
                **{k: int(faults.get(k, 0)) for k in FAULT_KINDS}}


class ManInTheMiddle:
    """The gateway's logic on two buses, without sockets or clocks of its own (testable on
    python-can's ``virtual`` buses): :meth:`pump` with the current time [s] moves frames both ways.

    ``to_leg`` applies to frames from ``controller_bus`` to ``leg_bus``, ``from_leg`` to the other
    way. ``silence_node``: the node :meth:`start_silence` silences (leg -> controller only).
    """

    def __init__(self, controller_bus: can.BusABC, leg_bus: can.BusABC, *, to_leg: FaultSpec = FaultSpec(),
                 from_leg: FaultSpec = FaultSpec(), seed: int = 0, silence_node: int | None = None) -> None:
        if silence_node is not None and not 0 <= silence_node <= 0x3F:
            raise ValueError(f"silence_node must be a node id 0..63, got {silence_node!r}")
        tx_rng, rx_rng = np.random.default_rng(seed).spawn(2)
        self.specs = {"to_leg": to_leg, "from_leg": from_leg}
        self.seed = seed
        self.silence_node = silence_node
        self.silence_started_mono: float | None = None
        self.silence_started_unix: float | None = None
        self._silencing = False
        self.to_leg = Link("to_leg", controller_bus, leg_bus, FaultInjector(to_leg, tx_rng))
        self.from_leg = Link("from_leg", leg_bus, controller_bus, FaultInjector(from_leg, rx_rng), self._is_silenced)

    def _is_silenced(self, msg: can.Message) -> bool:
        return self._silencing and not msg.is_extended_id and (msg.arbitration_id >> 5) == self.silence_node

    @property
    def silencing(self) -> bool:
        return self._silencing

    def start_silence(self, now_s: float) -> None:
        """Silence :attr:`silence_node` from ``now_s`` [s, monotonic] on (a no-op without one or
        when already silencing)."""
        if self.silence_node is None or self._silencing:
            return
        self._silencing = True
        self.silence_started_mono = now_s
        self.silence_started_unix = time.time()
        log.warning("silencing node %d from t=%.3f s", self.silence_node, now_s)

    def pump(self, now_s: float) -> int:
        """Move frames both ways at ``now_s`` [s]; returns the number of frames read."""
        return self.to_leg.pump(now_s) + self.from_leg.pump(now_s)

    def summary(self) -> dict[str, Any]:
        return {
            "seed": self.seed,
            "specs": {k: v.describe() for k, v in self.specs.items()},
            "to_leg": self.to_leg.counts(),
            "from_leg": self.from_leg.counts(),
            "silence": {"node": self.silence_node, "started_mono": self.silence_started_mono,
                        "started_unix": self.silence_started_unix},
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
             json_path: str | Path | None = None, ready_path: str | Path | None = None) -> dict[str, Any]:
    """Forward between the two SocketCAN channels until SIGTERM/SIGINT or ``duration_s`` [s].
    SIGUSR1 starts silencing ``silence_node``; so does ``silence_after_s`` [s] after start.
    ``poll_s``: the pause after each batch [s] (None: :func:`default_poll_s`). ``ready_path``: a
    file created once both channels are open. Returns the summary (also written to ``json_path``)."""
    import select

    poll_s = default_poll_s() if poll_s is None else poll_s

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
    node = ManInTheMiddle(ctl_bus, leg_bus, to_leg=to_leg, from_leg=from_leg, seed=seed, silence_node=silence_node)
    poller = select.poll()
    for b in (ctl_bus, leg_bus):
        poller.register(b.socket, select.POLLIN)
    poll_ms = max(1, int(math.ceil(poll_s * 1e3)))  # poll()'s resolution is 1 ms
    wakes = WakeStats()
    clock = time.monotonic
    t0 = clock()
    t_silence = math.inf if silence_after_s is None else t0 + silence_after_s
    t_end = math.inf if duration_s is None else t0 + duration_s
    if ready_path is not None:
        Path(ready_path).write_text(f"{os.getpid()}\n")
    log.info("mitm: %s <-> %s, to the leg %s, from it %s, seed %d", controller_channel, leg_channel,
             to_leg.describe(), from_leg.describe(), seed)
    try:
        while not flags["stop"]:
            held = node.to_leg.injector.in_flight or node.from_leg.injector.in_flight
            poller.poll(poll_ms if held else IDLE_WAIT_MS)  # returns at once when a frame waits
            now = clock()
            if now >= t_end:
                break
            if (flags["silence"] or now >= t_silence) and not node.silencing:
                node.start_silence(now)
            wakes.record(now, node.pump(now))
            time.sleep(poll_s)
    finally:
        frames = node.to_leg.frames_in + node.from_leg.frames_in
        summary = {"channels": {"controller": controller_channel, "leg": leg_channel}, **node.summary(),
                   "stopped_by": flags["by"], "wall_s": clock() - t0, "poll_s": poll_s,
                   "pacing": wakes.summary(frames), "cpu_s": sum(os.times()[:2])}
        ctl_raw.shutdown()
        leg_raw.shutdown()
        _write_json(json_path, summary)
    return summary


__all__ = ["Link", "ManInTheMiddle", "run_mitm", "default_poll_s", "read_counts", "COUNTS_KIND", "COUNTS_VERSION"]
