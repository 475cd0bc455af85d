"""The controller daemon's weights: resumed across restarts (file, else .prev, else zeros, logged),
saved periodically while walking and at exit; SIGTERM/SIGINT stop with exit code 0 and a
loadable file. Runs on python-can's ``virtual`` bus (no leg: the daemon waits for its nodes)."""

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
    assert saver.close(w) and saver.saves == 3  # the final save is always made
    assert np.array_equal(load_weights(path, N_CELLS, WIDTH_M), w)
    assert np.array_equal(load_weights(prev_path(path), N_CELLS, WIDTH_M), w)
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


def test_the_daemon_resumes_from_the_weights_it_saved(tmp_path, caplog):
    path = tmp_path / "w.npz"
    save_weights(path, W, WIDTH_M)
    before = {s: signal.getsignal(s) for s in (signal.SIGTERM, signal.SIGINT)}
    caplog.set_level(logging.INFO)
    for run in range(2):
        final = run_controller(virtual_bus(), weights=path, duration_s=0.2, records=tmp_path / f"r{run}.jsonl")
        assert final["weights_source"] == "file" and final["stopped_by"] == "duration"
        assert final["weights_saved"] is True and final["weights_saves"] == 1
        assert np.array_equal(final["weights"], W)  # the premotor ran on the loaded weights
        assert np.array_equal(load_weights(path, N_CELLS, WIDTH_M), W)  # and they survive the restart unchanged
    assert np.array_equal(load_weights(prev_path(path), N_CELLS, WIDTH_M), W)
    assert f"weights: resuming from {path}" in caplog.text
    assert {s: signal.getsignal(s) for s in before} == before  # the handlers are given back
    lines = [json.loads(x) for x in (tmp_path / "r1.jsonl").read_text().splitlines()]
    assert lines[-1]["kind"] == "final" and lines[-1]["weights_source"] == "file"


def test_a_corrupt_file_resumes_from_prev_then_zeros_with_a_logged_reason(tmp_path, caplog):
    path = tmp_path / "w.npz"
    save_weights(path, W, WIDTH_M)
    save_weights(path, W * 2, WIDTH_M)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 3])
    with caplog.at_level(logging.INFO):
        final = run_controller(virtual_bus(), weights=path, duration_s=0.1)
    assert final["weights_source"] == "prev" and np.array_equal(final["weights"], W)
    assert any(r.levelname == "ERROR" and "truncated" in r.getMessage() for r in caplog.records)
    assert f"resuming from {path}.prev" in caplog.text and "previous good copy" in caplog.text
    assert np.array_equal(load_weights(path, N_CELLS, WIDTH_M), W)  # the good copy is the file again

    caplog.clear()
    path.write_bytes(b"garbage")
    prev_path(path).write_bytes(b"PK\x03\x04 garbage")
    with caplog.at_level(logging.INFO):
        final = run_controller(virtual_bus(), weights=path, duration_s=0.1)
    assert final["weights_source"] == "zeros" and final["weights"] == [0.0] * N_CELLS
    assert any(r.levelname == "WARNING" and "starting from zeros" in r.getMessage() for r in caplog.records)
    assert "resuming from zeros" in caplog.text
    assert np.array_equal(load_weights(path, N_CELLS, WIDTH_M), np.zeros(N_CELLS))


def test_without_a_weights_file_nothing_is_loaded_or_saved(tmp_path):
    final = run_controller(virtual_bus(), duration_s=0.05)
    assert final["weights_source"] is None and final["weights_saved"] is None and final["weights_saves"] is None
    assert not list(tmp_path.iterdir())


def test_a_fault_without_a_signal_exits_1(tmp_path, capsys):
    config = tmp_path / "c.toml"
    config.write_text("[controller]\nbringup_timeout_s = 0.1\n")
    bus = virtual_bus()
    assert main(["controller", "--interface", "virtual", "--channel", bus["channel"], "--config", str(config),
                 "--seconds", "0.4", "--weights", str(tmp_path / "w.npz")]) == 1
    final = json.loads(capsys.readouterr().err.strip().splitlines()[-1])
    assert final["phase"] == "fault" and final["stopped_by"] == "duration" and final["weights_saved"] is True


@pytest.mark.parametrize("signum,fault", [(signal.SIGTERM, False), (signal.SIGINT, False), (signal.SIGTERM, True)])
def test_a_signal_stops_the_daemon_with_exit_code_0_and_a_loadable_file(tmp_path, signum, fault):
    """Also after a safe stop (fault): the stop asked for is done in order, so the exit code is 0;
    the fault is in the final record."""
    path, records, config = tmp_path / "w.npz", tmp_path / "r.jsonl", tmp_path / "c.toml"
    save_weights(path, W, WIDTH_M)
    config.write_text(f"[controller]\nbringup_timeout_s = {0.1 if fault else 5.0}\n")
    channel = f"weights-{uuid.uuid4().hex[:8]}"
    proc = subprocess.Popen([sys.executable, "-m", "hil.cli", "controller", "--interface", "virtual", "--channel",
                             channel, "--weights", str(path), "--records", str(records), "--config", str(config)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, stdin=subprocess.DEVNULL)
    wait_for = '"fault"' if fault else '"phase"'
    try:
        deadline = time.monotonic() + 60
        while not (records.exists() and wait_for in records.read_text()):  # ticking, handlers in place
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() < deadline
            time.sleep(0.05)
        os.kill(proc.pid, signum)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err
    final = json.loads(err.strip().splitlines()[-1])
    assert final["stopped_by"] == signal.Signals(signum).name and final["weights_saved"] is True
    assert final["weights_source"] == "file" and final["phase"] == ("fault" if fault else "wait_nodes")
    assert np.array_equal(load_weights(path, N_CELLS, WIDTH_M), W)
    assert not list(tmp_path.glob("*.tmp"))
