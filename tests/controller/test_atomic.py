"""controller.atomic: the project's one writer of text and JSON files. What a reader can see
(the old file or the new one), what is left behind on failure, and the two fsyncs, observed by a
spy on ``os.fsync`` that identifies each descriptor by its inode (``os.fstat``), not by kill -9."""

from __future__ import annotations

import json
import os

import pytest

from controller import atomic
from controller.atomic import fsync_dir, write_json_atomic, write_text_atomic
from tests.fakes import FsyncSpy, ident


@pytest.mark.parametrize("existing", [False, True], ids=["new", "replacing"])
def test_the_file_is_fsynced_before_the_rename_and_the_folder_after_it(tmp_path, monkeypatch, existing):
    path = tmp_path / "m.json"
    if existing:
        path.write_text("old")
    old_ino = os.stat(path).st_ino if existing else None
    spy = FsyncSpy(monkeypatch, path)
    assert write_text_atomic(path, "new text") == path
    assert path.read_text() == "new text"
    file_calls = [c for c in spy.calls if c["id"] == ident(path)]
    dir_calls = [c for c in spy.calls if c["id"] == ident(tmp_path)]
    assert len(file_calls) == 1 and not file_calls[0]["dir"], spy.calls  # the very file that is now at path
    assert len(dir_calls) == 1 and dir_calls[0]["dir"], spy.calls  # its folder
    assert len(spy.calls) == 2
    assert spy.calls.index(file_calls[0]) < spy.calls.index(dir_calls[0])
    assert file_calls[0]["at_path"] == old_ino  # fsynced while the old file (or none) was still at path
    assert os.path.dirname(file_calls[0]["path"]) == str(tmp_path)  # a temporary in the same folder: the rename
    assert file_calls[0]["path"] != str(path)  # is atomic
    assert dir_calls[0]["at_path"] == os.stat(path).st_ino  # the folder after the rename


def test_json_is_written_with_a_final_newline_through_the_same_writer(tmp_path, monkeypatch):
    path = tmp_path / "d.json"
    spy = FsyncSpy(monkeypatch, path)
    write_json_atomic(path, {"a": [1, 2]})
    assert path.read_text() == json.dumps({"a": [1, 2]}, indent=2) + "\n"
    write_json_atomic(path, {"a": 1}, indent=None)
    assert path.read_text() == '{"a": 1}\n'
    assert [c["dir"] for c in spy.calls] == [False, True, False, True]


def test_text_is_utf_8_and_nothing_else_is_left_in_the_folder(tmp_path):
    path = tmp_path / "t.txt"
    write_text_atomic(path, "Öl \u2713\n")
    assert path.read_bytes() == "Öl \u2713\n".encode("utf-8")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["t.txt"]


def test_a_failed_write_keeps_the_old_file_and_removes_the_temporary(tmp_path, monkeypatch):
    path = tmp_path / "m.json"
    path.write_text("old")

    def failing_fsync(fd):
        raise OSError(5, "I/O error")

    monkeypatch.setattr(os, "fsync", failing_fsync)
    with pytest.raises(OSError, match="I/O error"):
        write_text_atomic(path, "new")
    assert path.read_text() == "old" and sorted(p.name for p in tmp_path.iterdir()) == ["m.json"]
    monkeypatch.undo()
    with pytest.raises(TypeError):  # not text: nothing written, nothing left
        write_text_atomic(path, b"bytes")  # type: ignore[arg-type]
    assert path.read_text() == "old" and sorted(p.name for p in tmp_path.iterdir()) == ["m.json"]


def test_a_missing_folder_is_an_error_and_the_temporary_names_are_unique(tmp_path, monkeypatch):
    with pytest.raises(FileNotFoundError):
        write_text_atomic(tmp_path / "no" / "m.json", "x")
    made = []
    real = atomic.tempfile.mkstemp

    def recording(*a, **kw):
        fd, name = real(*a, **kw)
        made.append(os.path.basename(name))
        return fd, name

    monkeypatch.setattr(atomic.tempfile, "mkstemp", recording)
    write_text_atomic(tmp_path / "m.json", "1")
    write_text_atomic(tmp_path / "m.json", "2")
    assert len(set(made)) == 2
    assert all(n.startswith(f".m.json.{os.getpid()}.") and n.endswith(".tmp") for n in made), made


def test_fsync_dir_syncs_the_folder_and_closes_its_descriptor(tmp_path, monkeypatch):
    spy = FsyncSpy(monkeypatch, tmp_path)
    closed = []
    real_close = os.close
    monkeypatch.setattr(os, "close", lambda fd: (closed.append(fd), real_close(fd))[1])
    fsync_dir(tmp_path)
    assert [c["id"] for c in spy.calls] == [ident(tmp_path)] and spy.calls[0]["dir"]
    assert len(closed) == 1


def test_fsync_dir_is_a_no_op_where_folders_cannot_be_opened_or_synced(tmp_path, monkeypatch):
    def no_open(*a, **kw):
        raise OSError(13, "no directory fds here")

    monkeypatch.setattr(os, "open", no_open)
    fsync_dir(tmp_path)  # no error
    monkeypatch.undo()
    closed = []
    real_close = os.close
    monkeypatch.setattr(os, "close", lambda fd: (closed.append(fd), real_close(fd))[1])

    def no_fsync(fd):
        raise OSError(22, "fsync not supported on a folder here")

    monkeypatch.setattr(os, "fsync", no_fsync)
    fsync_dir(tmp_path)  # no error, and the descriptor is closed all the same
    assert len(closed) == 1
    with pytest.raises(OSError):  # a real fsync error of the file itself is not swallowed
        write_text_atomic(tmp_path / "x", "x")


def test_fsync_dir_of_a_file_that_is_not_a_folder_syncs_nothing(tmp_path, monkeypatch):
    f = tmp_path / "plain"
    f.write_text("x")
    spy = FsyncSpy(monkeypatch, f)
    fsync_dir(f)  # O_DIRECTORY: a path that is not a folder is not opened
    assert spy.calls == []


def test_the_text_is_utf_8_whatever_the_locale(tmp_path):
    import subprocess
    import sys

    env = {**os.environ, "LC_ALL": "C", "LANG": "C", "PYTHONCOERCECLOCALE": "0", "PYTHONUTF8": "0"}
    code = ("import locale, sys; from controller.atomic import write_text_atomic; "
            "assert locale.getpreferredencoding(False).lower() in ('ascii', 'ansi_x3.4-1968'), "
            "locale.getpreferredencoding(False); write_text_atomic(sys.argv[1], '\\u00d6l \\u2713')")  # ASCII argv
    subprocess.run([sys.executable, "-c", code, str(tmp_path / "t.txt")], env=env, check=True,
                   cwd=os.path.dirname(os.path.dirname(atomic.__file__)))
    assert (tmp_path / "t.txt").read_bytes() == "\u00d6l \u2713".encode("utf-8")


def test_a_new_file_is_readable_by_others_and_a_replaced_file_keeps_its_mode(tmp_path):
    import stat

    new = write_text_atomic(tmp_path / "new.json", "{}\n")
    assert stat.S_IMODE(new.stat().st_mode) == 0o644  # not mkstemp's 0600
    private = tmp_path / "private.toml"
    private.write_text("old\n")
    private.chmod(0o600)
    write_text_atomic(private, "new\n")
    assert stat.S_IMODE(private.stat().st_mode) == 0o600 and private.read_text() == "new\n"
