"""Fault injection: ``kill -9`` during weight saves, then count what a restarted controller loads.

:func:`kill_during_saves` forks, ``n`` times, a child that saves weights in a tight loop
(:func:`controller.stepping.weights.save_weights`, about 2 ms a save with its two fsyncs) and kills it
with SIGKILL once it has completed a number of saves drawn from ``0..saves_before`` and a further
delay drawn uniformly from ``[0, max_delay_s)`` (both by a seeded numpy Generator), so most kills
land inside a save. The child reports each completed save through a pipe: the kill waits for the
child's progress, not for the wall clock alone, so a busy machine that leaves the child
unscheduled for a while still sees saves complete and kills land inside them.

Save number ``k`` writes ``np.full(n_cells, k * STEP)`` and each child continues the counter from the value the parent last loaded, so the parent knows
exactly which values can be on disk: after each kill the strict load
(:func:`controller.stepping.weights.load_weights`) must return a value that was written, no older than
the one loaded after the previous kill, or raise only because no save has completed yet; any
other outcome is a ``corrupt_load``. The ``.prev`` copy is checked the same way (``prev_corrupt``,
it must hold a value written no later than the file's). The fallback load
(:func:`controller.stepping.weights.load_weights_or_fallback`) is counted by its source.

The counts (``elegant-stepping killsave --json``) carry the stamp ``format: "killsave"``,
``format_version`` :data:`KILLSAVE_VERSION` and ``project_version`` first
(:func:`controller.errors.stamp`).
"""

from __future__ import annotations

import logging
import os
import signal
import time
from pathlib import Path
from typing import Any

import numpy as np

from controller.errors import stamp
from controller.stepping.weights import WeightsError, load_weights, load_weights_or_fallback, prev_path, save_weights

KILLSAVE_KIND = "killsave"
KILLSAVE_VERSION = 1  # the counts' format version: raise it when a reader of the old one could misread it
STEP = 1e-3  # save k writes weights k * STEP [s]
N_CELLS = 28
CELL_WIDTH_M = 0.04


def _child(path: Path, first_k: int, progress: int) -> None:
    """Save forever, one byte to ``progress`` after each save; never return (the parent kills us;
    exit status 1 if a save raised)."""
    try:
        k = first_k
        while True:
            save_weights(path, np.full(N_CELLS, k * STEP), CELL_WIDTH_M)
            os.write(progress, b".")
            k += 1
    finally:
        os._exit(1)


def _wait_for_saves(progress: int, saves: int) -> None:
    """Block until the child has reported ``saves`` completed saves (or closed the pipe by dying)."""
    while saves > 0:
        got = os.read(progress, saves)
        if not got:
            return
        saves -= len(got)


def _counter(weights: np.ndarray) -> int | None:
    """The k of ``np.full(N_CELLS, k * STEP)``, or None for any other array."""
    k = int(round(float(weights[0]) / STEP))
    return k if k >= 0 and np.array_equal(weights, np.full(N_CELLS, k * STEP)) else None


def _temporaries(folder: Path, path: Path) -> int:
    return sum(1 for _ in folder.glob(path.name + ".*.tmp"))


def kill_during_saves(n: int, folder: str | Path, seed: int, max_delay_s: float = 0.02,
                      saves_before: int = 2) -> dict[str, Any]:
    """Kill ``n`` saving children with SIGKILL at random instants (after ``0..saves_before``
    completed saves and a delay in ``[0, max_delay_s)``); load after each kill; count."""
    if n < 1:
        raise ValueError(f"n must be at least 1, got {n}")
    if not (isinstance(saves_before, int) and saves_before >= 0):
        raise ValueError(f"saves_before must be an integer >= 0, got {saves_before!r}")
    if not max_delay_s > 0:
        raise ValueError(f"max_delay_s must be positive, got {max_delay_s!r}")
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "weights.npz"
    for stale in (path, prev_path(path), *folder.glob(path.name + ".*.tmp")):
        stale.unlink(missing_ok=True)
    rng = np.random.default_rng(seed)
    counts = {"kills": 0, "loads_ok_from_file": 0, "loads_from_prev": 0, "zeros": 0, "corrupt_loads": 0,
              "strict_load_errors_before_first_save": 0, "kills_mid_save": 0, "tmp_files_max": 0,
              "child_errors": 0, "prev_corrupt": 0}
    corrupt: list[str] = []
    last_k: int | None = None  # what the strict load returned after the previous kill
    quiet = logging.getLogger("controller.stepping.weights")
    level = quiet.level
    quiet.setLevel(logging.CRITICAL)  # a thousand "starting from zeros" before the first save are expected
    t0 = time.perf_counter()
    try:
        for i in range(n):
            saves = int(rng.integers(0, saves_before + 1))
            delay = float(rng.uniform(0.0, max_delay_s))
            read_end, write_end = os.pipe()
            pid = os.fork()
            if pid == 0:
                os.close(read_end)
                _child(path, 0 if last_k is None else last_k + 1, write_end)
            os.close(write_end)
            try:
                _wait_for_saves(read_end, saves)
                time.sleep(delay)
                os.kill(pid, signal.SIGKILL)
                _, status = os.waitpid(pid, 0)
            finally:
                os.close(read_end)
            counts["kills"] += 1
            counts["child_errors"] += not (os.WIFSIGNALED(status) and os.WTERMSIG(status) == signal.SIGKILL)
            counts["tmp_files_max"] = max(counts["tmp_files_max"], _temporaries(folder, path))
            # the child was inside a save (between creating its temporary file and the rename)
            counts["kills_mid_save"] += any(folder.glob(f"{path.name}.{pid}.*.tmp"))
            try:
                loaded = load_weights(path, N_CELLS, CELL_WIDTH_M)
            except WeightsError as exc:
                if last_k is None and not path.exists():
                    counts["strict_load_errors_before_first_save"] += 1
                else:
                    counts["corrupt_loads"] += 1
                    corrupt.append(f"kill {i}: {exc}")
            else:
                k = _counter(loaded)
                if k is None or (last_k is not None and k < last_k):
                    counts["corrupt_loads"] += 1
                    corrupt.append(f"kill {i}: loaded {loaded[:3]}..., last good counter {last_k}")
                else:
                    last_k = k
            if prev_path(path).exists():  # the copy kept for the fallback must be a value written, no newer
                try:
                    kp = _counter(load_weights(prev_path(path), N_CELLS, CELL_WIDTH_M))
                except WeightsError:
                    kp = None
                if kp is None or (last_k is not None and kp > last_k):
                    counts["prev_corrupt"] += 1
                    corrupt.append(f"kill {i}: {prev_path(path).name} is not a value written before the file's")
            weights, source = load_weights_or_fallback(path, N_CELLS, CELL_WIDTH_M)
            if source == "file":
                counts["loads_ok_from_file"] += 1
            elif source == "prev":
                counts["loads_from_prev"] += 1
            else:
                counts["zeros"] += 1
                if last_k is not None:
                    corrupt.append(f"kill {i}: zeros after a complete save")
                    counts["corrupt_loads"] += 1
            if source != "zeros" and _counter(weights) is None:
                counts["corrupt_loads"] += 1
                corrupt.append(f"kill {i}: fallback ({source}) loaded a value never written")
    finally:
        quiet.setLevel(level)
    return {
        **stamp(KILLSAVE_KIND, KILLSAVE_VERSION),
        **counts,
        "tmp_files_left": _temporaries(folder, path),
        "saves_completed": 0 if last_k is None else last_k + 1,
        "corrupt_examples": corrupt[:10],
        "n": n,
        "seed": seed,
        "max_delay_s": max_delay_s,
        "saves_before": saves_before,
        "folder": str(folder),
        "elapsed_s": time.perf_counter() - t0,
    }
