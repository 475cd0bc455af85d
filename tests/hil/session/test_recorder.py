"""The bus recorder's metadata beside its log: stamped, read back, and the frame count it gives."""

from __future__ import annotations

import json
import uuid

import can
import pytest

import controller.daemon.openbus as openbus
from controller.errors import InputError
from hil.analysis.buslog import LogReading, metadata_path, read_metadata
from hil.session.recorder import BusRecorder


@pytest.fixture
def virtual_channel(monkeypatch):
    """The recorder's SocketCAN bus replaced by a python-can virtual bus on a fresh channel."""
    channel = "rec-" + "".join(chr(ord("a") + int(c, 16)) for c in uuid.uuid4().hex[:8])  # no digits: BLF's channel
    monkeypatch.setattr(openbus, "open_bus", lambda kw: can.Bus(interface="virtual", channel=channel))
    return channel


@pytest.mark.parametrize("suffix", [".blf", ".log"])
def test_the_recorder_writes_stamped_metadata_counting_the_frames_it_wrote(virtual_channel, tmp_path, suffix):
    from protocol import BusContract

    c = BusContract.load()
    log = tmp_path / f"bus{suffix}"
    rec = BusRecorder("vcan0", log)
    sender = can.Bus(interface="virtual", channel=virtual_channel)
    rec.start()
    try:
        for i in range(25):
            sender.send(can.Message(arbitration_id=c.odrive_id(i % 2, "Set_Input_Pos"), data=bytes(8),
                                    is_extended_id=False))
            sender.send(can.Message(arbitration_id=c.odrive_id(i % 2, "Get_Encoder_Estimates"), data=bytes(8),
                                    is_extended_id=False))
    finally:
        sender.shutdown()
        rec.stop()  # drains what is left, closes the log, then writes the metadata
    meta = json.loads(metadata_path(log).read_text())
    assert list(meta)[:3] == ["format", "format_version", "project_version"]
    assert (meta["format"], meta["format_version"]) == ("bus-log", 1)
    assert (meta["frames"], meta["controller_to_leg"], meta["leg_to_controller"]) == (50, 25, 25)
    assert meta["log"] == log.name and meta["error"] is None
    assert read_metadata(log) == meta
    reading = LogReading(log, meta["frames"])
    assert sum(1 for _ in reading) == 50 and reading.damage is None


def test_metadata_of_an_unknown_version_or_kind_is_refused_in_one_line(tmp_path):
    log = tmp_path / "bus.blf"
    assert read_metadata(log) is None  # a log without metadata (from elsewhere): nothing to check
    meta = metadata_path(log)
    assert meta.name == "bus.blf.json"
    meta.write_text(json.dumps({"format": "bus-log", "format_version": 2, "project_version": "0.9", "frames": 1}))
    with pytest.raises(InputError, match=r"bus.blf.json: bus-log format version 2 \(written by elegant-stepping 0.9\)"):
        read_metadata(log)
    meta.write_text(json.dumps({"format": "metrics", "format_version": 1}))
    with pytest.raises(InputError, match="a 'metrics' file, not a bus-log file"):
        read_metadata(log)
    meta.write_text("{not json")
    with pytest.raises(InputError, match="not valid JSON"):
        read_metadata(log)
    meta.write_text(json.dumps({"format": "bus-log", "format_version": 1, "frames": "many"}))
    with pytest.raises(InputError, match="'frames' is 'many'"):
        read_metadata(log)


def test_metadata_without_a_stamp_is_read_as_version_0(tmp_path):
    log = tmp_path / "bus.log"
    metadata_path(log).write_text(json.dumps({"frames": 3, "channel": "vcan0"}))
    assert read_metadata(log) == {"frames": 3, "channel": "vcan0"}
