"""The one reader of bus logs: every valid frame, and where the damage starts (frame or line)."""

from __future__ import annotations

import json
import zlib

import can
import pytest

from controller.errors import InputError
from hil.analysis.buslog import LogReading, frames_lost, metadata_path, read_frames, read_metadata
from tests.bad_inputs import session_frames, write_blf, write_candump


def key(m: can.Message) -> tuple:
    return (m.timestamp, m.arbitration_id, bytes(m.data), m.is_error_frame)


@pytest.fixture(scope="module")
def whole(tmp_path_factory):
    """A 6000-frame BLF (three containers) and its frames."""
    path = tmp_path_factory.mktemp("buslog") / "whole.blf"
    frames = session_frames(6000)
    data = write_blf(path, frames)
    return path, data, [key(m) for m in list(LogReading(path))]


def read(path, expected=None):
    reading = LogReading(path, expected)
    return [key(m) for m in reading], reading.damage


def test_a_whole_log_reads_every_frame_and_passes(whole):
    path, _, frames = whole
    assert len(frames) == 6000
    reading = LogReading(path, expected_frames=6000)
    assert [key(m) for m in reading] == frames and reading.damage is None
    assert reading.check(partial=False) is None


def test_every_truncation_is_found_and_the_frames_before_it_are_the_logs_first(whole, tmp_path):
    """Cut the file at many places: never a silent short read."""
    path, data, frames = whole
    cut = tmp_path / "cut.blf"
    for size in [0, 3, 100, 144, 160, 1000, *range(2000, len(data), 1777), len(data) - 1]:
        cut.write_bytes(data[:size])
        got, damage = read(cut)
        assert damage is not None, size
        assert got == frames[:len(got)] and damage.frame == len(got) + 1 and damage.line is None, size
    cut.write_bytes(data[: len(data) * 2 // 3])
    got, damage = read(cut)
    assert len(got) == 2730 and "truncated" in damage.reason  # the first container, whole


def test_a_flipped_bit_in_the_compressed_data_is_found(whole, tmp_path):
    """Every bit position sampled across the containers (zlib's checksum catches what decodes)."""
    path, data, frames = whole
    flipped = tmp_path / "flip.blf"
    for pos in range(144, len(data), 997):
        for bit in (0x01, 0x80):
            b = bytearray(data)
            b[pos] ^= bit
            flipped.write_bytes(bytes(b))
            got, damage = read(flipped)
            assert damage is not None, (pos, bit)
            assert got == frames[:len(got)] and damage.frame == len(got) + 1, (pos, bit)


def test_an_unclosed_recording_and_a_short_one_are_damage(whole, tmp_path):
    import can.io.blf as blf

    path, data, frames = whole
    w = blf.BLFWriter(str(tmp_path / "unclosed.blf"))
    for m in session_frames(6000):
        w.on_message_received(m)
    w._flush()  # the containers so far reach the disk; the header is never rewritten
    w.file.close()
    got, damage = read(tmp_path / "unclosed.blf")
    assert got == frames and "never closed" in damage.reason
    got, damage = read(path, expected=6001)  # the recorder counted one more than the log holds
    assert got == frames and damage.frame == 6001 and "metadata counts 6001" in damage.reason


def test_an_uncompressed_container_of_the_wrong_size_is_damage(whole, tmp_path):
    """A container stored without compression is checked against its stated size too."""
    frames = session_frames(50)
    path = tmp_path / "plain.blf"
    with can.io.BLFWriter(str(path), compression_level=0) as w:
        for m in frames:
            w.on_message_received(m)
    assert read(path)[1] is None and len(read(path)[0]) == 50
    data = bytearray(path.read_bytes())
    data[144 + 24:144 + 28] = (12345).to_bytes(4, "little")  # the container's uncompressed size
    path.write_bytes(bytes(data))
    got, damage = read(path)
    assert got == [] and "holds" in damage.reason and "12345" in damage.reason


def test_a_junk_line_in_a_candump_log_is_named_by_its_line(tmp_path):
    frames = session_frames(20)
    write_candump(tmp_path / "bus.log", frames, junk_at_line=8)
    got, damage = read(tmp_path / "bus.log")
    assert [g[1] for g in got] == [m.arbitration_id for m in frames[:7]]
    assert (damage.frame, damage.line) == (8, 8) and "hi there" in damage.reason
    text = (tmp_path / "bus.log").read_text().splitlines()
    (tmp_path / "blank.log").write_text("\n\n" + "\n".join(text[:3]) + "\n(1000.5) vcan0 00C#ZZ\n")
    got, damage = read(tmp_path / "blank.log")
    assert len(got) == 3 and damage.line == 6  # blank lines count as lines
    (tmp_path / "bytes.log").write_bytes(("\n".join(text[:4]) + "\n").encode() + b"\xff\xfe junk\n")
    got, damage = read(tmp_path / "bytes.log")
    assert len(got) == 4 and damage.line == 5


def test_check_raises_one_line_or_with_partial_returns_the_warning(tmp_path):
    write_candump(tmp_path / "bus.log", session_frames(20), junk_at_line=8)
    reading = LogReading(tmp_path / "bus.log")
    with pytest.raises(RuntimeError):
        reading.check(partial=True)  # before reading
    assert len(list(reading)) == 7
    with pytest.raises(InputError) as exc:
        reading.check(partial=False)
    assert str(exc.value).startswith(f"{tmp_path / 'bus.log'}: damaged at line 8: not a frame: ")
    assert str(exc.value).endswith("; the 7 frames before it are valid (--partial: use them)")
    assert "\n" not in str(exc.value)
    assert reading.check(partial=True).startswith(f"{tmp_path / 'bus.log'}: read 7 frames, stopped at line 8: ")
    warned = []
    assert len(read_frames(tmp_path / "bus.log", partial=True, warn=warned.append)) == 7 and len(warned) == 1


def test_a_log_that_cannot_be_read_at_all_is_an_input_error(tmp_path):
    with pytest.raises(InputError, match="no such log"):
        LogReading(tmp_path / "none.blf")
    with pytest.raises(InputError, match="a folder, not a bus log"):
        LogReading(tmp_path)
    (tmp_path / "x.txt").write_text("hello\n")
    with pytest.raises(InputError, match=r"not a bus log format python-can reads \(.txt"):
        LogReading(tmp_path / "x.txt")
    with pytest.raises(InputError, match="empty path"):
        LogReading("")


def test_the_zlib_error_is_what_python_cans_own_reader_would_hit(whole, tmp_path):
    """The damage this reader reports before parsing is real: python-can's reader fails (or reads
    silently short) on the same file."""
    path, data, frames = whole
    b = bytearray(data)
    b[len(data) // 2] ^= 0x10
    (tmp_path / "f.blf").write_bytes(bytes(b))
    with pytest.raises((zlib.error, can.io.blf.BLFParseError)):
        list(can.io.BLFReader(str(tmp_path / "f.blf")))


def test_metadata_of_version_1_without_the_lost_count_reads_as_unknown_and_with_it_as_the_count(tmp_path):
    """The recorder's lost-frame count (issue 16) is a new key of version 1: absent is unknown, not 0."""
    log = tmp_path / "bus.blf"
    stamp = {"format": "bus-log", "format_version": 1, "project_version": "0.9"}
    metadata_path(log).write_text(json.dumps({**stamp, "frames": 3}))  # written before the count existed
    assert frames_lost(read_metadata(log)) is None
    metadata_path(log).write_text(json.dumps({**stamp, "frames": 3, "frames_lost": 0}))
    assert frames_lost(read_metadata(log)) == 0
    metadata_path(log).write_text(json.dumps({**stamp, "frames": 3, "frames_lost": 17}))
    assert frames_lost(read_metadata(log)) == 17
    assert frames_lost(None) is None  # a log without metadata
