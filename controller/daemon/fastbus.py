"""A lean front for python-can's SocketCAN bus, for the real-time processes.

python-can's ``SocketcanBus.recv(timeout=0)`` costs a ``select`` and a ``recvmsg`` per frame, and
``send`` a clock read, a ``select`` and a ``send``. Inside User-Mode Linux every system call is
a ptrace round trip (figures: docs/hil.md), so these add up to a good part of a CPU at our
frame rates. :class:`LeanSocketcan` keeps the bus python-can opened (its configuration,
filters, timestamps, frame layout) and only trims the calls: the socket is made non-blocking,
``recv(0)`` is one ``recvmsg`` (``EAGAIN``: no frame), ``send`` one ``send``; a ``recv`` with a
timeout tries first and waits in one ``select`` only when no frame is there (the simulated-time
protocol's waits: ``hil --clock sim``). Any other bus goes to python-can unchanged.

With ``timestamps=False`` (the controller and the plant: neither reads a frame's timestamp)
frames are read with a plain ``recv``: no kernel timestamp (``timestamp`` is 0.0), and no
source address, whose conversion costs CPython an extra ``ioctl(SIOCGIFNAME)`` per frame.
"""

from __future__ import annotations

import errno
import logging
import select

import can

log = logging.getLogger(__name__)

try:
    from can.interfaces.socketcan import constants as _c
    from can.interfaces.socketcan.socketcan import SocketcanBus, build_can_frame, capture_message, dissect_can_frame
except ImportError:  # python-can without SocketCAN support (not Linux), or internals that moved
    SocketcanBus = None


def internals_work() -> bool:
    """Whether python-can's SocketCAN internals this front borrows (``build_can_frame``,
    ``dissect_can_frame``, the constants) still behave as this module expects: one standard and one
    extended frame built and dissected back. They are not python-can's public API (pyproject.toml
    bounds its version); where they fail, :func:`lean` hands out python-can's own bus instead."""
    if SocketcanBus is None:
        return False
    try:
        for can_id, ext in ((0x123, False), (0x1ABCDEF0 & 0x1FFFFFFF, True)):
            frame = build_can_frame(can.Message(arbitration_id=can_id, is_extended_id=ext, data=b"\x01\x02\x03"))
            got_id, dlc, _flags, data = dissect_can_frame(frame)
            if (got_id & (0x1FFFFFFF if ext else 0x7FF)) != can_id or bool(got_id & _c.CAN_EFF_FLAG) != ext \
                    or dlc != 3 or bytes(data[:dlc]) != b"\x01\x02\x03":
                return False
    except Exception:  # noqa: BLE001 - any failure means: do not use them
        return False
    return True


def _capture_plain(sock) -> can.Message:
    try:
        cf = sock.recv(_c.CANFD_MTU)
    except OSError as error:
        raise can.CanOperationError(f"Error receiving: {error.strerror}", error.errno) from error
    can_id, can_dlc, flags, data = dissect_can_frame(cf)
    ext = bool(can_id & _c.CAN_EFF_FLAG)
    return can.Message(
        timestamp=0.0,
        arbitration_id=can_id & (0x1FFFFFFF if ext else 0x7FF),
        is_extended_id=ext,
        is_remote_frame=bool(can_id & _c.CAN_RTR_FLAG),
        is_error_frame=bool(can_id & _c.CAN_ERR_FLAG),
        is_fd=len(cf) == _c.CANFD_MTU,
        bitrate_switch=bool(flags & _c.CANFD_BRS),
        error_state_indicator=bool(flags & _c.CANFD_ESI),
        dlc=can_dlc,
        data=data,
    )


class LeanSocketcan:
    def __init__(self, bus: can.BusABC, timestamps: bool = True) -> None:
        self.bus = bus
        self.socket = bus.socket
        self.socket.setblocking(False)
        self.channel_info = getattr(bus, "channel_info", "")
        self.received = 0  # frames handed out by recv
        self._capture = capture_message if timestamps else _capture_plain

    def recv(self, timeout: float | None = None) -> can.Message | None:
        """The next frame, or None: at once when none waits (``timeout`` None or 0), else after
        waiting up to ``timeout`` [s] in one ``select`` (a frame already waiting costs no select)."""
        msg = self._try()
        if msg is not None or not timeout:
            return msg
        if not select.select((self.socket,), (), (), timeout)[0]:
            return None
        return self._try()

    def _try(self) -> can.Message | None:
        try:
            msg = self._capture(self.socket)
            self.received += 1
            return msg
        except can.CanOperationError as exc:
            if exc.error_code in (errno.EAGAIN, errno.EWOULDBLOCK):
                return None
            raise

    def send(self, msg: can.Message, timeout: float | None = None) -> None:  # noqa: ARG002
        data = build_can_frame(msg)
        try:
            sent = self.socket.send(data)
        except OSError as error:
            raise can.CanOperationError(f"Failed to transmit: {error.strerror}", error.errno) from error
        if sent != len(data):
            raise can.CanOperationError("Transmit buffer full")

    def shutdown(self) -> None:
        self.bus.shutdown()

    def __getattr__(self, name):
        return getattr(self.bus, name)


def lean(bus: can.BusABC, timestamps: bool = True):
    """``bus`` behind :class:`LeanSocketcan` if it is a SocketCAN bus and python-can's internals
    pass :func:`internals_work`, else ``bus`` itself (slower, the same frames)."""
    if SocketcanBus is not None and isinstance(bus, SocketcanBus):
        if internals_work():
            return LeanSocketcan(bus, timestamps=timestamps)
        log.warning("python-can %s: its SocketCAN internals are not as expected; using its own bus (slower)",
                    can.__version__)
    return bus
