"""The controller daemon's weights: resumed across restarts (file, else .prev, .prev2, ..., else zeros,
logged), saved periodically while walking and at exit only if they changed, never destroyed (a run
that never walked leaves the file byte-identical; another configuration's file is set aside; the
folder must be writable); SIGTERM/SIGINT/SIGHUP/SIGUSR1 stop with exit code 0 and a loadable file,
a second signal during the stop changes nothing. Runs on python-can's ``virtual`` bus (no leg:
the daemon waits for its nodes)."""

from __future__ import annotations

import json
import logging
import os
import signal
import subprocess
import sys
import time
import uuid

import numpy as np
import pytest

from controller.stepping.weights import load_weights, prev_path, save_weights
from controller.daemon.autosave import AutosaveConfig, WeightAutosave
from hil.cli import main
from controller.daemon.run import run_controller

N_CELLS, WIDTH_M = 28, 0.04
W = np.linspace(-0.05, 0.05, N_CELLS)


def virtual_bus() -> dict:
    return {"interface": "virtual", "channel": f"weights-{uuid.uuid4().hex[:8]}"}


def test_autosave_saves_after_walking_time_only_when_changed(tmp_path):
    path = tmp_path / "w.npz"
    saver = WeightAutosave(path, WIDTH_M, AutosaveConfig(every_s=1.0))
    w = W.copy()
    assert not saver.tick(0.0, True, w)
    assert not saver.tick(0.5, True, w)
    assert not saver.tick(5.0, False, w)  # standing still does not count
    assert saver.tick(5.6, True, w)  # 0.5 + 0.6 s of walking
    saver.flush()
    assert saver.saves == 1 and np.array_equal(load_weights(path, N_CELLS, WIDTH_M), W)
    assert not saver.tick(6.7, True, w)  # due, but unchanged
    w[3] += 0.01
    assert not saver.tick(7.0, True, w)
    assert saver.tick(7.8, True, w)
    saver.flush()
    data = path.read_bytes()
    assert saver.close(w) and saver.saves == 2 and saver.unchanged  # the final save: nothing new to write
    assert path.read_bytes() == data
    assert np.array_equal(load_weights(path, N_CELLS, WIDTH_M), w)
    assert np.array_equal(load_weights(prev_path(path), N_CELLS, WIDTH_M), W)
    w[4] += 0.01
    again = WeightAutosave(path, WIDTH_M, AutosaveConfig(every_s=1.0), saved=W)
    assert again.close(w) and again.saves == 1 and not again.unchanged  # changed since the start: written
    with pytest.raises(ValueError, match="every_s"):
        AutosaveConfig(every_s=0.0)


def test_autosave_logs_a_failed_save_and_tries_again(tmp_path, caplog):
    (tmp_path / "file").write_text("not a folder")
    saver = WeightAutosave(tmp_path / "file" / "w.npz", WIDTH_M, AutosaveConfig(every_s=1.0), saved=W)
    saver.tick(0.0, True, W)
    assert not saver.tick(1.5, True, W)  # the weights on disk already
    with caplog.at_level(logging.ERROR, logger="controller.daemon.autosave"):
        assert saver.tick(3.0, True, W * 2)
        saver.flush()
        assert saver.failures == 1 and "periodic save" in caplog.text
        assert saver.tick(4.5, True, W * 2)  # retried: it never reached the disk
        assert not saver.close(W * 2)
    assert saver.failures == 3 and saver.saves == 0 and "final save" in caplog.text


def test_the_daemon_resumes_from_the_weights_it_saved_and_never_rewrites_them_unchanged(tmp_path, caplog):
    path = tmp_path / "w.npz"
    save_weights(path, W * 2, WIDTH_M)
    save_weights(path, W, WIDTH_M)
    before_bytes = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    mtimes = {p.name: p.stat().st_mtime_ns for p in tmp_path.iterdir()}
    before = {s: signal.getsignal(s) for s in (signal.SIGTERM, signal.SIGINT, signal.SIGHUP, signal.SIGUSR1)}
    caplog.set_level(logging.INFO)
    for run in range(2):
        final = run_controller(virtual_bus(), weights=path, duration_s=0.2, records=tmp_path / f"r{run}.jsonl")
        assert final["weights_source"] == "file" and final["stopped_by"] == "duration"
        assert final["weights_saved"] is None and final["weights_saves"] == 0 and final["weights_unchanged"] is True
        assert np.array_equal(final["weights"], W)  # the premotor ran on the loaded weights
    # never walked: nothing written, every generation byte-identical (and not even touched)
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir() if p.suffix == ".npz" or ".prev" in p.name} == before_bytes
    assert {n: (tmp_path / n).stat().st_mtime_ns for n in mtimes} == mtimes
    assert np.array_equal(load_weights(prev_path(path), N_CELLS, WIDTH_M), W * 2)
    assert f"weights: resuming from {path}" in caplog.text
    assert {s: signal.getsignal(s) for s in before} == before  # the handlers are given back
    lines = [json.loads(x) for x in (tmp_path / "r1.jsonl").read_text().splitlines()]
    assert lines[-1]["kind"] == "final" and lines[-1]["weights_source"] == "file"


def test_a_corrupt_file_resumes_from_prev_then_prev2_then_zeros_with_a_logged_reason(tmp_path, caplog):
    path = tmp_path / "w.npz"
    for k in (3, 2, 1):
        save_weights(path, W * k, WIDTH_M, generations=3)  # w.npz = W, .prev = 2W, .prev2 = 3W
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 3])
    with caplog.at_level(logging.INFO):
        final = run_controller(virtual_bus(), weights=path, duration_s=0.1)
    assert final["weights_source"] == "prev" and np.array_equal(final["weights"], W * 2)
    assert any(r.levelname == "ERROR" and "truncated" in r.getMessage() for r in caplog.records)
    assert f"resuming from {path}.prev" in caplog.text and "previous good copy" in caplog.text
    assert path.read_bytes() == data[: len(data) // 3]  # never walked: nothing written, the evidence left

    prev_path(path).write_bytes(b"PK\x03\x04 garbage")
    final = run_controller(virtual_bus(), weights=path, duration_s=0.1)
    assert final["weights_source"] == "prev2" and np.array_equal(final["weights"], W * 3)

    caplog.clear()
    path.with_name("w.npz.prev2").write_bytes(b"garbage")
    with caplog.at_level(logging.INFO):
        final = run_controller(virtual_bus(), weights=path, duration_s=0.1)
    assert final["weights_source"] == "zeros" and final["weights"] == [0.0] * N_CELLS
    assert any(r.levelname == "WARNING" and "starting from zeros" in r.getMessage() for r in caplog.records)
    assert "resuming from zeros" in caplog.text
    assert final["weights_saved"] is None and path.with_name("w.npz.prev2").read_bytes() == b"garbage"


def test_an_incompatible_file_is_set_aside_and_zeros_never_written_over_anything(tmp_path, caplog):
    path, records = tmp_path / "w.npz", tmp_path / "r.jsonl"
    other = np.linspace(0, 1, 40)  # another configuration: 40 cells
    save_weights(path, other * 2, WIDTH_M)
    save_weights(path, other, WIDTH_M)
    original = path.read_bytes()
    with caplog.at_level(logging.INFO):
        final = run_controller(virtual_bus(), weights=path, duration_s=0.1, records=records)
    assert final["weights_source"] == "zeros" and final["weights_saved"] is None
    aside = final["weights_set_aside"]
    assert [a["file"] for a in aside] == [str(path), str(prev_path(path))]
    assert all("40" in a["reason"] and "28 cells" in a["reason"] for a in aside)
    kept = sorted(tmp_path.glob("w.npz*.incompatible-*"))
    assert len(kept) == 2 and not path.exists() and not prev_path(path).exists()  # nothing left to write over
    assert (tmp_path / aside[0]["moved_to"]).read_bytes() == original  # byte-identical, beside the old name
    assert aside[0]["moved_to"].startswith(str(path) + ".incompatible-2") and aside[0]["moved_to"].endswith("Z")
    assert any(r.levelname == "ERROR" and "kept aside as" in r.getMessage() for r in caplog.records)
    kinds = [json.loads(x)["kind"] for x in records.read_text().splitlines()]
    assert kinds.count("weights") == 2 and kinds[-1] == "final"
    # another cell width is another configuration too
    save_weights(path, W, 0.05)
    final = run_controller(virtual_bus(), weights=path, duration_s=0.05)
    assert len(final["weights_set_aside"]) == 1 and "cell width" in final["weights_set_aside"][0]["reason"]


def test_saves_keep_the_configured_generations(tmp_path):
    path = tmp_path / "w.npz"
    saver = WeightAutosave(path, WIDTH_M, AutosaveConfig(every_s=1.0), saved=np.zeros(N_CELLS), generations=3)
    for k in range(1, 5):
        saver.tick(2.0 * k - 1.5, True, W * k)
        assert saver.tick(2.0 * k, True, W * k)
        saver.flush()
    assert saver.close(W * 5) and saver.saves == 5
    assert sorted(p.name for p in tmp_path.iterdir()) == ["w.npz", "w.npz.prev", "w.npz.prev2"]
    for name, k in (("w.npz", 5), ("w.npz.prev", 4), ("w.npz.prev2", 3)):
        assert np.array_equal(load_weights(tmp_path / name, N_CELLS, WIDTH_M), W * k)


def test_a_weights_folder_that_is_not_writable_refuses_the_start(tmp_path):
    from controller.daemon.run import StartError

    (tmp_path / "file").write_text("not a folder")
    with pytest.raises(StartError, match="not writable"):
        run_controller(virtual_bus(), weights=tmp_path / "file" / "w.npz", duration_s=0.05)
    if os.geteuid() != 0:  # root writes anywhere
        ro = tmp_path / "ro"
        ro.mkdir()
        ro.chmod(0o500)
        with pytest.raises(StartError, match="not writable"):
            run_controller(virtual_bus(), weights=ro / "w.npz", duration_s=0.05)


def test_the_command_line_refuses_an_unwritable_weights_folder_in_one_line(tmp_path, capsys):
    (tmp_path / "file").write_text("not a folder")
    assert main(["controller", "--interface", "virtual", "--channel", "x", "--socket", "none", "--seconds", "0.1",
                 "--weights", str(tmp_path / "file" / "w.npz")]) == 3
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not writable" in err[0] and "Traceback" not in err[0]
    assert err[0].startswith(f"elegant-stepping controller: error: the weights' folder {tmp_path / 'file'} ")


def test_without_a_weights_file_nothing_is_loaded_or_saved(tmp_path):
    final = run_controller(virtual_bus(), duration_s=0.05)
    assert final["weights_source"] is None and final["weights_saved"] is None and final["weights_saves"] is None
    assert not list(tmp_path.iterdir())


def test_a_fault_at_the_end_of_seconds_is_a_safety_stop_exit_5(tmp_path, capsys):
    config = tmp_path / "c.toml"
    bus = virtual_bus()
    config.write_text(f'[bus]\ninterface = "virtual"\nchannel = "{bus["channel"]}"\n[controller]\nbringup_timeout_s = 0.1\n')
    assert main(["controller", "--interface", "virtual", "--channel", bus["channel"], "--config", str(config),
                 "--socket", "none", "--seconds", "0.4", "--weights", str(tmp_path / "w.npz")]) == 5
    final = json.loads(capsys.readouterr().err.strip().splitlines()[-1])
    assert final["phase"] == "fault" and final["stopped_by"] == "duration" and final["weights_saved"] is None
    assert not (tmp_path / "w.npz").exists()  # zeros never learned from: never written


def _start_daemon(tmp_path, fault: bool = False):
    path, records, config = tmp_path / "w.npz", tmp_path / "r.jsonl", tmp_path / "c.toml"
    save_weights(path, W, WIDTH_M)
    channel = f"weights-{uuid.uuid4().hex[:8]}"
    config.write_text(f'[bus]\ninterface = "virtual"\nchannel = "{channel}"\n'
                      f"[controller]\nbringup_timeout_s = {0.1 if fault else 5.0}\n")
    proc = subprocess.Popen([sys.executable, "-m", "hil.cli", "controller", "--interface", "virtual", "--channel",
                             channel, "--weights", str(path), "--records", str(records), "--config", str(config),
                             "--socket", "none"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, stdin=subprocess.DEVNULL)
    wait_for = '"fault"' if fault else '"phase"'
    deadline = time.monotonic() + 60  # generous: an outcome waited for, not a duration asserted
    while not (records.exists() and wait_for in records.read_text()):  # ticking, handlers in place
        if proc.poll() is not None or time.monotonic() > deadline:
            proc.kill()
            out, err = proc.communicate()
            raise AssertionError(f"the daemon never recorded a {wait_for} phase (exit {proc.returncode}): {err[-2000:]}")
        time.sleep(0.05)
    return proc, path


@pytest.mark.parametrize("signum,fault", [(signal.SIGTERM, False), (signal.SIGINT, False), (signal.SIGTERM, True),
                                          (signal.SIGHUP, False), (signal.SIGUSR1, False)])
def test_a_signal_stops_the_daemon_with_exit_code_0_and_a_loadable_file(tmp_path, signum, fault):
    """Also after a safe stop (fault): the stop asked for is done in order, so the exit code is 0;
    the fault is in the final record. SIGHUP and SIGUSR1 stop exactly like SIGTERM (no reload)."""
    proc, path = _start_daemon(tmp_path, fault)
    before = path.read_bytes()
    try:
        os.kill(proc.pid, signum)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err
    assert "Traceback" not in err
    final = json.loads(err.strip().splitlines()[-1])
    assert final["stopped_by"] == signal.Signals(signum).name and final["weights_saved"] is None
    assert final["weights_source"] == "file" and final["phase"] == ("fault" if fault else "wait_nodes")
    assert path.read_bytes() == before  # never walked: never written
    assert not list(tmp_path.glob("*.tmp"))


def test_a_second_signal_during_the_stop_changes_nothing(tmp_path, monkeypatch):
    """SIGINT twice (a person pressing Ctrl-C again), then SIGTERM, while the stop runs (slowed by a
    test hook: the stop's IDLE frames are sent three times 10 ms apart): exit 0, no traceback."""
    proc, path = _start_daemon(tmp_path)
    try:
        os.kill(proc.pid, signal.SIGINT)
        for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
            time.sleep(0.005)
            try:
                os.kill(proc.pid, s)
            except ProcessLookupError:
                break
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err
    assert "Traceback" not in err and "KeyboardInterrupt" not in err
    final = json.loads(err.strip().splitlines()[-1])
    assert final["stopped_by"] == "SIGINT" and final["signals"][0] == "SIGINT"
    assert np.array_equal(load_weights(path, N_CELLS, WIDTH_M), W)
