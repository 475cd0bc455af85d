"""Bus load from a recorded log: frames per second x bits per frame."""

from __future__ import annotations

import json

import can
import pytest

from hil.analysis.busload import bus_load_from_log
from hil.cli import main
from protocol import BusContract, frame_bits


def write_log(path, frames_per_s: float, seconds: float) -> list[can.Message]:
    contract = BusContract.load()
    pos = contract.odrive_id(0, "Set_Input_Pos")
    rng = 0x208  # SB_Range
    msgs = []
    n = int(frames_per_s * seconds)
    for i in range(n + 1):
        t = 1000.0 + i / frames_per_s
        if i % 2:
            msgs.append(can.Message(timestamp=t, arbitration_id=pos, data=bytes(8), is_extended_id=False))
        else:
            msgs.append(can.Message(timestamp=t, arbitration_id=rng, data=bytes([i % 256, 1, 2, 3, 4, 5]),
                                    is_extended_id=False))
    with can.Logger(str(path)) as log:
        for m in msgs:
            log.on_message_received(m)
    return msgs


@pytest.mark.parametrize("suffix", [".blf", ".log"])
def test_load_is_frames_per_second_times_bits_per_frame(tmp_path, suffix):
    path = tmp_path / f"bus{suffix}"
    msgs = write_log(path, frames_per_s=400.0, seconds=2.0)
    load = bus_load_from_log(path)
    bits = [frame_bits(m.arbitration_id, bytes(m.data)) for m in msgs]
    assert load["frames"] == len(msgs)
    assert load["span_s"] == pytest.approx(2.0, abs=1e-3)
    assert load["bits_per_frame"] == pytest.approx(sum(bits) / len(bits))
    assert load["fraction"] == pytest.approx(sum(bits) / 2.0 / 1e6, rel=1e-3)
    assert load["frames_per_s_by_message"]["Set_Input_Pos"] == pytest.approx(200.0, rel=0.01)
    assert load["frames_per_s_by_message"]["SB_Range"] == pytest.approx(200.5, rel=0.01)
    half = bus_load_from_log(path, bitrate=500_000)
    assert half["fraction"] == pytest.approx(2 * load["fraction"])


def test_load_rejects_missing_or_empty_logs(tmp_path, capsys):
    with pytest.raises(FileNotFoundError, match="no such log"):
        bus_load_from_log(tmp_path / "none.blf")
    empty = tmp_path / "empty.log"
    with can.Logger(str(empty)):
        pass
    with pytest.raises(ValueError, match="fewer than two frames"):
        bus_load_from_log(empty)


def test_decode_load_prints_json(tmp_path, capsys):
    path = tmp_path / "bus.log"
    write_log(path, frames_per_s=100.0, seconds=1.0)
    assert main(["decode", str(path), "--load"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["frames"] == 101 and 0.0 < out["fraction"] < 0.05


def test_a_damaged_log_is_refused_unless_partial_then_the_valid_frames_are_measured(tmp_path):
    from controller.errors import InputError

    path = tmp_path / "bus.log"
    msgs = write_log(path, frames_per_s=100.0, seconds=1.0)
    lines = path.read_text().splitlines()
    lines.insert(60, "(1000.6) vcan0 hi")  # a junk line after 60 frames
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match=r"bus.log: damaged at line 61: .*the 60 frames before it are valid"):
        bus_load_from_log(path)
    warned = []
    load = bus_load_from_log(path, partial=True, warn=warned.append)
    assert load["frames"] == 60 and load["partial"] == {"frames_read": 60, "stopped_at": "line 61",
                                                         "reason": load["partial"]["reason"]}
    assert load["span_s"] == pytest.approx(msgs[59].timestamp - msgs[0].timestamp, abs=1e-5)
    assert warned == [f"{path}: read 60 frames, stopped at line 61: {load['partial']['reason']}"]
    write_log(tmp_path / "whole.log", frames_per_s=100.0, seconds=1.0)
    assert bus_load_from_log(tmp_path / "whole.log")["partial"] is None
