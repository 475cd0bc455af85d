"""The scenario side channel, server and client together: JSON lines over a Unix stream socket.

The firmware-sim process serves it (:class:`SideChannel`, non-blocking, one client at a time);
the HIL session, the dry run and the bench connect to it (:class:`ScenarioClient`). An address
starting with ``@`` is in the abstract namespace. The requests and replies are described in
:mod:`hil.session.firmware`. The channel is a side channel of the simulation, never the bus.

A path address never costs a file that is not the server's own: an existing file there that is not
a socket is refused (:class:`controller.errors.InputError`, exit 3), and so is a socket another
process still serves; only a stale socket (one that no process answers on: a firmware-sim that
was killed) is removed and replaced. The server removes its socket file when it closes, if the
file is still the one it made.
"""

from __future__ import annotations

import errno
import json
import os
import socket
import stat
import time
from typing import Any

from controller.errors import InputError
from hil.session.outcome import HilError


def unix_address(addr: str) -> str:
    """``@name`` -> abstract-namespace address; anything else is a path."""
    return "\0" + addr[1:] if addr.startswith("@") else addr


def claim_address(addr: str, option: str = "--scenario") -> None:
    """Make a path address ``addr`` free for a server, or refuse it in one line naming ``option``:
    an existing file that is not a socket is never removed, nor a socket another process serves;
    a stale socket (nobody answers) is removed. Abstract addresses (``@name``) have no file."""
    real = unix_address(addr)
    if real.startswith("\0") or not os.path.lexists(real):
        return
    try:
        mode = os.lstat(real).st_mode
    except OSError as exc:
        raise InputError(f"{option} {addr}: {exc.strerror}") from None
    if not stat.S_ISSOCK(mode):
        raise InputError(f"{option} {addr}: an existing file that is not a socket; it is left alone (give a path "
                         f"that does not exist, or '@name' for the abstract namespace)")
    probe = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        probe.connect(real)
    except ConnectionRefusedError:  # stale: its server is gone
        os.unlink(real)
        return
    except OSError as exc:
        raise InputError(f"{option} {addr}: an existing socket that cannot be checked ({exc.strerror}); "
                         f"it is left alone") from None
    finally:
        probe.close()
    raise InputError(f"{option} {addr}: another process serves this socket; give another address")


class SideChannel:
    """A non-blocking JSON-lines server for one client at a time (see the module docstring for
    what an existing file at the address gets).

    Raises:
        InputError: the address cannot be served (a file that is not a socket, a socket in use,
            a folder that does not exist, a path too long for a Unix socket).
    """

    def __init__(self, addr: str) -> None:
        real = unix_address(addr)
        claim_address(addr)
        self.server = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        try:
            self.server.bind(real)
        except OSError as exc:
            self.server.close()
            why = "already in use" if exc.errno == errno.EADDRINUSE else (exc.strerror or str(exc))
            raise InputError(f"--scenario {addr}: cannot serve the side channel there: {why}") from None
        self._path = None if real.startswith("\0") else real
        self._ino = None if self._path is None else os.stat(self._path).st_ino
        self.server.listen(1)
        self.server.setblocking(False)
        self.client: socket.socket | None = None
        self._buf = b""

    def poll(self) -> list[dict[str, Any]]:
        if self.client is None:
            try:
                self.client, _ = self.server.accept()
                self.client.setblocking(False)
            except BlockingIOError:
                return []
        try:
            chunk = self.client.recv(65536)
        except BlockingIOError:
            return []
        except OSError:
            chunk = b""
        if not chunk:
            self.client.close()
            self.client = None
            return [{"op": "disconnected"}]
        self._buf += chunk
        out = []
        while b"\n" in self._buf:
            line, self._buf = self._buf.split(b"\n", 1)
            if line.strip():
                try:
                    out.append(json.loads(line))
                except ValueError:
                    out.append({"op": "bad", "line": line[:200].decode(errors="replace")})
        return out

    def send(self, msg: dict[str, Any]) -> None:
        if self.client is None:
            return
        data = (json.dumps(msg) + "\n").encode()
        self.client.setblocking(True)
        try:
            self.client.sendall(data)
        except OSError:
            pass
        finally:
            if self.client is not None:
                self.client.setblocking(False)

    def close(self) -> None:
        if self.client is not None:
            self.client.close()
        self.server.close()
        if self._path is not None:  # our socket file, if it is still ours
            try:
                if os.stat(self._path).st_ino == self._ino:
                    os.unlink(self._path)
            except OSError:
                pass


class ScenarioClient:
    def __init__(self, addr: str, timeout_s: float, alive) -> None:
        deadline = time.monotonic() + timeout_s
        while True:
            self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            try:
                self.sock.connect(unix_address(addr))
                break
            except OSError:
                self.sock.close()
                if not alive():
                    raise HilError("the firmware-sim process ended before opening its side channel")
                if time.monotonic() > deadline:
                    raise HilError(f"no side channel at {addr} after {timeout_s:.0f} s")
                time.sleep(0.2)
        self._buf = b""

    def send(self, msg: dict[str, Any]) -> None:
        self.sock.sendall((json.dumps(msg) + "\n").encode())

    def receive(self, timeout_s: float, alive=lambda: True) -> dict[str, Any]:
        deadline = time.monotonic() + timeout_s
        while b"\n" not in self._buf:
            left = deadline - time.monotonic()
            if left <= 0:
                raise HilError(f"no answer on the side channel within {timeout_s:.0f} s")
            self.sock.settimeout(min(1.0, left))
            try:
                chunk = self.sock.recv(65536)
            except TimeoutError:
                if not alive():
                    raise HilError("a process of the session ended unexpectedly") from None
                continue
            if not chunk:
                raise HilError("the firmware-sim process closed the side channel")
            self._buf += chunk
        line, self._buf = self._buf.split(b"\n", 1)
        return json.loads(line)

    def request(self, msg: dict[str, Any], timeout_s: float = 30.0, expect: str | None = None) -> dict[str, Any]:
        """Send ``msg``, return the reply; with ``expect``, the first reply whose op it is (a
        trial's ``trial_done`` sent meanwhile is skipped)."""
        self.send(msg)
        deadline = time.monotonic() + timeout_s
        while True:
            reply = self.receive(max(1.0, deadline - time.monotonic()))
            if expect is None or reply.get("op") == expect:
                return reply

    def close(self) -> None:
        self.sock.close()
