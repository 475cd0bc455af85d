"""Bus load measured from a recorded log: frames per second x bits per frame, per message.

Reads any log python-can can read (BLF, candump ``.log``, ASC, ...), counts every frame's bit
time with :func:`protocol.frame_bits` (stuff bits and intermission included) and divides by the
recording's span. The figure a CAN engineer quotes: the fraction of the bitrate in use. The log
is read by :mod:`hil.analysis.buslog`: a damaged log is an :class:`controller.errors.InputError`
naming where the damage starts, unless ``partial`` (the frames before it are measured).
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path
from typing import Any, Callable

from protocol import BusContract, frame_bits


def bus_load_from_log(path: str | Path, bitrate: int = 1_000_000, skip_s: float = 0.0, *, partial: bool = False,
                      warn: Callable[[str], None] | None = None) -> dict[str, Any]:
    """Load of the recording at ``path`` on a bus of ``bitrate`` bit/s; the first ``skip_s``
    seconds (bring-up) are left out. A damaged log raises :class:`controller.errors.InputError`,
    unless ``partial``: then the valid frames are measured and ``warn`` gets the line saying where
    the reading stopped (also in the result, ``partial``).

    Raises:
        FileNotFoundError: no file at ``path``.
        InputError: a damaged log (without ``partial``), fewer than two frames, or no time spanned.
    """
    from controller.errors import InputError
    from hil.analysis.buslog import LogReading, read_metadata

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such log")
    if bitrate <= 0:
        raise ValueError(f"bitrate must be positive, got {bitrate}")
    contract = BusContract.load()
    frames = bits = 0
    first = last = None
    by_name: Counter[str] = Counter()
    metadata = read_metadata(path)
    reading = LogReading(path, None if metadata is None else metadata.get("frames"))
    for msg in reading:
        if msg.is_error_frame:
            continue
        if first is None:
            first = msg.timestamp
        if msg.timestamp - first < skip_s:
            continue
        last = msg.timestamp
        data = bytes(msg.dlc) if msg.is_remote_frame else bytes(msg.data)
        bits += frame_bits(msg.arbitration_id, data, extended=msg.is_extended_id, remote=msg.is_remote_frame)
        frames += 1
        route = contract.route(msg.arbitration_id) if not msg.is_extended_id else None
        by_name[route.codec.name if route is not None else f"0x{msg.arbitration_id:03X}"] += 1
    line = reading.check(partial)
    if line is not None and warn is not None:
        warn(line)
    if frames < 2 or last is None or first is None:
        raise InputError(f"{path}: fewer than two frames to measure a load from")
    span = last - first - skip_s
    if span <= 0:
        raise InputError(f"{path}: the recording spans no time after {skip_s} s")
    return {
        "frames": frames,
        "span_s": span,
        "frames_per_s": frames / span,
        "bits_per_frame": bits / frames,
        "bitrate": bitrate,
        "fraction": bits / span / bitrate,
        "frames_per_s_by_message": {k: v / span for k, v in sorted(by_name.items())},
        "partial": None if reading.damage is None else {"frames_read": reading.frames,
                                                        "stopped_at": reading.damage.where,
                                                        "reason": reading.damage.reason},
    }
