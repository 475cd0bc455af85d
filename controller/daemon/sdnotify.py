"""systemd's service notification protocol (``sd_notify``), from the standard library only.

A service started with ``Type=notify`` finds in ``$NOTIFY_SOCKET`` the address of an AF_UNIX
datagram socket on which systemd listens (a path, or ``@name`` for the abstract namespace) and
sends it newline-separated ``KEY=VALUE`` assignments: ``READY=1`` (start-up finished),
``STATUS=...`` (one line shown by ``systemctl status``), ``WATCHDOG=1`` (a keep-alive ping),
``STOPPING=1`` (shutdown begun). With ``WatchdogSec=`` in the unit, systemd also sets
``WATCHDOG_USEC`` (the limit [us]) and ``WATCHDOG_PID`` (the process that must ping); a service
that does not ping within the limit is killed (SIGABRT) and, with ``Restart=on-failure``,
started again.

:class:`Notifier` is a no-op when ``NOTIFY_SOCKET`` is unset (every call returns False and does
nothing else), so the same daemon runs by hand, under ``hil`` and under systemd. It never
raises: a failed send (no listener, a full socket buffer, an address family it cannot use) is
counted in ``errors`` and logged once, and the caller goes on. The socket is non-blocking, so a
send costs one system call and never waits. Pings are paced by the caller's clock:
:meth:`Notifier.watchdog` is cheap to call every control tick (one float comparison) and sends
``WATCHDOG=1`` only when one is due, every half of ``WATCHDOG_USEC`` (systemd's own advice), and
only if ``WATCHDOG_PID`` is unset or is this process. Call it from the loop that must stay
alive, never from a thread of its own: a ping must mean that the loop ran.
"""

from __future__ import annotations

import logging
import math
import os
import socket
from typing import Mapping

log = logging.getLogger(__name__)


def socket_address(addr: str) -> str:
    """``@name`` -> the abstract-namespace address (leading NUL); a path stays a path."""
    return "\0" + addr[1:] if addr.startswith("@") else addr


def watchdog_usec_from(environ: Mapping[str, str], pid: int) -> int | None:
    """The watchdog limit [us] systemd asks this process to keep, or None (no watchdog, a bad
    value, or a WATCHDOG_PID that is another process)."""
    text = environ.get("WATCHDOG_USEC")
    if not text:
        return None
    try:
        usec = int(text)
    except ValueError:
        log.warning("sd_notify: WATCHDOG_USEC=%r is not an integer; not pinging", text)
        return None
    if usec <= 0:
        return None
    owner = environ.get("WATCHDOG_PID")
    if owner:
        try:
            if int(owner) != pid:
                log.info("sd_notify: WATCHDOG_PID=%s is not this process (%d); not pinging", owner, pid)
                return None
        except ValueError:
            log.warning("sd_notify: WATCHDOG_PID=%r is not a process id; not pinging", owner)
            return None
    return usec


class Notifier:
    """The service's side of ``sd_notify``.

    Attributes:
        address: ``$NOTIFY_SOCKET`` as given (None: notifications off).
        watchdog_usec: the watchdog limit [us] this process must keep (None: no pings).
        ping_period_s: the interval between pings [s], half of ``watchdog_usec`` (None: no pings).
        sent: notifications handed to the socket; ``pings``: of them, ``WATCHDOG=1``;
        errors: sends that failed (counted, logged once, never raised).
    """

    def __init__(self, environ: Mapping[str, str] | None = None, pid: int | None = None) -> None:
        env = os.environ if environ is None else environ
        self.pid = os.getpid() if pid is None else pid
        self.address: str | None = env.get("NOTIFY_SOCKET") or None
        self.watchdog_usec = watchdog_usec_from(env, self.pid) if self.address else None
        self.ping_period_s = None if self.watchdog_usec is None else self.watchdog_usec / 2e6
        self.sent = 0
        self.pings = 0
        self.errors = 0
        self.last_error: str | None = None
        self._next_ping_s = -math.inf
        self._sock: socket.socket | None = None
        self._target = None if self.address is None else socket_address(self.address)
        if self._target is not None:
            if not self._target.startswith(("\0", "/")):
                self._fail(f"unsupported NOTIFY_SOCKET {self.address!r} (a path or @name expected)")
                self._target = None
            else:
                try:
                    self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
                    self._sock.setblocking(False)
                except OSError as exc:
                    self._fail(f"cannot open an AF_UNIX datagram socket: {exc}")
                    self._target = None

    @property
    def enabled(self) -> bool:
        """True when notifications go somewhere."""
        return self._sock is not None and self._target is not None

    def _fail(self, why: str) -> None:
        self.errors += 1
        self.last_error = why
        if self.errors == 1:
            log.warning("sd_notify: %s (further failures are only counted)", why)

    def notify(self, **fields: str | int) -> bool:
        """Send one notification, e.g. ``notify(READY=1, STATUS="walking")``; True if sent."""
        if not self.enabled:
            return False
        text = "\n".join(f"{key}={str(value).replace(chr(10), ' ')}" for key, value in fields.items())
        try:
            self._sock.sendto(text.encode("utf-8", "replace"), self._target)  # type: ignore[union-attr]
        except Exception as exc:  # noqa: BLE001 - never into the control loop
            self._fail(f"send to {self.address!r} failed: {exc!r}")
            return False
        self.sent += 1
        return True

    def ready(self, status: str) -> bool:
        return self.notify(READY=1, STATUS=status)

    def status(self, status: str) -> bool:
        return self.notify(STATUS=status)

    def stopping(self, status: str) -> bool:
        return self.notify(STOPPING=1, STATUS=status)

    def watchdog(self, now_s: float) -> bool:
        """Ping if one is due at ``now_s`` (any monotonic clock [s]); True if a ping was sent.
        The first call pings; then one every ``ping_period_s``. A failed ping is retried on the
        next call."""
        if self.ping_period_s is None or now_s < self._next_ping_s:
            return False
        if not self.notify(WATCHDOG=1):
            return False
        self.pings += 1
        self._next_ping_s = now_s + self.ping_period_s
        return True

    def summary(self) -> dict[str, object]:
        return {"socket": self.address, "watchdog_usec": self.watchdog_usec, "sent": self.sent,
                "pings": self.pings, "errors": self.errors, "last_error": self.last_error}

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None


__all__ = ["Notifier", "socket_address", "watchdog_usec_from"]
