"""The lean SocketCAN front borrows python-can internals: it checks them, and falls back to
python-can's own bus when they are absent or behave differently."""

from __future__ import annotations

import can

import controller.daemon.fastbus as fastbus


class FakeSocketcan:
    """Stands in for a SocketcanBus (isinstance is patched to accept it)."""

    socket = None


def test_the_installed_python_can_passes_the_check():
    assert fastbus.internals_work(), f"python-can {can.__version__}: the lean front's internals changed"


def test_a_non_socketcan_bus_is_handed_back_as_it_is():
    bus = can.Bus(interface="virtual", channel="fastbus-test")
    try:
        assert fastbus.lean(bus) is bus
    finally:
        bus.shutdown()


def test_broken_internals_mean_python_cans_own_bus(monkeypatch, caplog):
    monkeypatch.setattr(fastbus, "SocketcanBus", FakeSocketcan)
    monkeypatch.setattr(fastbus, "build_can_frame", lambda msg: b"\x00" * 16)  # a changed frame layout
    bus = FakeSocketcan()
    with caplog.at_level("WARNING", logger="controller.daemon.fastbus"):
        assert fastbus.lean(bus) is bus
    assert "internals are not as expected" in caplog.text


def test_internals_missing_altogether_mean_python_cans_own_bus(monkeypatch):
    monkeypatch.setattr(fastbus, "SocketcanBus", None)
    assert not fastbus.internals_work()
    bus = FakeSocketcan()
    assert fastbus.lean(bus) is bus
