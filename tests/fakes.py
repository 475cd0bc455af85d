"""Small stand-ins for the PyBullet plant and for a CAN bus, used by the tests.

:class:`FakeJointPlant` is a set of independent 1-DOF rotary inertias with viscous damping and
an optional constant load torque, integrated with semi-implicit (symplectic) Euler: velocity
first, then position with the new velocity. :class:`FakeSensorSource` returns whatever range,
range profile and contacts a test sets. :class:`FakeBus` is an in-memory python-can bus: frames
pushed into it are received in order, frames sent are kept, and it raises whatever error a test
sets, on receive or on send. :class:`FsyncSpy` records every ``os.fsync`` (which file, which folder,
in what order).
"""

from __future__ import annotations

import math
import os
import stat
from collections import deque
from dataclasses import dataclass, field
from typing import Iterable

import can


class FakeBus(can.BusABC):
    """An in-memory bus. ``incoming``: frames :meth:`recv` hands out, oldest first; ``sent``:
    frames given to :meth:`send`. ``recv_error`` / ``send_error``: an exception raised by every
    ``recv`` / ``send`` while set. ``closed``: :meth:`shutdown` was called."""

    def __init__(self, frames: Iterable[can.Message] = ()) -> None:
        super().__init__(channel="fake")
        self.incoming: deque[can.Message] = deque(frames)
        self.sent: list[can.Message] = []
        self.recv_error: BaseException | None = None
        self.send_error: BaseException | None = None
        self.closed = False
        self._is_shutdown = True  # nothing to release: no "not properly shut down" warning

    def push(self, *frames: can.Message) -> None:
        self.incoming.extend(frames)

    def recv(self, timeout: float | None = None) -> can.Message | None:  # noqa: ARG002 - never blocks
        if self.recv_error is not None:
            raise self.recv_error
        return self.incoming.popleft() if self.incoming else None

    def send(self, msg: can.Message, timeout: float | None = None) -> None:  # noqa: ARG002
        if self.send_error is not None:
            raise self.send_error
        self.sent.append(msg)

    def _recv_internal(self, timeout: float | None):  # noqa: ARG002 - recv is overridden
        return None, False

    def shutdown(self) -> None:
        self.closed = True


@dataclass
class _Joint:
    q: float = 0.0
    qd: float = 0.0
    tau: float = 0.0


class FakeJointPlant:
    """Independent joints: ``inertia * qdd = tau + load_torque - damping * qd`` (SI units, joint side)."""

    def __init__(
        self,
        joints: dict[str, float] | None = None,
        inertia_kg_m2: float = 0.02,
        damping_nm_s: float = 0.02,
        load_torque_nm: float = 0.0,
    ) -> None:
        self.joints = {name: _Joint(q=q0) for name, q0 in (joints or {"knee": 0.0}).items()}
        self.inertia_kg_m2 = inertia_kg_m2
        self.damping_nm_s = damping_nm_s
        self.load_torque_nm = load_torque_nm
        self.torque_calls = 0
        self.time_s = 0.0

    def joint_state(self, name: str) -> tuple[float, float]:
        j = self.joints[name]
        return j.q, j.qd

    def set_joint_torque(self, name: str, tau_nm: float) -> None:
        if not math.isfinite(tau_nm):
            raise ValueError(f"non-finite torque {tau_nm!r}")
        self.joints[name].tau = tau_nm
        self.torque_calls += 1

    def torque(self, name: str) -> float:
        return self.joints[name].tau

    def set_state(self, name: str, q: float, qd: float = 0.0) -> None:
        j = self.joints[name]
        j.q, j.qd = q, qd

    def step(self, dt_s: float) -> None:
        for j in self.joints.values():
            qdd = (j.tau + self.load_torque_nm - self.damping_nm_s * j.qd) / self.inertia_kg_m2
            j.qd += qdd * dt_s
            j.q += j.qd * dt_s
        self.time_s += dt_s


@dataclass
class FakeSensorSource:
    """A range and two switches set by the test; counts how often each is read."""

    range_value: float | None = 1.0
    profile_value: tuple[float | None, ...] = (None, None, None)
    foot: bool = False
    shin: bool = False
    range_reads: int = field(default=0, init=False)
    contact_reads: int = field(default=0, init=False)

    def range_m(self) -> float | None:
        self.range_reads += 1
        return self.range_value

    def range_profile_m(self) -> tuple[float | None, ...]:
        return self.profile_value

    def contacts(self) -> tuple[bool, bool]:
        self.contact_reads += 1
        return self.foot, self.shin


def drain(bus) -> list:
    """Every frame waiting on ``bus`` (a python-can bus), read without blocking."""
    out = []
    msg = bus.recv(0)
    while msg is not None:
        out.append(msg)
        msg = bus.recv(0)
    return out


class FsyncSpy:
    """Wraps ``os.fsync`` (through pytest's ``monkeypatch``): records, for each call, the
    descriptor's (device, inode) as ``id``, whether it is a folder (``dir``), the inode at ``watch``
    at that moment (``at_path``, None if nothing is there) and the descriptor's path (``path``).
    How the tests see that a writer fsyncs the file and its folder, in order, without kill -9."""

    def __init__(self, monkeypatch, watch) -> None:
        self.calls: list[dict] = []
        self.watch = watch
        real = os.fsync

        def spy(fd):
            st = os.fstat(fd)
            try:
                at_path = os.stat(self.watch).st_ino
            except FileNotFoundError:
                at_path = None
            self.calls.append({"id": (st.st_dev, st.st_ino), "dir": stat.S_ISDIR(st.st_mode), "at_path": at_path,
                               "path": os.readlink(f"/proc/self/fd/{fd}")})
            return real(fd)

        monkeypatch.setattr(os, "fsync", spy)


def ident(path) -> tuple[int, int]:
    """(device, inode) of ``path``: what :class:`FsyncSpy` records as ``id``."""
    st = os.stat(path)
    return st.st_dev, st.st_ino
