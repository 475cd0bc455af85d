"""The scenario side channel's address: never a file that is not the server's own."""

from __future__ import annotations

import socket

import pytest

from controller.errors import InputError
from hil.session.scenario import SideChannel, claim_address


@pytest.fixture
def short_tmp(tmp_path_factory):
    """A folder with a path short enough for a Unix socket (108 bytes)."""
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory(prefix="es-sc-", dir="/tmp") as d:
        yield Path(d)


def test_an_existing_file_that_is_not_a_socket_is_refused_and_left_alone(short_tmp):
    notes = short_tmp / "notes.txt"
    notes.write_text("precious\n")
    with pytest.raises(InputError, match=r"--scenario .*notes.txt: an existing file that is not a socket; it is left alone"):
        SideChannel(str(notes))
    assert notes.read_text() == "precious\n"
    (short_tmp / "dir").mkdir()
    with pytest.raises(InputError, match="not a socket"):
        claim_address(str(short_tmp / "dir"))
    assert (short_tmp / "dir").is_dir()


def test_a_socket_another_process_serves_is_refused(short_tmp):
    addr = str(short_tmp / "live.sock")
    first = SideChannel(addr)
    try:
        with pytest.raises(InputError, match="another process serves this socket"):
            SideChannel(addr)
        assert first.poll() == [{"op": "disconnected"}]  # the probe connected and left: the server goes on
    finally:
        first.close()
    assert not (short_tmp / "live.sock").exists()  # the server removed its own socket file


def test_a_stale_socket_is_replaced(short_tmp):
    addr = str(short_tmp / "stale.sock")
    dead = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    dead.bind(addr)
    dead.close()  # bound, never listened: a socket file nobody answers on (a killed server's)
    chan = SideChannel(addr)
    try:
        client = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        client.connect(addr)
        client.sendall(b'{"op": "status"}\n')
        for _ in range(100):
            got = chan.poll()
            if got:
                break
        assert got == [{"op": "status"}]
        client.close()
    finally:
        chan.close()


def test_an_address_in_a_missing_folder_is_one_line(short_tmp):
    with pytest.raises(InputError, match=r"--scenario .*/nothere/x.sock: cannot serve the side channel there"):
        SideChannel(str(short_tmp / "nothere" / "x.sock"))


def test_close_leaves_a_file_that_replaced_the_socket(short_tmp):
    addr = short_tmp / "mine.sock"
    chan = SideChannel(str(addr))
    addr.unlink()
    addr.write_text("someone else's file now\n")
    chan.close()
    assert addr.read_text() == "someone else's file now\n"
