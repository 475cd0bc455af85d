"""The bus recorder on a real SocketCAN vcan0 (natively, or inside User-Mode Linux): run by
tests/vcan/test_recorder_vcan.py, not collected by pytest.

Two recordings, each of frames sent by another python-can SocketCAN bus on vcan0:

1. ``lossy``: a :class:`hil.session.recorder.BusRecorder` whose socket's receive buffer is shrunk
   to the kernel's minimum (``SO_RCVBUF`` set after construction) gets a burst of
   :data:`BURST` frames before it drains at all, so the kernel must drop most of them; then, once
   it has drained, :data:`TRICKLE` more frames one at a time (each waited for), which the kernel
   hands over with its drop count attached (``SO_RXQ_OVFL``): the count the recorder had read
   before ``stop`` (``lost_before_stop``) is the ancillary data's, the one after is also
   ``SO_MEMINFO``'s.
2. ``lossless``: a recorder with its own (large) buffer, started first, gets :data:`MODEST` frames.

Usage: python3 tests/vcan/recorder_vcan_session.py OUT_DIR. Writes OUT_DIR/session.json (per
recording: the frames sent, as [id, data hex] in order; the recorder's counts; its metadata; the
frames its log holds, read back with python-can) and exits 0 once everything ran (the test judges).
"""

from __future__ import annotations

import json
import os
import socket
import struct
import sys
import time
from pathlib import Path

import can

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # a script: the repository's packages
from hil.analysis.buslog import read_metadata  # noqa: E402
from hil.profile import current  # noqa: E402
from hil.session.recorder import BusRecorder  # noqa: E402

CHANNEL = "vcan0"
BURST, TRICKLE, MODEST = 2000, 10, 500
GIVE_UP_S = 60.0  # a deadline for waiting on the recorder, not a measurement


def frame(i: int) -> can.Message:
    """Frame ``i`` of a recording: an id and data that differ from its neighbours'."""
    return can.Message(arbitration_id=0x100 + i % 0x600, is_extended_id=False,
                       data=struct.pack("<IHBB", i, (i * 7919) & 0xFFFF, i & 0xFF, 0xA5))


def as_row(msg: can.Message) -> list:
    return [msg.arbitration_id, bytes(msg.data).hex()]


def wait_until(condition, timeout_s: float = GIVE_UP_S) -> bool:
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.02)
    return True


def wait_drained(rec: BusRecorder) -> bool:
    """True once the recorder's count has stood still for 0.3 s (it drains every 10 ms)."""
    last, since = -1, time.monotonic()
    deadline = since + GIVE_UP_S
    while time.monotonic() < deadline:
        if rec.frames != last:
            last, since = rec.frames, time.monotonic()
        elif time.monotonic() - since > 0.3:
            return True
        time.sleep(0.02)
    return False


def report(rec: BusRecorder, path: Path, sent: list, **extra) -> dict:
    return {"sent": sent, "frames": rec.frames, "frames_lost": rec.frames_lost, "error": rec.error,
            "metadata": read_metadata(path), "logged": [as_row(m) for m in can.LogReader(str(path))], **extra}


def lossy(out: Path, tx: can.BusABC) -> dict:
    path = out / "lossy.log"
    rec = BusRecorder(CHANNEL, path)
    sock = rec.raw.socket
    asked = sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1)  # the kernel rounds up to its minimum
    rcvbuf = sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)
    sent = []
    for i in range(BURST):  # nobody reads the recorder's socket yet
        msg = frame(i)
        tx.send(msg)
        sent.append(as_row(msg))
    rec.start()
    drained = wait_drained(rec)
    for i in range(BURST, BURST + TRICKLE):  # one at a time: each reaches the queue, with the drop count
        msg = frame(i)
        before = rec.frames
        tx.send(msg)
        sent.append(as_row(msg))
        wait_until(lambda: rec.frames > before)
    lost_before_stop = rec.frames_lost
    rec.stop()
    return report(rec, path, sent, rcvbuf_default=asked, rcvbuf=rcvbuf, drained=drained,
                  lost_before_stop=lost_before_stop)


def lossless(out: Path, tx: can.BusABC) -> dict:
    path = out / "lossless.log"
    rec = BusRecorder(CHANNEL, path)
    rcvbuf = rec.raw.socket.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)
    rec.start()
    sent = []
    for i in range(MODEST):
        msg = frame(i)
        tx.send(msg)
        sent.append(as_row(msg))
    drained = wait_drained(rec)
    rec.stop()
    return report(rec, path, sent, rcvbuf=rcvbuf, rcvbuf_bytes=rec.rcvbuf_bytes, drained=drained)


def main(out: Path) -> int:
    out.mkdir(parents=True, exist_ok=True)
    session: dict = {"where": current().name, "privileged": os.geteuid() == 0}
    tx = can.Bus(interface="socketcan", channel=CHANNEL)
    try:
        session["lossy"] = lossy(out, tx)
        session["lossless"] = lossless(out, tx)
    finally:
        tx.shutdown()
    (out / "session.json").write_text(json.dumps(session) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main(Path(sys.argv[1])))
