"""The scenario side channel, server and client together: JSON lines over a Unix stream socket.

The firmware-sim process serves it (:class:`SideChannel`, non-blocking, one client at a time);
the HIL session, the dry run and the bench connect to it (:class:`ScenarioClient`). An address
starting with ``@`` is in the abstract namespace. The requests and replies are described in
:mod:`hil.session.firmware`. The channel is a side channel of the simulation, never the bus.
"""

from __future__ import annotations

import json
import os
import socket
import time
from typing import Any

from hil.session.outcome import HilError


def unix_address(addr: str) -> str:
    """``@name`` -> abstract-namespace address; anything else is a path."""
    return "\0" + addr[1:] if addr.startswith("@") else addr


class SideChannel:
    """A non-blocking JSON-lines server for one client at a time."""

    def __init__(self, addr: str) -> None:
        self.server = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        real = unix_address(addr)
        if not real.startswith("\0") and os.path.exists(real):
            os.unlink(real)
        self.server.bind(real)
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
