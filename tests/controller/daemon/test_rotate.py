"""Bounded disk: the daemon's records and ticks rotate (FILE the newest, FILE.1 ... FILE.<keep>),
each file begins with the format line and the clock (and the current phase), and a restarted daemon rotates the
previous run's records instead of overwriting them."""

from __future__ import annotations

import json
import uuid
from array import array

from controller.daemon.rotate import RotatingFile
from controller.daemon.run import read_records, run_controller


def test_rotating_file_keeps_the_newest_as_file_and_at_most_keep_old_ones(tmp_path):
    path = tmp_path / "r.jsonl"
    f = RotatingFile(path, max_bytes=100, keep=2, header=lambda: ['{"kind": "clock"}\n'])
    for i in range(40):
        f.write(json.dumps({"kind": "n", "i": i}) + "\n")
    f.close()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.jsonl", "r.jsonl.1", "r.jsonl.2"]
    newest = [json.loads(x) for x in path.read_text().splitlines()]
    older = [json.loads(x) for x in (tmp_path / "r.jsonl.1").read_text().splitlines()]
    assert newest[0] == {"kind": "clock"} and newest[-1]["i"] == 39  # each file reads on its own
    assert older[-1]["i"] + 1 == newest[1]["i"]  # nothing lost between the two newest
    assert all(p.stat().st_size < 100 + 40 for p in tmp_path.iterdir())
    assert f.rotations >= 3


def test_binary_ticks_rotate_on_whole_records(tmp_path):
    path = tmp_path / "t.ticks"
    f = RotatingFile(path, max_bytes=160, keep=1, binary=True)
    for k in range(10):
        f.write_array(array("d", [float(k), 1.0] * 4))  # 4 pairs, 64 bytes
    f.close()
    assert path.stat().st_size % 16 == 0 and (tmp_path / "t.ticks.1").stat().st_size % 16 == 0
    got = array("d")
    got.frombytes(path.read_bytes())
    assert got[-2] == 9.0


def test_the_daemon_rotates_its_ticks_and_keeps_the_previous_runs_records(tmp_path):
    records, ticks = tmp_path / "controller.jsonl", tmp_path / "controller.ticks"
    bus = {"interface": "virtual", "channel": f"rot-{uuid.uuid4().hex[:8]}"}
    first = run_controller(bus, records=records, ticks=ticks, duration_s=0.3, records_max_bytes=2000, records_keep=2)
    second = run_controller(bus, records=records, ticks=ticks, duration_s=0.3, records_max_bytes=2000, records_keep=2)
    assert second["records_rotations"] >= 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["controller.jsonl", "controller.jsonl.1", "controller.ticks",
                                                          "controller.ticks.1"]
    # the newest file is a whole run's records: clock, phase, final (what replay reads)
    newest, before = read_records(records), read_records(tmp_path / "controller.jsonl.1")
    for part in (records, tmp_path / "controller.jsonl.1"):  # each part begins with the format line, then the clock
        head, then = (json.loads(x) for x in part.read_text().splitlines()[:2])
        assert head["kind"] == "format" and head["format"] == "controller-records" and then["kind"] == "clock"
    assert newest["clock"] and newest["final"][0]["ticks"] == second["ticks"]
    assert before["final"][0]["ticks"] == first["ticks"]
    assert all(p.stat().st_size <= 2000 + 8192 for p in tmp_path.glob("controller.ticks*"))
    # without rotation (the harness): one file, overwritten
    run_controller(bus, records=records, duration_s=0.05)
    assert len(read_records(records)["final"]) == 1
