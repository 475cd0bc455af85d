"""The daemon's control socket: how a person (``elegant-stepping-leg status|arm|disarm|clear-faults|estop``)
commands the running controller.

The protocol: a Unix ``SOCK_STREAM`` socket at ``[service] control_socket``
(``/run/elegant-stepping/control.sock`` by default). A client connects, sends ONE line of JSON,
``{"verb": "status"|"arm"|"disarm"|"clear-faults"|"estop"}``, and reads ONE line of JSON back,
``{"ok": bool, "verb": str|null, "refused": str|null, "status": dict|null}``; the daemon then closes the
connection. ``ok`` is true when the command was accepted (``status`` always is), ``refused`` the
one-line reason when it was not (a bad request, a command the controller refused, ``"daemon busy"``),
``status`` the daemon's status (:meth:`controller.loop.ControlLoop.status` and the daemon's own
fields) taken right after the command ran (None for a request that never reached the loop).

Threads: :class:`ControlServer` accepts and parses on threads of its own, but never touches the
control loop: each valid request is queued, and the loop's own thread runs the queue at the start
of a tick (:meth:`ControlServer.run_pending`), because ``ControlLoop``'s methods are not
thread-safe. The connection's thread waits for the reply at most :data:`REPLY_TIMEOUT_S` (2 s);
a request the loop has not taken by then is withdrawn (it never runs) and answered
``"daemon busy"``. A request line longer than :data:`MAX_REQUEST_BYTES`, not JSON, not an object or
with an unknown verb is answered ``ok: false`` with the reason; nothing a client sends stops the
server.

Permissions: the socket file is made mode 0660 (bound under umask 0117, then chmod'ed), so only its
owner (the daemon's user) and its group may connect. Its group is ``[service] control_group`` when
given (``""``: the daemon's own primary group): ``chown`` to a group is permitted to root, or to a
user that is a member of that group; a group the daemon may not give the socket to is logged as a
warning and the socket keeps the daemon's group. A group that does not exist refuses the start. A
person commands the leg by being in that group (``usermod -aG elegant-stepping NAME``). The folder
(``/run/elegant-stepping``, systemd's ``RuntimeDirectory=``) is created if missing.

Start and exit: a socket file left at the path by a daemon that died is removed, but only if
nothing answers on it; a path where another daemon listens, or that is not a socket, refuses the
start. At exit the file is removed if it is still ours (same inode).

:func:`request` is the client: one request, its reply as a dict, or :class:`ControlError` with a
one-line message. Its exit code (:mod:`controller.errors`), for the leg verbs: **4** when no daemon
answers (no socket file, nothing listening on it, no reply within the timeout, the connection
closed, a reply that is not the protocol's): the control socket is the verbs' link to the leg, as
the CAN bus is the daemon's, and "a node on it does not answer" is exit 4; **3** when the socket is
there but this user may not connect (:class:`ControlPermissionError`, naming the socket's group):
like any file the user may not open, an input to fix (``usermod -aG``), not an absent daemon.
A socket that cannot be created at start is :class:`ControlSocketError` (exit 3, the daemon does not
start).

May import: the standard library and :mod:`controller.errors` (standard library only) (the leg
verbs import it inside ``run``).
"""

from __future__ import annotations

import grp
import json
import logging
import os
import queue
import socket
import stat
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from controller.errors import EXIT_INPUT, BusError, InputError

log = logging.getLogger(__name__)

DEFAULT_SOCKET = "/run/elegant-stepping/control.sock"
SERVICE = "elegant-stepping-controller"
VERBS = ("status", "arm", "disarm", "clear-faults", "estop")
REPLY_TIMEOUT_S = 2.0
MAX_REQUEST_BYTES = 4096
READ_TIMEOUT_S = 2.0  # a client that connects and never sends its line
MAX_CLIENTS = 8


class ControlError(BusError):
    """A control request that got no reply from a daemon: the one-line message says why (exit 4)."""


class ControlPermissionError(ControlError):
    """The control socket is there, but this user may not connect to it (exit 3: join its group)."""

    exit_code = EXIT_INPUT


class ControlSocketError(InputError):
    """The control socket cannot be created (the daemon refuses to start: exit 3, one line)."""


def reply(verb: str | None, refused: str | None, status: dict[str, Any] | None) -> dict[str, Any]:
    return {"ok": refused is None, "verb": verb, "refused": refused, "status": status}


def parse_request(line: bytes) -> tuple[str | None, str | None]:
    """``(verb, None)`` for a valid request line, ``(verb or None, reason)`` for a bad one."""
    try:
        obj = json.loads(line.decode("utf-8"))
    except (UnicodeDecodeError, ValueError):
        return None, 'bad request: not a JSON line (send {"verb": "status"})'
    if not isinstance(obj, dict):
        return None, 'bad request: a JSON object expected, e.g. {"verb": "status"}'
    verb = obj.get("verb")
    if not isinstance(verb, str):
        return None, f"bad request: no verb (one of {', '.join(VERBS)})"
    if verb not in VERBS:
        return verb[:64], f"unknown verb {verb[:64]!r} (one of {', '.join(VERBS)})"
    return verb, None


@dataclass
class Pending:
    """One request waiting for the loop's thread."""

    verb: str
    state: str = "queued"  # queued -> taken -> done, or queued -> withdrawn
    result: dict[str, Any] | None = None
    done: threading.Event = field(default_factory=threading.Event)
    lock: threading.Lock = field(default_factory=threading.Lock)


class ControlServer:
    """The daemon's side. ``start()`` creates the socket and the accepting thread;
    ``run_pending(execute)`` on the loop's thread runs the queued requests, ``execute(verb) ->
    (refused, status)``; ``close()`` stops accepting and removes the socket file. ``wait(event,
    timeout_s)``: how a connection's thread waits for the loop to run its request (default
    ``threading.Event.wait``; a test gives its own to decide when the reply timeout has passed)."""

    def __init__(self, path: str | os.PathLike, group: str = "", reply_timeout_s: float = REPLY_TIMEOUT_S,
                 wait: Callable[[threading.Event, float], bool] = threading.Event.wait) -> None:
        self.path = Path(path)
        self.group = group
        self.reply_timeout_s = reply_timeout_s
        self.wait = wait  # wait(event, timeout_s) -> set?: how a connection waits for the loop (a test's clock)
        self.requests = 0  # answered, valid or not
        self.executed = 0
        self.busy = 0
        self.bad = 0
        self._queue: queue.SimpleQueue[Pending] = queue.SimpleQueue()
        self._sock: socket.socket | None = None
        self._ino: int | None = None
        self._thread: threading.Thread | None = None
        self._closing = threading.Event()
        self._slots = threading.BoundedSemaphore(MAX_CLIENTS)

    # -- start and stop ---------------------------------------------------------------------
    def _gid(self) -> int | None:
        if not self.group:
            return None
        try:
            return grp.getgrnam(self.group).gr_gid
        except KeyError:
            raise ControlSocketError(f"control socket: group {self.group!r} ([service] control_group) does not "
                                     f"exist (create it: groupadd {self.group}, or leave control_group empty)") from None

    def _clear_stale(self) -> None:
        try:
            st = os.lstat(self.path)
        except FileNotFoundError:
            return
        if not stat.S_ISSOCK(st.st_mode):
            raise ControlSocketError(f"control socket: {self.path} exists and is not a socket: not touching it "
                                     f"(remove it, or set [service] control_socket)")
        probe = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        probe.settimeout(1.0)
        try:
            probe.connect(str(self.path))
        except (ConnectionRefusedError, FileNotFoundError):
            log.warning("control socket: removing the stale %s (nothing listens on it)", self.path)
            self.path.unlink(missing_ok=True)
            return
        except OSError as exc:
            raise ControlSocketError(f"control socket: {self.path} exists and cannot be probed ({exc})") from None
        finally:
            probe.close()
        raise ControlSocketError(f"control socket: another daemon listens on {self.path} (systemctl status {SERVICE})")

    def start(self) -> "ControlServer":
        gid = self._gid()
        if len(os.fsencode(self.path)) > 107:
            raise ControlSocketError(f"control socket: the path {self.path} is longer than AF_UNIX's 107 bytes")
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise ControlSocketError(f"control socket: cannot create the folder {self.path.parent} ({exc})") from None
        self._clear_stale()
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        old = os.umask(0o117)  # born 0660: no instant at which others may connect
        try:
            sock.bind(str(self.path))
        except OSError as exc:
            sock.close()
            raise ControlSocketError(f"control socket: cannot create {self.path} ({exc})") from None
        finally:
            os.umask(old)
        try:
            os.chmod(self.path, 0o660)
            if gid is not None:
                try:
                    os.chown(self.path, -1, gid)
                except PermissionError:
                    log.warning("control socket: may not give %s to the group %s (the daemon's user is not in it): "
                                "it keeps the daemon's group", self.path, self.group)
            sock.listen(MAX_CLIENTS)
            sock.settimeout(0.2)
            self._ino = os.stat(self.path).st_ino
        except OSError as exc:
            sock.close()
            self.path.unlink(missing_ok=True)
            raise ControlSocketError(f"control socket: cannot set up {self.path} ({exc})") from None
        self._sock = sock
        self._thread = threading.Thread(target=self._accept, name="control-socket", daemon=True)
        self._thread.start()
        st = os.stat(self.path)
        try:
            group = grp.getgrgid(st.st_gid).gr_name
        except KeyError:
            group = str(st.st_gid)
        log.info("control socket: %s (mode %o, group %s)", self.path, stat.S_IMODE(st.st_mode), group)
        return self

    def close(self) -> None:
        """Stop accepting, answer what is still queued "daemon stopping", remove the socket file."""
        self._closing.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        if self._sock is not None:
            self._sock.close()
            self._sock = None
            try:
                if os.stat(self.path).st_ino == self._ino:
                    self.path.unlink()
            except FileNotFoundError:
                pass
        self._drain("daemon stopping")

    def _drain(self, why: str) -> None:
        while True:
            try:
                p = self._queue.get_nowait()
            except queue.Empty:
                return
            with p.lock:
                if p.state == "queued":
                    p.state = "withdrawn"
                    p.result = reply(p.verb, why, None)
                    p.done.set()

    # -- the loop's side ----------------------------------------------------------------------
    def run_pending(self, execute: Callable[[str], tuple[str | None, dict[str, Any] | None]]) -> int:
        """Run every queued request on the caller's thread (the control loop's); how many ran.
        ``execute(verb)`` returns ``(refused or None, status)``; an exception in it is answered as
        a refusal (and logged), never raised into the loop."""
        n = 0
        while True:
            try:
                p = self._queue.get_nowait()
            except queue.Empty:
                return n
            with p.lock:
                if p.state != "queued":
                    continue  # withdrawn: its client was told "daemon busy"
                p.state = "taken"
            try:
                refused, status = execute(p.verb)
                result = reply(p.verb, refused, status)
            except Exception as exc:  # noqa: BLE001 - never into the control loop
                log.exception("control socket: %s failed", p.verb)
                result = reply(p.verb, f"internal error: {type(exc).__name__}: {exc}", None)
            with p.lock:
                p.result = result
                p.state = "done"
            p.done.set()
            self.executed += 1
            n += 1

    # -- the server's threads -----------------------------------------------------------------
    def _accept(self) -> None:
        sock = self._sock
        assert sock is not None
        while not self._closing.is_set():
            try:
                conn, _ = sock.accept()
            except socket.timeout:
                continue
            except OSError as exc:
                if self._closing.is_set():
                    return
                log.warning("control socket: accept failed: %s", exc)
                continue
            if not self._slots.acquire(blocking=False):
                self._answer(conn, reply(None, "daemon busy (too many clients)", None))
                continue
            threading.Thread(target=self._serve, args=(conn,), name="control-client", daemon=True).start()

    def _answer(self, conn: socket.socket, result: dict[str, Any]) -> None:
        self.requests += 1
        try:
            conn.settimeout(1.0)
            conn.sendall((json.dumps(result) + "\n").encode("utf-8"))
        except OSError:
            pass  # the client left
        finally:
            conn.close()

    def _read_line(self, conn: socket.socket) -> tuple[bytes | None, str | None]:
        conn.settimeout(READ_TIMEOUT_S)
        buf = b""
        try:
            while b"\n" not in buf:
                chunk = conn.recv(1024)
                if not chunk:
                    break
                buf += chunk
                if len(buf) > MAX_REQUEST_BYTES:
                    return None, f"bad request: longer than {MAX_REQUEST_BYTES} bytes"
        except socket.timeout:
            if not buf:
                return None, f"bad request: no request line within {READ_TIMEOUT_S:g} s"
        except OSError as exc:
            return None, f"bad request: {exc}"
        line = buf.split(b"\n", 1)[0]
        if len(line) > MAX_REQUEST_BYTES:
            return None, f"bad request: longer than {MAX_REQUEST_BYTES} bytes"
        if not line.strip():
            return None, 'bad request: an empty line (send {"verb": "status"})'
        return line, None

    def _serve(self, conn: socket.socket) -> None:
        try:
            line, why = self._read_line(conn)
            if why is not None:
                self.bad += 1
                self._answer(conn, reply(None, why, None))
                return
            verb, why = parse_request(line)
            if why is not None:
                self.bad += 1
                self._answer(conn, reply(verb, why, None))
                return
            if self._closing.is_set():
                self._answer(conn, reply(verb, "daemon stopping", None))
                return
            p = Pending(verb)
            self._queue.put(p)
            if not self.wait(p.done, self.reply_timeout_s):
                with p.lock:
                    if p.state == "queued":
                        p.state = "withdrawn"  # never runs
                        p.result = reply(verb, "daemon busy", None)
                        self.busy += 1
                if p.state == "taken":  # running on the loop's thread right now: it ends within a tick
                    self.wait(p.done, self.reply_timeout_s)
            with p.lock:
                result = p.result if p.result is not None else reply(verb, "daemon busy", None)
            self._answer(conn, result)
        except Exception:  # noqa: BLE001 - a client never stops the server
            log.exception("control socket: a request failed")
            try:
                conn.close()
            except OSError:
                pass
        finally:
            self._slots.release()

    def summary(self) -> dict[str, Any]:
        return {"socket": str(self.path), "requests": self.requests, "executed": self.executed,
                "busy": self.busy, "bad": self.bad}


# -- the client -------------------------------------------------------------------------------
def _group_of(path: Path) -> str:
    try:
        gid = os.stat(path).st_gid
    except OSError:
        return "the daemon's group"
    try:
        return grp.getgrgid(gid).gr_name
    except KeyError:
        return f"gid {gid}"


def request(path: str | os.PathLike, verb: str, timeout_s: float = 5.0) -> dict[str, Any]:
    """Send ``{"verb": verb}`` to the daemon at ``path``; its reply. Raises :class:`ControlError`
    with a one-line message when no reply came."""
    path = Path(path)
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    sock.settimeout(timeout_s)
    try:
        try:
            sock.connect(str(path))
        except (FileNotFoundError, ConnectionRefusedError):
            raise ControlError(f"no daemon at {path} (is it running? systemctl status {SERVICE})") from None
        except PermissionError:
            group = _group_of(path)
            raise ControlPermissionError(f"permission denied on {path}: commanding the leg needs the group {group} "
                               f"(sudo usermod -aG {group} $USER, then log in again)") from None
        except socket.timeout:
            raise ControlError(f"no answer from {path} within {timeout_s:g} s (systemctl status {SERVICE})") from None
        except OSError as exc:
            raise ControlError(f"cannot connect to {path}: {exc}") from None
        buf = b""
        try:
            sock.sendall((json.dumps({"verb": verb}) + "\n").encode("utf-8"))
            while b"\n" not in buf:
                chunk = sock.recv(65536)
                if not chunk:
                    break
                buf += chunk
        except socket.timeout:
            raise ControlError(f"no reply from the daemon at {path} within {timeout_s:g} s") from None
        except OSError as exc:
            raise ControlError(f"the daemon at {path} closed the connection: {exc}") from None
    finally:
        sock.close()
    if not buf.strip():
        raise ControlError(f"the daemon at {path} closed the connection without a reply")
    try:
        out = json.loads(buf.split(b"\n", 1)[0].decode("utf-8"))
    except ValueError:
        raise ControlError(f"the daemon at {path} replied something that is not JSON") from None
    if not isinstance(out, dict) or "ok" not in out:
        raise ControlError(f"the daemon at {path} replied an unexpected message")
    return out


__all__ = ["ControlError", "ControlPermissionError", "ControlServer", "ControlSocketError", "DEFAULT_SOCKET", "VERBS",
           "parse_request",
           "reply", "request"]
