"""systemd's side of ``sd_notify``, for the dry run and the tests: a datagram socket that listens.

:class:`NotifyListener` binds an AF_UNIX datagram socket (``@name``: abstract namespace, else a
path; by default a fresh abstract name), turns on ``SO_PASSCRED`` so that every datagram comes
with the sender's process id, uid and gid as the kernel saw them (what systemd checks for
``NotifyAccess=main``), and records each one in a thread: the monotonic time it arrived [s], the
sender's pid and its ``KEY=VALUE`` fields. Give a service its address as ``NOTIFY_SOCKET``.
"""

from __future__ import annotations

import os
import socket
import struct
import threading
import time
import uuid
from dataclasses import dataclass, field

from controller.daemon.sdnotify import socket_address

_UCRED = struct.Struct("iII")  # struct ucred: pid, uid, gid


@dataclass(frozen=True)
class NotifyMessage:
    """One datagram: arrival time (time.monotonic() [s]), sender pid (None if unknown), fields."""

    t_s: float
    pid: int | None
    fields: dict[str, str] = field(default_factory=dict)

    def has(self, key: str, value: str | None = None) -> bool:
        return key in self.fields and (value is None or self.fields[key] == value)


def parse_fields(data: bytes) -> dict[str, str]:
    """``KEY=VALUE`` lines -> dict (a later key wins; lines without '=' are skipped)."""
    out: dict[str, str] = {}
    for line in data.decode("utf-8", "replace").split("\n"):
        key, sep, val = line.partition("=")
        if sep and key:
            out[key] = val
    return out


class NotifyListener:
    """Listen on ``address`` (default: a new ``@elegant-stepping-notify-...`` name) until
    :meth:`stop`; ``messages`` grows as datagrams arrive (read it under ``lock``, or after
    :meth:`stop`)."""

    def __init__(self, address: str | None = None) -> None:
        self.address = address or f"@elegant-stepping-notify-{os.getpid()}-{uuid.uuid4().hex[:8]}"
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_PASSCRED, 1)
        real = socket_address(self.address)
        if not real.startswith("\0") and os.path.exists(real):
            os.unlink(real)
        self.sock.bind(real)
        self.sock.settimeout(0.1)
        self.messages: list[NotifyMessage] = []
        self.lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="notify-listener", daemon=True)

    def start(self) -> NotifyListener:
        self._thread.start()
        return self

    def _run(self) -> None:
        space = socket.CMSG_SPACE(_UCRED.size)
        while not self._stop.is_set():
            try:
                data, ancillary, _flags, _addr = self.sock.recvmsg(4096, space)
            except TimeoutError:
                continue
            except OSError:
                if self._stop.is_set():
                    break
                raise
            t = time.monotonic()
            pid = None
            for level, kind, payload in ancillary:
                if level == socket.SOL_SOCKET and kind == socket.SCM_CREDENTIALS and len(payload) >= _UCRED.size:
                    pid = _UCRED.unpack_from(payload)[0]
            with self.lock:
                self.messages.append(NotifyMessage(t, pid, parse_fields(data)))

    def snapshot(self) -> list[NotifyMessage]:
        with self.lock:
            return list(self.messages)

    def first(self, key: str, value: str | None = None, pid: int | None = None) -> NotifyMessage | None:
        """The first message with ``key`` (= ``value``), from ``pid`` if given."""
        return next((m for m in self.snapshot() if m.has(key, value) and (pid is None or m.pid == pid)), None)

    def wait_for(self, key: str, value: str | None, timeout_s: float, alive=lambda: True,
                 pid: int | None = None) -> NotifyMessage | None:
        """The first message with ``key`` (= ``value``), from ``pid`` if given, waiting up to
        ``timeout_s``; None if it did not come, or ``alive()`` turned False first."""
        deadline = time.monotonic() + timeout_s
        while True:
            found = self.first(key, value, pid)
            if found is not None or time.monotonic() > deadline or not alive():
                return found if found is not None else self.first(key, value, pid)
            time.sleep(0.05)

    def stop(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=5)
        self.sock.close()
        if not self.address.startswith("@"):
            try:
                os.unlink(self.address)
            except OSError:
                pass


__all__ = ["NotifyListener", "NotifyMessage", "parse_fields"]
