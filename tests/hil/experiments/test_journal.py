"""The append-only trial record, the folder lock and the output-folder check (no simulation)."""

from __future__ import annotations

import json
import logging
import os
import signal

import pytest

from controller.errors import InputError
from hil.experiments import journal
from hil.experiments.journal import FolderBusy, FolderLock, JournalWriter, is_locked, prepare_folder, read_journal

CONFIG = {"trials": 3, "seed": 1, "trace_trials": (0, -1)}


def _record(i: int) -> dict:
    return {"index": i, "success": i % 2 == 0, "burst_s": [0.3, 0.1 * i], "nan": float("nan")}


def _written(tmp_path, n: int):
    path = tmp_path / "trials.jsonl"
    with JournalWriter.create(path, CONFIG) as w:
        for i in range(n):
            w.append(_record(i))
    return path


def test_the_header_is_stamped_and_each_trial_is_one_line(tmp_path):
    path = _written(tmp_path, 3)
    lines = path.read_text().splitlines()
    assert len(lines) == 4
    header = json.loads(lines[0])
    assert (header["format"], header["format_version"]) == ("learn-trials", 1) and "project_version" in header
    assert header["config"] == {"trials": 3, "seed": 1, "trace_trials": [0, -1]}  # as JSON gives it back
    j = read_journal(path)
    assert [r["index"] for r in j.records] == [0, 1, 2] and not j.torn
    assert j.good_bytes == path.stat().st_size and j.config == header["config"]


def test_each_append_is_flushed_and_fsynced_before_it_returns(tmp_path, monkeypatch):
    path = tmp_path / "trials.jsonl"
    w = JournalWriter.create(path, CONFIG)
    synced = []
    monkeypatch.setattr(journal.os, "fsync", lambda fd: synced.append(os.path.getsize(path)))
    w.append(_record(0))
    w.append(_record(1))
    w.close()
    # the file held the whole line (header + records so far) when fsync was called
    sizes = [len(line) + 1 for line in path.read_text().splitlines()]
    assert synced == [sizes[0] + sizes[1], sum(sizes)]


def test_signals_are_held_during_an_append_and_delivered_after(tmp_path, monkeypatch):
    path = tmp_path / "trials.jsonl"
    w = JournalWriter.create(path, CONFIG)
    seen = []
    previous = signal.signal(signal.SIGTERM, lambda *a: seen.append(os.path.getsize(path)))
    real_fsync = os.fsync

    def fsync_with_a_signal(fd):
        os.kill(os.getpid(), signal.SIGTERM)  # arrives in the middle of the append
        assert not seen  # not handled yet: it is held
        real_fsync(fd)

    monkeypatch.setattr(journal.os, "fsync", fsync_with_a_signal)
    try:
        w.append(_record(0))
    finally:
        signal.signal(signal.SIGTERM, previous)
        w.close()
    assert seen == [path.stat().st_size]  # handled once the line was complete
    assert w.appended == 1


def test_a_stop_raised_by_a_held_signal_comes_after_the_record_is_counted(tmp_path, monkeypatch):
    path = tmp_path / "trials.jsonl"
    w = JournalWriter.create(path, CONFIG)

    def stop(*args):
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, stop)
    real_fsync = os.fsync
    monkeypatch.setattr(journal.os, "fsync", lambda fd: (os.kill(os.getpid(), signal.SIGTERM), real_fsync(fd)))
    try:
        with pytest.raises(KeyboardInterrupt):
            w.append(_record(0))
    finally:
        signal.signal(signal.SIGTERM, previous)
        w.close()
    assert w.appended == 1 and [r["index"] for r in read_journal(path).records] == [0]


def test_a_torn_last_line_is_dropped_with_a_warning(tmp_path, caplog):
    path = _written(tmp_path, 3)
    whole = path.read_bytes()
    cut = whole[: len(whole) - 20]  # the last record cut mid-line (kill -9 in the write)
    path.write_bytes(cut)
    with caplog.at_level(logging.WARNING, logger="hil.experiments.journal"):
        j = read_journal(path)
    assert [r["index"] for r in j.records] == [0, 1] and j.torn
    assert "incomplete" in caplog.text
    assert j.good_bytes == len(whole.rsplit(b"\n", 2)[0]) + 1
    # a complete-looking last line without its newline is torn too, and so is an unparsable last line
    path.write_bytes(whole[:-1])
    assert len(read_journal(path).records) == 2
    path.write_bytes(whole + b'{"index": 3, "succ\n')
    assert len(read_journal(path).records) == 3


def test_the_writer_cuts_a_torn_line_before_appending(tmp_path):
    path = _written(tmp_path, 2)
    path.write_bytes(path.read_bytes() + b'{"index": 2, "success": tr')
    j = read_journal(path)
    with JournalWriter(path, keep_bytes=j.good_bytes) as w:
        w.append(_record(2))
    again = read_journal(path)
    assert [r["index"] for r in again.records] == [0, 1, 2] and not again.torn


def test_a_damaged_line_before_the_last_names_the_file_and_line(tmp_path):
    path = _written(tmp_path, 3)
    lines = path.read_bytes().split(b"\n")
    lines[2] = lines[2][:10] + b"\x00garbage"
    path.write_bytes(b"\n".join(lines))
    with pytest.raises(InputError, match=r"trials\.jsonl: line 3 is damaged"):
        read_journal(path)


@pytest.mark.parametrize("content,match", [
    (b"", "no header"),
    (b'{"format": "walk", "format_version": 1}\n', "not a learn-trials file"),
    (b'{"format": "learn-trials", "format_version": 7, "config": {}}\n', "format version 7"),
    (b'{"format": "learn-trials", "format_version": 1}\n', "no 'config'"),
    (b'{"format": "learn-trials", "format_version": 1, "config": {}}\n{"index": 1, "success": true}\n',
     "line 2 is not trial 0"),
])
def test_a_record_that_is_not_a_learn_runs_is_refused(tmp_path, content, match):
    path = tmp_path / "trials.jsonl"
    path.write_bytes(content)
    with pytest.raises(InputError, match=match):
        read_journal(path)


def test_the_lock_refuses_a_second_writer_and_is_released(tmp_path):
    with FolderLock(tmp_path, "--out X"):
        assert is_locked(tmp_path)
        with pytest.raises(FolderBusy, match="--out X: another run is writing this folder") as err:
            FolderLock(tmp_path, "--out X").acquire()
        assert err.value.exit_code == 3
    assert not is_locked(tmp_path)
    with FolderLock(tmp_path):  # free again
        pass


def test_a_lock_held_by_another_process_refuses_and_dies_with_it(tmp_path):
    import subprocess
    import sys

    code = ("import fcntl, os, sys, time; fd = os.open(sys.argv[1], os.O_RDWR | os.O_CREAT); "
            "fcntl.flock(fd, fcntl.LOCK_EX); print('locked', flush=True); time.sleep(60)")
    p = subprocess.Popen([sys.executable, "-c", code, str(tmp_path / ".lock")], stdout=subprocess.PIPE, text=True)
    try:
        assert p.stdout.readline().strip() == "locked"
        with pytest.raises(FolderBusy):
            FolderLock(tmp_path).acquire()
    finally:
        p.kill()
        p.wait()
    with FolderLock(tmp_path):  # a killed holder leaves no lock behind
        pass


def test_output_folders_are_checked_before_any_work(tmp_path):
    (tmp_path / "a_file").write_text("x")
    with pytest.raises(InputError, match="--out: an empty path"):
        prepare_folder("")
    with pytest.raises(InputError, match="--out .*a_file: is a file, not a folder"):
        prepare_folder(tmp_path / "a_file")
    with pytest.raises(InputError, match="a_file is a file, so no folder can be made under it"):
        prepare_folder(tmp_path / "a_file" / "deeper" / "run", "--out")
    with pytest.raises(InputError, match="cell c /proc/no-such-process-folder/run: cannot be written here"):
        prepare_folder("/proc/no-such-process-folder/run", "cell c")
    assert not (tmp_path / "new").exists()
    assert prepare_folder(tmp_path / "new", create=False) == tmp_path / "new" and not (tmp_path / "new").exists()
    assert prepare_folder(tmp_path / "new" / "run").is_dir()
    assert os.listdir(tmp_path / "new" / "run") == []  # the write test leaves nothing behind
