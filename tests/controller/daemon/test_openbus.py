"""A bus that cannot be opened (controller/daemon/openbus.py), and the daemon's other refusals to
start, as the leg's command line reports them: one line naming what is wrong, the exit code of
controller/errors.py (4 the bus, 3 an input), no traceback, nothing left behind (the control
socket removed, the signal handlers given back, no records file)."""

from __future__ import annotations

import errno
import shutil
import signal
import tempfile
import uuid

import can
import pytest

from controller.cli import main
from controller.daemon.openbus import describe_bus, open_bus
from controller.daemon.run import STOP_SIGNALS, StartError, run_controller
from controller.errors import EXIT_BUS, EXIT_INPUT, BusError, InputError

NO_SUCH_CHANNEL_ERRNOS = (errno.ENODEV, errno.EAFNOSUPPORT)
"""What a kernel says to SocketCAN on a channel that does not exist: no such device (19) where it
has SocketCAN, address family not supported (97) where it has none (this project's machines)."""


@pytest.fixture
def short_dir():
    folder = tempfile.mkdtemp(prefix="es-o-", dir="/tmp")  # AF_UNIX paths: at most 107 bytes
    yield folder
    shutil.rmtree(folder, ignore_errors=True)


def one_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert "Traceback" not in err[0] and "this is a bug" not in err[0]
    return err[0]


# -- open_bus ---------------------------------------------------------------------------------
def test_an_unknown_interface_is_a_bus_error_naming_it():
    with pytest.raises(BusError) as exc:
        open_bus({"interface": "nosuch", "channel": "x"})
    text = str(exc.value)
    assert exc.value.exit_code == EXIT_BUS == 4 and "\n" not in text
    assert text.startswith("cannot open the CAN bus (interface nosuch, channel x): Unknown interface type \"nosuch\"")
    assert "socketcan" in text and "virtual" in text  # the interfaces python-can knows


def test_socketcan_on_a_channel_that_does_not_exist_is_a_bus_error_with_the_systems_reason():
    with pytest.raises(BusError) as exc:
        open_bus({"interface": "socketcan", "channel": "can9"})
    text = str(exc.value)
    assert isinstance(exc.value.__cause__, OSError) and exc.value.__cause__.errno in NO_SUCH_CHANNEL_ERRNOS
    assert text.startswith("cannot open the CAN bus (interface socketcan, channel can9): [Errno ")
    assert "No such device" in text or "Address family not supported" in text


@pytest.mark.parametrize("raised,words", [
    (OSError(errno.ENODEV, "No such device"), ["[Errno 19] No such device", "no such network interface", "can9"]),
    (OSError(errno.EAFNOSUPPORT, "Address family not supported by protocol"),
     ["[Errno 97]", "this kernel has no SocketCAN", "--interface virtual"]),
    (OSError(errno.ENETDOWN, "Network is down"), ["[Errno 100] Network is down", "sudo ip link set can9 up"]),
    (OSError(errno.EPERM, "Operation not permitted"), ["[Errno 1]", "not permitted"]),
    (can.CanInitializationError("adapter on fire"), ["adapter on fire", "ip -details link show can9"]),
    (NameError("name 'canGetNumberOfChannels' is not defined"), ["NameError: name 'canGetNumberOfChannels'"]),
])
def test_every_failure_of_python_can_is_one_line_with_what_to_check(raised, words, monkeypatch):
    def fails(**kw):
        raise raised

    monkeypatch.setattr(can, "Bus", fails)
    with pytest.raises(BusError) as exc:
        open_bus({"interface": "socketcan", "channel": "can9"})
    text = str(exc.value)
    assert text.startswith("cannot open the CAN bus (interface socketcan, channel can9): ") and "\n" not in text
    for word in words:
        assert word in text, text
    assert exc.value.__cause__ is raised


def test_an_interrupt_while_opening_is_not_a_bus_error(monkeypatch):
    def interrupted(**kw):
        raise KeyboardInterrupt

    monkeypatch.setattr(can, "Bus", interrupted)
    with pytest.raises(KeyboardInterrupt):
        open_bus({"interface": "virtual"})


def test_describe_bus_says_where_python_can_configures_it():
    assert describe_bus({}) == "interface python-can's configured interface, channel python-can's configured channel"
    assert describe_bus({"interface": "pcan", "channel": "PCAN_USBBUS1"}) == "interface pcan, channel PCAN_USBBUS1"


def test_a_bus_that_opens_is_returned():
    bus = open_bus({"interface": "virtual", "channel": f"ok-{uuid.uuid4().hex[:8]}"})
    try:
        assert isinstance(bus, can.BusABC)
    finally:
        bus.shutdown()


# -- the daemon -------------------------------------------------------------------------------
def test_the_daemon_without_a_bus_raises_a_bus_error_and_leaves_nothing_behind(short_dir, tmp_path):
    socket_path = f"{short_dir}/c.sock"
    before = {s: signal.getsignal(s) for s in STOP_SIGNALS}
    with pytest.raises(BusError, match=r"\(interface nosuch, channel x\)"):
        run_controller({"interface": "nosuch", "channel": "x"}, control_socket=socket_path,
                       records=tmp_path / "r.jsonl", duration_s=0.1)
    assert {s: signal.getsignal(s) for s in STOP_SIGNALS} == before  # the handlers given back
    assert not list(tmp_path.iterdir())  # no records begun
    from pathlib import Path

    assert not Path(socket_path).exists()  # the control socket closed and removed


@pytest.mark.parametrize("interface,channel", [("socketcan", "can9"), ("nosuch", "can0")])
def test_run_without_a_bus_is_exit_4_in_one_line_naming_interface_and_channel(interface, channel, capsys):
    rc = main(["run", "--interface", interface, "--channel", channel, "--socket", "none", "--seconds", "0.1"])
    line = one_line(capsys)
    assert rc == 4
    assert line.startswith(f"elegant-stepping-leg run: error: cannot open the CAN bus (interface {interface}, "
                           f"channel {channel}): "), line


def test_a_control_socket_that_cannot_be_made_is_exit_3(short_dir, capsys):
    blocker = f"{short_dir}/file"
    with open(blocker, "w") as f:
        f.write("not a folder")
    rc = main(["run", "--interface", "virtual", "--channel", f"x-{uuid.uuid4().hex[:6]}", "--socket",
               f"{blocker}/c.sock", "--seconds", "0.1"])
    line = one_line(capsys)
    assert rc == 3 and line.startswith(f"elegant-stepping-leg run: error: control socket: cannot create the folder "
                                       f"{blocker}"), line
    with pytest.raises(StartError) as exc:
        run_controller({"interface": "virtual"}, control_socket=f"{blocker}/c.sock", duration_s=0.1)
    assert isinstance(exc.value, InputError) and exc.value.exit_code == EXIT_INPUT


def test_a_records_file_that_cannot_be_written_is_exit_3_and_closes_the_bus(tmp_path, capsys, monkeypatch):
    (tmp_path / "file").write_text("not a folder")
    opened: list[can.BusABC] = []
    real = can.Bus

    def spy(**kw):
        bus = real(**kw)
        opened.append(bus)
        return bus

    monkeypatch.setattr(can, "Bus", spy)
    for option in ("--records", "--ticks"):
        rc = main(["run", "--interface", "virtual", "--channel", f"x-{uuid.uuid4().hex[:6]}", "--socket", "none",
                   "--seconds", "0.1", option, str(tmp_path / "file" / "out")])
        line = one_line(capsys)
        out = tmp_path / "file" / "out"
        assert rc == 3 and line.startswith(f"elegant-stepping-leg run: error: cannot write {out}: Not a directory"), line
    assert len(opened) == 2 and all(b._is_shutdown for b in opened)  # the bus given back each time


def test_a_missing_or_invalid_configuration_is_exit_3(tmp_path, capsys):
    missing = tmp_path / "none.toml"
    assert main(["run", "--config", str(missing)]) == 3
    assert one_line(capsys) == (f"elegant-stepping-leg run: error: {missing}: cannot read the configuration: No such "
                                "file or directory")
    bad = tmp_path / "bad.toml"
    bad.write_text("[bus]\ninterface = \"virtual\"\nchannel = \"x\"\n[axes.knee]\ngear_ratio = -6\nnode_id = 0\n")
    assert main(["run", "--config", str(bad)]) == 3
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1] == (f"elegant-stepping-leg run: error: {bad}: 2 problems in the configuration (each on its own "
                       "line above)")
    assert any(line.startswith(f"{bad}: axes.knee.gear_ratio = -6: must be in [0.1, 1000] rev/rev") for line in err)
