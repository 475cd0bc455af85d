"""``replay`` and ``decode``: a recorded bus log, offline.

``decode LOG`` prints every frame as named signals, decoded by cantools with our DBC (ODrive
messages are defined for node 0; a frame of node N is decoded as ``arbitration_id & 0x1F``).

``replay LOG`` feeds the log to a fresh :class:`controller.loop.ControlLoop` and reports its
decisions per step: the gated range, the encoder cell gated, the burst change the premotor asked
for and the burst length. The controller's ticks are recovered from the log itself: every tick
in bring-up and walking sends one Set_Input_Pos per axis, so each hip Set_Input_Pos marks a tick
and the tick's clock is the timestamp of its first frame; the frames the controller received in
that tick are those recorded before it. Frames recorded long before the controller started are
not fed (only the last 0.5 s before its first frame). With the live run's records
(``controller.jsonl`` beside the log), each replayed step is compared with the live one: the
same cell, burst change and burst length within 1 ms. The controller is configured as the live
one was: ``controller.toml`` beside the log (or ``--config FILE``); a session recorded before the
switch to TOML has a ``controller.json`` there instead, still read (with a warning).

Both verbs read the log with :mod:`hil.analysis.buslog` (the one reader of bus logs): a damaged
log (an empty, garbage, truncated or bit-flipped BLF, a junk line in a candump log) is an input
error (exit 3) naming the frame or line where the damage starts, unless ``--partial``, which uses
the valid frames before it and says so in one warning line. The recorder's metadata beside the log
(``bus.blf.json``, :func:`hil.analysis.buslog.read_metadata`) is checked for its format version
and gives the frame count the log must hold.

**Lost frames.** The metadata also gives ``frames_lost``: the frames the kernel dropped before the
recorder read them (:mod:`hil.session.recorder`, ``SO_RXQ_OVFL``). A lost frame is one the live
controller may have read and the replayed one cannot, so a replay of such a log is not the live
run: with any lost, replay says how many in one warning line, its result has ``frames_lost: N``
and ``as_live: false``, and the comparison with the live records is reported as "steps match the
live records (not a reproduction: N frames lost)" instead of "steps as live". With none lost it
is as before (``as_live: true``). Where the count is unknown (no metadata, a recording from before
the count, or one not made on SocketCAN) both are null and the summary says so.

Every other file replay reads (``--config``, ``--records``, ``controller.ticks``) is checked for
its structure; a problem is one line naming it.

**Simulated time.** A log of a ``hil --clock sim`` session holds the plant's ``ES_Sim_Sync`` frames,
and there the ticks need no recovering: the live controller ticked once per sync (the opening sync
at 0.0 and syncs for a time already lived aside), with the sync's time as its clock, on exactly the
frames recorded before that sync since the previous one (a vcan delivers frames to every socket in
one order). Replay does the same (``tick_source`` "sync frames"), so with nothing lost it is the
live run, tick for tick; the controller's own sync-protocol frames are never fed to it.
"""

from __future__ import annotations

import dataclasses
import json
import math
import struct
import sys
from collections import deque
from pathlib import Path
from typing import Any

import can
import cantools

from controller.config import ControllerConfig
from controller.loop import ControlLoop
from hil.analysis.buslog import LogReading, frames_lost, read_frames, read_metadata
from hil.session.recorder import SET_INPUT_POS, sent_by_controller
from protocol import SENSOR_BOARD_NODE_ID, split_arbitration_id
from protocol.contract import DBC_PATH, SIM_SYNC_ID, BusContract

PRE_START_S = 0.5
_F64 = struct.Struct("<d")


class ReplayBus:
    """What ControlLoop needs of a bus: ``recv`` from a queue the replay fills, ``send`` recorded."""

    def __init__(self) -> None:
        self.inbox: deque[can.Message] = deque()
        self.sent: list[can.Message] = []

    def recv(self, timeout: float | None = None) -> can.Message | None:  # noqa: ARG002
        return self.inbox.popleft() if self.inbox else None

    def send(self, msg: can.Message, timeout: float | None = None) -> None:  # noqa: ARG002
        self.sent.append(msg)

    def shutdown(self) -> None:
        pass


_is_controller = sent_by_controller  # the recorder's rule: the contract's master messages


def _align(inbound: list[can.Message], t_log: list[float], counts: list[int]) -> int:
    """Index in ``inbound`` of the first frame the live controller read: the one that puts each
    tick's frames before that tick (within 1 ms) most often, near the time-based guess.

    The guess is the median, over the ticks, of (frames logged before the tick) - (frames the
    controller had read by then): tick 0 alone misleads, because the first tick reads everything
    queued since the socket opened and frames keep arriving while it does (17 and 14 frames off
    in two User-Mode Linux sessions, which fed every frame about 7 ticks late)."""
    import bisect
    from statistics import median

    ts = [m.timestamp for m in inbound]
    offsets, read = [], 0
    for t, n in zip(t_log[:20000], counts[:20000]):
        read += n
        offsets.append(bisect.bisect_right(ts, t) - read)
    guess = int(median(offsets)) if offsets else 0
    best, best_bad = max(guess, 0), None
    for s in range(max(0, guess - 4), guess + 5):
        bad, j = 0, s
        for t, n in zip(t_log[:20000], counts[:20000]):
            j += n
            if j > len(ts):
                bad += 1_000_000
                break
            if n and ts[j - 1] > t + 1e-3:
                bad += 1
            if j < len(ts) and ts[j] < t - 1e-3:
                bad += 1
        if best_bad is None or bad < best_bad:
            best, best_bad = s, bad
    return best


def replay(log: str | Path, config: ControllerConfig = ControllerConfig(), *, tick_times: list[float] | None = None,
           tick_counts: list[int] | None = None, clock_offset_s: float | None = None,
           drivers_watchdog_s: float | None = None, frames: list[can.Message] | None = None) -> dict[str, Any]:
    """Replay ``log``. With ``tick_times`` (the live loop's clock at each tick, from
    ``controller.ticks``), ``tick_counts`` (frames it read in each tick) and ``clock_offset_s``
    (log timestamp minus that clock), the loop ticks when the live one did and reads in each
    tick exactly the frames it read; otherwise the ticks are recovered from the log.

    The replayed controller arms by itself (``auto_arm``) as soon as every node is heard: a log
    holds no operator's command, and sessions recorded before the lifecycle existed armed so.
    ``drivers_watchdog_s``: the drivers' watchdog the live controller wrote at arming (its
    configuration's ``[drivers]``), so the replayed one expects the same read-back. ``frames``: the
    log's frames as read (:func:`hil.analysis.buslog.read_frames`); default: read ``log`` whole (a
    damaged log is an :class:`controller.errors.InputError`)."""
    from controller.errors import InputError

    config = dataclasses.replace(config, auto_arm=True)
    if frames is None:
        frames = read_frames(log)
    frames = [m for m in frames if not m.is_error_frame]
    frames.sort(key=lambda m: m.timestamp)
    hip_id = next(a.node_id for a in config.axes if a.name == "hip")
    bus = ReplayBus()
    loop = ControlLoop(config, bus)
    if drivers_watchdog_s is not None:
        loop.drivers_watchdog_timeout_s = drivers_watchdog_s
    first_ctl = next((i for i, m in enumerate(frames) if _is_controller(m)), None)
    if first_ctl is None:
        raise InputError(f"{log}: no frame from the controller in the log ({len(frames)} frames): nothing to replay")
    t_first = frames[first_ctl].timestamp
    inbound = [m for m in frames if not _is_controller(m) and m.timestamp >= t_first - PRE_START_S]
    # tick starts: the first controller frame after each hip Set_Input_Pos (and the very first)
    ticks: list[float] = []
    new_tick = True
    for m in frames[first_ctl:]:
        if not _is_controller(m):
            continue
        if new_tick:
            ticks.append(m.timestamp)
            new_tick = False
        if split_arbitration_id(m.arbitration_id) == (hip_id, SET_INPUT_POS):
            new_tick = True
    offset = 0.0
    if any(_sync_time(m) is not None for m in frames):
        return _replay_on_syncs(log, loop, bus, frames)
    if tick_times is not None and clock_offset_s is not None:
        ticks, offset = list(tick_times), clock_offset_s
        inbound = [m for m in frames if not _is_controller(m)]
        if tick_counts is not None and all(n >= 0 for n in tick_counts):
            j = _align(inbound, [t + offset for t in ticks], tick_counts)
            for t, n in zip(ticks, tick_counts):
                bus.inbox.extend(inbound[j:j + n])
                j += n
                loop.tick(t)
            ticks_done = True
        else:
            ticks_done = False
    else:
        ticks_done = False
    n_ticks = len(ticks)
    j = 0
    if ticks_done:
        ticks = []
    for t in ticks:
        t_log = t + offset
        while j < len(inbound) and inbound[j].timestamp < t_log:
            bus.inbox.append(inbound[j])
            j += 1
        loop.tick(t)
    return _result(log, frames, n_ticks,
                   "live ticks and frame counts" if ticks_done else ("live ticks" if offset else "log"), loop, bus)


def compare(replayed: list[dict[str, Any]], live: list[dict[str, Any]]) -> dict[str, Any]:
    by_index = {s["index"]: s for s in live}
    compared = matching = 0
    mismatches = []
    for r in replayed:
        s = by_index.get(r["index"])
        if s is None or s["burst_s"] is None or r["burst_s"] is None:
            continue
        compared += 1
        same = (r["cell"] == s["cell"] and abs(r["modulation_s"] - s["modulation_s"]) < 1e-3
                and abs(r["burst_s"] - s["burst_s"]) < 1e-3)
        if same:
            matching += 1
        else:
            mismatches.append({"index": r["index"], "replayed": {k: r[k] for k in ("gated_range_m", "cell", "modulation_s", "burst_s")},
                               "live": {k: s[k] for k in ("gated_range_m", "cell", "modulation_s", "burst_s")}})
    return {"compared_steps": compared, "matching_steps": matching, "mismatches": mismatches}


STEP_FIELDS = ("index", "cell", "modulation_s", "burst_s")
"""What replay compares of each live step record (``controller.jsonl``)."""


def _live_steps(path: Path, option: str) -> list[dict[str, Any]]:
    """The live run's step records in ``path``, each checked for what the comparison reads.

    Raises:
        InputError: not the controller's records (a line that is JSON but not an object, a step
            record without its fields or with fields of the wrong type).
    """
    from controller.daemon.run import read_records
    from controller.errors import InputError

    try:
        steps = read_records(path).get("step", [])
    except InputError as exc:  # the records' own reader names the line
        raise InputError(f"{option}: {exc}" if option.startswith("--") else str(exc)) from None
    except (AttributeError, TypeError):  # a JSON line that is not an object
        raise InputError(f"{option} {path}: not the controller's records (a line that is not a JSON object)") from None
    except UnicodeDecodeError:
        raise InputError(f"{option} {path}: not the controller's records (not text)") from None
    for n, step in enumerate(steps, 1):
        missing = [k for k in STEP_FIELDS if k not in step]
        if missing:
            raise InputError(f"{option} {path}: step record {n} lacks {', '.join(missing)}")
        ok = (isinstance(step["index"], int) and (step["cell"] is None or isinstance(step["cell"], int))
              and isinstance(step["modulation_s"], (int, float))
              and (step["burst_s"] is None or isinstance(step["burst_s"], (int, float))))
        if not ok:
            raise InputError(f"{option} {path}: step record {n} has a field of the wrong type: "
                             f"{ {k: step[k] for k in STEP_FIELDS} }")
    return steps


def _sync_time(msg: can.Message) -> float | None:
    """The time an ``ES_Sim_Sync`` frame carries, or None for any other frame (or a malformed sync)."""
    if not (msg.is_extended_id and msg.arbitration_id == SIM_SYNC_ID) or msg.is_remote_frame or len(msg.data) != 8:
        return None
    t = _F64.unpack(bytes(msg.data))[0]
    return t if math.isfinite(t) else None


def _replay_on_syncs(log: str | Path, loop: ControlLoop, bus: ReplayBus, frames: list[can.Message]) -> dict[str, Any]:
    """Replay a simulated-time log: one tick per sync, on the frames before it (module doc)."""
    last = -math.inf
    ticks = 0
    for m in frames:
        if m.is_extended_id:
            t = _sync_time(m)
            if t is None or t <= last:
                continue  # the controller's end of period or state, another extended frame, a stale sync
            last = t
            if t > 0.0:  # the opening sync: answered without a tick
                loop.tick(t)
                ticks += 1
        elif not _is_controller(m):
            bus.inbox.append(m)
    return _result(log, frames, ticks, "sync frames", loop, bus)


def _result(log: str | Path, frames: list[can.Message], n_ticks: int, source: str, loop: ControlLoop,
            bus: ReplayBus) -> dict[str, Any]:
    steps = [{"index": s.index, "onset_s": s.onset_s, "gated_range_m": s.gated_range_m, "cell": s.cell,
              "modulation_s": s.modulation_s, "burst_s": None if math.isnan(s.burst_s) else s.burst_s,
              "amplitude": s.amplitude} for s in loop.stats.steps]
    return {"log": str(log), "frames": len(frames), "ticks": n_ticks, "tick_source": source,
            "phase": loop.phase.value, "steps": steps, "reflexes": len(loop.stats.reflexes),
            "sent_set_input_pos": sum(1 for m in bus.sent if split_arbitration_id(m.arbitration_id)[1] == SET_INPUT_POS),
            "logged_set_input_pos": sum(1 for m in frames if _is_controller(m) and not m.is_extended_id
                                        and split_arbitration_id(m.arbitration_id)[1] == SET_INPUT_POS)}


def _live_ticks(ticks_path: Path, rec_path: Path) -> tuple[list[float], list[int], float] | None:
    """The live loop's ticks (its clock at each tick, frames read in it) and the clock offset,
    from ``controller.ticks`` and the records' clock record; None where the records have none.

    Raises:
        InputError: the ticks file is not pairs of doubles, or the clock record lacks its offset.
    """
    from array import array

    from controller.daemon.run import read_records
    from controller.errors import InputError

    clock = read_records(rec_path).get("clock") or []
    if not clock:
        return None
    offset = clock[0].get("realtime_minus_monotonic_s")
    if isinstance(offset, bool) or not isinstance(offset, (int, float)) or not math.isfinite(offset):
        raise InputError(f"{rec_path}: its clock record has no realtime_minus_monotonic_s ({offset!r})")
    raw = ticks_path.read_bytes()
    if len(raw) % 16:
        raise InputError(f"{ticks_path}: {len(raw)} bytes, not whole (tick clock, frames read) pairs of doubles "
                         f"(cut short at tick {len(raw) // 16 + 1})")
    arr = array("d")
    arr.frombytes(raw)
    pairs = arr.tolist()
    counts = pairs[1::2]
    if not all(math.isfinite(n) and n == int(n) for n in counts):
        raise InputError(f"{ticks_path}: a frame count that is not a whole number: not a controller.ticks file")
    return pairs[0::2], [int(n) for n in counts], float(offset)


def _clock_lines(rec_path: Path) -> list[dict[str, Any]]:
    from controller.daemon.run import read_records

    return read_records(rec_path).get("clock") or []


def _frames(n: int) -> str:
    return f"{n} frame{'' if n == 1 else 's'}"


def lost_line(log: str | Path, lost: int) -> str:
    """The warning for a recording whose recorder lost ``lost`` (> 0) frames."""
    return (f"{log}: the recorder lost {_frames(lost)} (dropped by the kernel, its "
            f"receive queue full): the replayed controller cannot read what the live one read, so this "
            f"replay is not the live run")


def summary_tail(matching: int | None, compared: int | None, lost: int | None, with_live: bool) -> str:
    """The end of replay's summary line: the comparison with the live records (if any), called
    "as live" only when the recorder lost no frames; the lost frames when any or unknown."""
    if lost is None:
        tail = f"; {matching}/{compared} steps as live" if with_live else ""
        return tail + "; frames lost by the recorder: unknown"
    if lost == 0:
        return f"; {matching}/{compared} steps as live" if with_live else ""
    if with_live:
        return f"; {matching}/{compared} steps match the live records (not a reproduction: {_frames(lost)} lost)"
    return f"; {_frames(lost)} lost by the recorder"


def main_replay(args) -> int:
    from controller.cli.common import check_output_file, warn
    from controller.errors import InputError
    from hil.analysis.legacy_config import load_controller_config

    log = Path(args.log)
    check_output_file(args.json, "--json")
    cfg_path = args.config
    if cfg_path is not None and not Path(cfg_path).is_file():
        raise InputError(f"--config {cfg_path}: {'a folder, not a file' if Path(cfg_path).is_dir() else 'no such file'}")
    if args.records is not None and not Path(args.records).is_file():
        raise InputError(f"--records {args.records}: "
                         f"{'a folder, not a file' if Path(args.records).is_dir() else 'no such file'}")
    metadata = read_metadata(log)  # checked first: a session from a newer version is refused at once
    reading = LogReading(log, None if metadata is None else metadata.get("frames"))
    frames = list(reading)
    line = reading.check(getattr(args, "partial", False))
    if line is not None:
        warn(args, line)
    lost = frames_lost(metadata)
    if lost:
        warn(args, lost_line(log, lost))
    if cfg_path is None:  # the session's: controller.toml, else an old session's controller.json (with a warning)
        candidates = (log.parent / "controller.toml", log.parent / "controller.json")
        cfg_path = next((p for p in candidates if p.exists()), None)
    config = load_controller_config(cfg_path)
    drivers_watchdog_s = None
    if cfg_path is not None and Path(cfg_path).suffix.lower() == ".toml":
        from controller.settings.file import load_config

        drivers_watchdog_s = load_config(cfg_path).drivers.watchdog_timeout_s
    option = "--records" if args.records else "the records"
    rec_path = Path(args.records) if args.records else log.parent / "controller.jsonl"
    live = _live_steps(rec_path, option) if rec_path.exists() else None
    ticks_path = log.parent / "controller.ticks"
    sim = rec_path.exists() and any(c.get("clock") == "sim" for c in _clock_lines(rec_path))
    # in simulated time the ticks are the log's sync frames (replay finds them there)
    ticks = _live_ticks(ticks_path, rec_path) if ticks_path.exists() and rec_path.exists() and not sim else None
    tick_times, tick_counts, offset = ticks if ticks is not None else (None, None, None)
    result = replay(log, config, tick_times=tick_times, tick_counts=tick_counts, clock_offset_s=offset,
                    drivers_watchdog_s=drivers_watchdog_s, frames=frames)
    result["config"] = None if cfg_path is None else str(cfg_path)
    result["frames_lost"] = lost
    result["as_live"] = None if lost is None else lost == 0
    result["partial"] = None if reading.damage is None else {"frames_read": reading.frames,
                                                             "stopped_at": reading.damage.where,
                                                             "reason": reading.damage.reason}
    if live is not None:
        result.update(compare(result["steps"], live))
        result["records"] = str(rec_path)
    live_by = {s["index"]: s for s in live or []}
    out = sys.stderr if args.json == "-" else sys.stdout
    for s in result["steps"]:
        g = "   -   " if s["gated_range_m"] is None else f"{s['gated_range_m']:.3f} m"
        b = "  -  " if s["burst_s"] is None else f"{s['burst_s']:.3f}"
        line = f"step {s['index']:4d}: gated {g}, cell {'-' if s['cell'] is None else s['cell']:>2}, " \
               f"burst change {s['modulation_s']:+.3f} s, burst {b} s"
        if s["index"] in live_by and live_by[s["index"]]["burst_s"] is not None and s["burst_s"] is not None:
            l = live_by[s["index"]]
            ok = (l["cell"] == s["cell"] and abs(l["burst_s"] - s["burst_s"]) < 1e-3
                  and abs(l["modulation_s"] - s["modulation_s"]) < 1e-3)
            line += "   = live" if ok else f"   live: cell {l['cell']}, change {l['modulation_s']:+.3f}, burst {l['burst_s']:.3f}"
        print(line, file=out)
    summary = f"replayed {result['frames']} frames in {result['ticks']} ticks: {len(result['steps'])} steps, " \
              f"{result['reflexes']} reflexes, final phase {result['phase']}"
    summary += summary_tail(result.get("matching_steps"), result.get("compared_steps"), lost, live is not None)
    print(summary, file=sys.stderr)
    if args.json is not None:
        from controller.cli.common import write_json

        write_json(args.json, result)
    return 0


def main_decode(args) -> int:
    import os

    try:
        return _decode(args)
    except BrokenPipeError:  # e.g. piped into head
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0


def _decode(args) -> int:
    from controller.cli.common import warn

    partial = getattr(args, "partial", False)
    if getattr(args, "load", False):
        from hil.analysis.busload import bus_load_from_log

        print(json.dumps(bus_load_from_log(args.log, args.bitrate, args.skip_s, partial=partial,
                                           warn=lambda line: warn(args, line)), indent=2))
        return 0
    metadata = read_metadata(args.log)
    reading = LogReading(args.log, None if metadata is None else metadata.get("frames"))
    db = cantools.database.load_file(str(DBC_PATH))
    contract = BusContract.load()
    for i, msg in enumerate(reading):
        if args.limit is not None and i >= args.limit:
            return 0  # the rest is not read, so not judged
        arb = msg.arbitration_id
        route = None if msg.is_extended_id or msg.is_error_frame else contract.route(arb)
        head = f"{msg.timestamp:.6f} {arb:03X}"
        if route is None:
            print(f"{head} unknown {bytes(msg.data).hex()}")
            continue
        name = route.codec.name
        message = db.get_message_by_name(name)
        who = "sensor_board" if route.node_id == SENSOR_BOARD_NODE_ID else f"node {route.node_id}"
        if msg.is_remote_frame:
            print(f"{head} {who} {name} (remote request)")
            continue
        try:
            signals = message.decode(bytes(msg.data), decode_choices=True)
        except Exception as exc:  # noqa: BLE001 - a malformed frame is printed, not fatal
            print(f"{head} {who} {name} undecodable ({exc}): {bytes(msg.data).hex()}")
            continue
        text = " ".join(f"{k}={v:.6g}" if isinstance(v, float) else f"{k}={v}" for k, v in signals.items())
        print(f"{head} {who} {name} {text}")
    sys.stdout.flush()  # the frames before the damage first, then the line about it
    line = reading.check(partial)
    if line is not None:
        warn(args, line)
    return 0
