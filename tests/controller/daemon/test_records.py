"""The daemon's records file (controller/daemon/run.py: ``Records``, ``read_records``): a format line
first in every file (rotated ones too), checked when read back; a file from before the stamp
(version 0) read as before; an unknown version or another kind of file refused in one line naming
the file; a damaged line named by its number; a torn last line (a kill while writing) dropped with
a warning. Runs the daemon on python-can's ``virtual`` bus (no leg: it waits for its nodes)."""

from __future__ import annotations

import json
import logging
import uuid

import pytest

from controller.daemon.run import (RECORDS_FORMAT, RECORDS_VERSION, Records, phases_seen, read_records,
                                   records_format_line, run_controller)
from controller.errors import EXIT_INPUT, InputError, project_version


def virtual_bus() -> dict:
    return {"interface": "virtual", "channel": f"records-{uuid.uuid4().hex[:8]}"}


def lines_of(path) -> list[dict]:
    return [json.loads(x) for x in path.read_text().splitlines()]


def write_lines(path, objs, tail: str = "") -> None:
    path.write_text("".join(json.dumps(o) + "\n" for o in objs) + tail)


CLOCK = {"kind": "clock", "realtime_minus_monotonic_s": 1.7e9}
PHASE = {"kind": "phase", "phase": "wait_nodes", "lifecycle": "inactive", "t_s": 1.0, "fault_cause": None}
FINAL = {"kind": "final", "phase": "wait_nodes", "ticks": 10}


def test_the_daemon_writes_the_format_line_first_and_reads_its_records_back(tmp_path):
    records = tmp_path / "controller.jsonl"
    final = run_controller(virtual_bus(), records=records, duration_s=0.1)
    lines = lines_of(records)
    assert lines[0] == {"kind": "format", "format": "controller-records", "format_version": 1,
                        "project_version": project_version()}
    assert lines[1]["kind"] == "clock" and lines[-1]["kind"] == "final"  # every other line as before
    got = read_records(records)
    assert "format" not in got  # checked, not returned: the return shape callers use is unchanged
    assert set(got) >= {"phase", "step", "reflex", "final", "clock"}
    assert got["final"][0]["ticks"] == final["ticks"] and got["clock"] == [lines[1]]
    assert [p["phase"] for p in got["phase"]] == phases_seen(records) and phases_seen(records)[0] == "wait_nodes"


def test_every_rotated_file_begins_with_the_format_line_and_reads_on_its_own(tmp_path):
    records = tmp_path / "controller.jsonl"
    rec = Records(records, max_bytes=300, keep=50)
    for i in range(30):
        rec.write({"kind": "step", "index": i})
    rec.write(FINAL)
    rec.close()
    files = sorted(tmp_path.iterdir())
    assert len(files) > 2
    steps = []
    for f in files:
        lines = lines_of(f)
        assert lines[0] == rec.format and lines[1] == rec.clock, f
        steps += [s["index"] for s in read_records(f)["step"]]
    assert sorted(steps) == list(range(30))  # nothing lost across the rotations


def test_a_file_from_before_the_stamp_is_version_0_and_reads_as_before(tmp_path):
    old = tmp_path / "controller.jsonl"
    write_lines(old, [CLOCK, PHASE, {"kind": "step", "index": 0}, FINAL])
    got = read_records(old)
    assert got["clock"] == [CLOCK] and got["phase"] == [PHASE] and got["final"] == [FINAL]
    assert [s["index"] for s in got["step"]] == [0] and got["reflex"] == []


@pytest.mark.parametrize("version", [2, -1, "1", None, True])
def test_an_unknown_version_is_refused_in_one_line_naming_the_file(version, tmp_path):
    path = tmp_path / "controller.jsonl"
    write_lines(path, [{"kind": "format", "format": RECORDS_FORMAT, "format_version": version,
                        "project_version": "9.9"}, CLOCK, FINAL])
    with pytest.raises(InputError) as exc:
        read_records(path)
    assert exc.value.exit_code == EXIT_INPUT and "\n" not in str(exc.value)
    assert str(exc.value).startswith(f"{path}: controller-records format version {version!r}")
    assert "9.9" in str(exc.value)  # which version wrote it


def test_another_kind_of_file_is_refused(tmp_path):
    path = tmp_path / "metrics.jsonl"
    write_lines(path, [{"kind": "format", "format": "learn-metrics", "format_version": 1}, CLOCK])
    with pytest.raises(InputError, match="a 'learn-metrics' file, not a controller-records file"):
        read_records(path)
    write_lines(path, [{"trial": 0, "steps": 3}, {"trial": 1, "steps": 4}])  # JSON lines, but not records
    with pytest.raises(InputError, match=r"not a controller records file \(line 1 is neither its format line"):
        read_records(path)
    path.write_text(json.dumps({"config": {}, "trials": []}, indent=2))  # a JSON file, not JSON lines
    with pytest.raises(InputError, match=r"line 1: not a JSON record"):
        read_records(path)


def test_a_torn_last_line_is_dropped_with_a_warning(tmp_path, caplog):
    path = tmp_path / "controller.jsonl"
    write_lines(path, [records_format_line(), CLOCK, PHASE], tail='{"kind": "step", "index": 0, "onset')
    with caplog.at_level(logging.WARNING):
        got = read_records(path)
    assert got["phase"] == [PHASE] and got["step"] == [] and got["clock"] == [CLOCK]
    warned = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert warned == [f"{path}: line 4 is not a whole record (cut short by a kill?): dropped"]
    write_lines(path, [records_format_line()], tail="\n\n{\"kind\n\n")  # torn, then blank lines: still the last
    assert read_records(path)["phase"] == []
    caplog.clear()
    write_lines(path, [records_format_line(), CLOCK, PHASE], tail='{"kind": "step", "ind')
    with caplog.at_level(logging.DEBUG):
        assert read_records(path, live=True)["phase"] == [PHASE]  # a file the daemon is writing: its end to come
        assert phases_seen(path) == ["wait_nodes"]
    assert not [r for r in caplog.records if r.levelno >= logging.WARNING]
    assert any("still being written" in r.getMessage() for r in caplog.records)


def test_a_damaged_line_before_the_last_is_refused_by_its_number(tmp_path):
    path = tmp_path / "controller.jsonl"
    path.write_text("".join(json.dumps(o) + "\n" for o in (records_format_line(), CLOCK, PHASE))
                    + "\x00\x00garbage\n" + json.dumps(FINAL) + "\n")
    with pytest.raises(InputError) as exc:
        read_records(path)
    assert str(exc.value).startswith(f"{path}: line 4: not a JSON record") and "damage starts there" in str(exc.value)
    write_lines(path, [records_format_line(), CLOCK, [1, 2], FINAL])  # JSON, but not a record
    with pytest.raises(InputError, match="line 3: not a JSON record"):
        read_records(path)
    path.write_bytes(b"".join(json.dumps(o).encode() + b"\n" for o in (records_format_line(), CLOCK))
                     + b'{"kind": "phase", "phase": "\xff"}\n' + json.dumps(FINAL).encode() + b"\n")
    with pytest.raises(InputError, match="line 3: not UTF-8 text"):
        read_records(path)


def test_an_empty_file_and_a_missing_one(tmp_path):
    empty = tmp_path / "controller.jsonl"
    empty.write_text("")
    assert read_records(empty) == {"phase": [], "step": [], "reflex": [], "final": []}
    with pytest.raises(FileNotFoundError):
        read_records(tmp_path / "none.jsonl")
    assert phases_seen(tmp_path / "none.jsonl") == []


def test_the_version_written_is_one_the_reader_reads():
    assert records_format_line()["format_version"] == RECORDS_VERSION
    from controller.daemon.run import RECORDS_VERSIONS

    assert RECORDS_VERSION in RECORDS_VERSIONS and 0 in RECORDS_VERSIONS
