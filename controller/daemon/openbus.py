"""Opening the CAN bus for the leg's verbs (``run``, ``bringup``): python-can's failure as one line.

:func:`open_bus` is ``can.Bus(**bus_kw)``, except that a bus that cannot be opened raises
:class:`controller.errors.BusError` (exit 4) with one line naming the interface, the channel, the
operating system's (or python-can's) reason and what to check, instead of python-can's exception
and its traceback. The likeliest deployment mistakes, and what this machine's kernel says to them:

- a channel that does not exist (``--channel can9``): ``ENODEV`` (19), "No such device";
- a kernel without SocketCAN (a container, a VM, User-Mode Linux without CAN): ``EAFNOSUPPORT``
  (97), "Address family not supported by protocol", for every channel;
- an interface that is down: ``ENETDOWN`` (100);
- an interface python-can does not know (``--interface nosuch``), or one whose driver or library
  is not installed (``pcan`` without PCANBasic, ``slcan`` without pyserial):
  ``CanInterfaceNotImplementedError`` or an ``OSError`` from the interface's module.

python-can raises many kinds of exception here (an interface module's ``NameError`` when its
vendor library is absent is one); every ``Exception`` from ``can.Bus`` means "no bus", so each is
turned into the one line, with its type named when it is not an ``OSError`` or a ``CanError``.
``KeyboardInterrupt`` passes through.

May import: the standard library, python-can, ``controller.errors``.
"""

from __future__ import annotations

import errno
from typing import Any

import can

from controller.errors import BusError


def describe_bus(bus_kw: dict[str, Any]) -> str:
    """``interface X, channel Y`` as far as ``bus_kw`` says (python-can's configuration otherwise)."""
    interface = bus_kw.get("interface") or bus_kw.get("bustype") or "python-can's configured interface"
    channel = bus_kw.get("channel")
    channel = "python-can's configured channel" if channel in (None, "") else channel
    return f"interface {interface}, channel {channel}"


def _hint(bus_kw: dict[str, Any], exc: BaseException) -> str:
    channel = bus_kw.get("channel") or "can0"
    code = getattr(exc, "errno", None)
    if code == errno.ENODEV:
        return f"no such network interface: check the name and the adapter (ip -details link show; {channel}?)"
    if code == errno.EAFNOSUPPORT:
        return ("this kernel has no SocketCAN (modprobe can can_raw; a container or VM may have no CAN at all; "
                "on a simulated leg: a vcan channel, or --interface virtual)")
    if code == errno.ENETDOWN:
        return f"the interface is down: sudo ip link set {channel} up type can bitrate 1000000"
    if code in (errno.EPERM, errno.EACCES):
        return "not permitted to open it (the daemon's user, the unit's RestrictAddressFamilies=AF_CAN)"
    if isinstance(exc, can.CanInterfaceNotImplementedError):
        known = ", ".join(sorted(getattr(can, "VALID_INTERFACES", ())))
        return f"python-can's interfaces: {known}" if known else "see python-can's list of interfaces"
    interface = bus_kw.get("interface") or bus_kw.get("bustype")
    if interface in (None, "socketcan"):
        return f"is the interface there and up? (ip -details link show {channel})"
    return f"is the {interface} adapter connected, and its driver and library installed?"


def bus_error(bus_kw: dict[str, Any], exc: BaseException) -> BusError:
    """The one-line :class:`BusError` for ``exc``, raised by ``can.Bus(**bus_kw)``."""
    why = " ".join(str(exc).split()) or type(exc).__name__
    if not isinstance(exc, (OSError, can.CanError)):
        why = f"{type(exc).__name__}: {why}"
    return BusError(f"cannot open the CAN bus ({describe_bus(bus_kw)}): {why}; {_hint(bus_kw, exc)}")


def open_bus(bus_kw: dict[str, Any]) -> can.BusABC:
    """``can.Bus(**bus_kw)``; raises :class:`controller.errors.BusError` (one line) if it cannot be opened."""
    try:
        return can.Bus(**bus_kw)
    except Exception as exc:  # noqa: BLE001 - python-can raises many kinds; every one means "no bus"
        raise bus_error(bus_kw, exc) from exc


__all__ = ["bus_error", "describe_bus", "open_bus"]
