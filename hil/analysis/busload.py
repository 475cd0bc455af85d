"""Bus load measured from a recorded log: frames per second x bits per frame, per message.

Reads any log python-can can read (BLF, candump ``.log``, ASC, ...), counts every frame's bit
time with :func:`protocol.frame_bits` (stuff bits and intermission included) and divides by the
recording's span. The figure a CAN engineer quotes: the fraction of the bitrate in use.
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path
from typing import Any

import can

from protocol import BusContract, frame_bits


def bus_load_from_log(path: str | Path, bitrate: int = 1_000_000, skip_s: float = 0.0) -> dict[str, Any]:
    """Load of the recording at ``path`` on a bus of ``bitrate`` bit/s; the first ``skip_s``
    seconds (bring-up) are left out."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such log")
    if bitrate <= 0:
        raise ValueError(f"bitrate must be positive, got {bitrate}")
    contract = BusContract.load()
    frames = bits = 0
    first = last = None
    by_name: Counter[str] = Counter()
    for msg in can.LogReader(str(path)):
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
    if frames < 2 or last is None or first is None:
        raise ValueError(f"{path}: fewer than two frames to measure a load from")
    span = last - first - skip_s
    if span <= 0:
        raise ValueError(f"{path}: the recording spans no time after {skip_s} s")
    return {
        "frames": frames,
        "span_s": span,
        "frames_per_s": frames / span,
        "bits_per_frame": bits / frames,
        "bitrate": bitrate,
        "fraction": bits / span / bitrate,
        "frames_per_s_by_message": {k: v / span for k, v in sorted(by_name.items())},
    }
