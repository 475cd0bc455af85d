"""A sweep killed mid-cell: its workers die with it, and the same command again ends with the
records of an uninterrupted run."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from hil.analysis.records import compare, read
from hil.cli import main
from hil.experiments.journal import read_journal
from hil.experiments.learn import learn_into
from hil.experiments.sweep import Cell, cell_config

REPO = Path(__file__).resolve().parents[3]
SEED, TRIALS = 5, 4
ARGV = ["sweep", "--seeds", str(SEED), "--methods", "paper", "--trials", str(TRIALS), "--workers", "1", "--quiet"]
CELL = Cell("paper", 0.08, SEED, TRIALS)


def _children(pid: int) -> set[int]:
    """The processes whose parent is ``pid`` (from /proc)."""
    out = set()
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                stat = Path(f"/proc/{entry}/stat").read_text()
            except OSError:
                continue
            if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
                out.add(int(entry))
    return out


def _alive(pid: int) -> bool:
    """Running (a zombie waiting for a reaper has died)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def _wait(condition, what: str, timeout_s: float = 300.0) -> None:
    deadline = time.monotonic() + timeout_s  # generous: an outcome, not a timing
    while not condition():
        assert time.monotonic() < deadline, what
        time.sleep(0.02)


def test_a_sweep_killed_mid_cell_leaves_no_worker_and_resumes_to_the_same_records(tmp_path):
    out = tmp_path / "sweep"
    journal = CELL.folder(out) / "trials.jsonl"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")]))}
    parent = subprocess.Popen([sys.executable, "-m", "hil.cli", *ARGV, "--out", str(out)], env=env, cwd=REPO,
                              stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)

    def mid_cell() -> bool:
        assert parent.poll() is None, parent.communicate()
        return journal.exists() and journal.read_bytes().count(b"\n") >= 3  # the header and 2 trials

    _wait(mid_cell, "the cell never wrote its trials")
    workers = _children(parent.pid)
    assert workers, "no worker process found"
    parent.kill()
    parent.communicate()
    _wait(lambda: not any(_alive(w) for w in workers), f"workers {workers} outlived their parent")
    kept = len(read_journal(journal).records)
    assert 2 <= kept < TRIALS and not (CELL.folder(out) / "metrics.json").exists()

    assert main([*ARGV, "--out", str(out)]) == 0  # the same command again resumes the cell
    reference = tmp_path / "reference"
    learn_into(cell_config(CELL), reference)  # the cell's run, uninterrupted
    result = compare(read(reference), read(CELL.folder(out)))
    assert result["same"], result["first_difference"]


def test_sigterm_stops_the_sweep_and_its_workers(tmp_path):
    out = tmp_path / "sweep"
    journal = CELL.folder(out) / "trials.jsonl"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")]))}
    parent = subprocess.Popen([sys.executable, "-m", "hil.cli", *ARGV, "--out", str(out)], env=env, cwd=REPO,
                              stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    _wait(lambda: journal.exists() and journal.read_bytes().count(b"\n") >= 2, "the cell never wrote a trial")
    workers = _children(parent.pid)
    parent.send_signal(signal.SIGTERM)
    _, err = parent.communicate()
    assert parent.returncode == 130, err
    assert "stopped with 0 of 1 cells finished" in err and "run the same command again to resume" in err
    assert "Traceback" not in err
    _wait(lambda: not any(_alive(w) for w in workers), f"workers {workers} outlived the stop")
    assert len(read_journal(journal).records) >= 1  # the finished trials are kept
