"""Periodic saving of the controller daemon's learned weights, off the control loop's thread.

:class:`WeightAutosave` is told every tick whether the leg walks; after every ``every_s`` seconds
of walking it saves the weights with :func:`controller.stepping.weights.save_weights` if they changed
since the last save. The save (write, fsync, rename, fsync: about 2 ms) runs on one background
thread, on a copy of the weights taken on the loop's thread, so a tick never waits for the disk;
a save still running when the next one is due postpones that one. A failed periodic save is
logged and retried at the next period; the daemon keeps running. :meth:`WeightAutosave.close`
waits for a running save and then saves the final weights on the caller's thread, but only if
they differ from what is on disk (``saved``: the weights loaded at start, then each save's): a run
that never changed them (never walked, no learning update) never writes, so the good file and
its older generations stay byte-identical. Each save keeps ``generations`` good files
(:func:`controller.stepping.weights.save_weights`).
"""

from __future__ import annotations

import logging
import math
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from controller.stepping.weights import save_weights

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class AutosaveConfig:
    """Attributes:
        every_s: save after this many seconds of walking [s], if the weights changed; default 10.
    """

    every_s: float = 10.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.every_s) and self.every_s > 0):
            raise ValueError(f"every_s must be a positive number of seconds, got {self.every_s!r}")


class WeightAutosave:
    def __init__(self, path: str | Path, cell_width_m: float, config: AutosaveConfig = AutosaveConfig(),
                 saved: np.ndarray | None = None, generations: int = 2) -> None:
        """``saved``: the weights the run started from (loaded from ``path`` or one of its older
        generations, or the zeros it started with), so that an unchanged copy is never written."""
        self.path = Path(path)
        self.cell_width_m = cell_width_m
        self.config = config
        self.generations = generations
        self.unchanged = False  # set by close(): nothing to write
        self.saves = 0
        self.failures = 0
        self.walked_s = 0.0
        self._saved = None if saved is None else np.array(saved, dtype=float)
        self._last_s: float | None = None
        self._pending: Future | None = None
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="weights-autosave")

    def _reap(self) -> bool:
        """True when no save is running (the finished one's outcome accounted for)."""
        job = self._pending
        if job is None:
            return True
        if not job.done():
            return False
        self._pending = None
        exc = job.exception()
        if exc is None:
            self.saves += 1
        else:
            self.failures += 1
            self._saved = None  # not on disk: the next period saves again
            log.error("weights: periodic save to %s failed: %s", self.path, exc)
        return True

    def tick(self, now_s: float, walking: bool, weights: np.ndarray | None) -> bool:
        """Account for the time since the last tick; start a save when one is due. True if started."""
        last, self._last_s = self._last_s, now_s
        if walking and last is not None:
            self.walked_s += max(0.0, now_s - last)
        if self.walked_s < self.config.every_s or weights is None or not self._reap():
            return False
        self.walked_s = 0.0
        if self._saved is not None and np.array_equal(weights, self._saved):
            return False
        copy = np.array(weights, dtype=float)
        self._saved = copy
        self._pending = self._pool.submit(save_weights, self.path, copy, self.cell_width_m, self.generations)
        return True

    def flush(self) -> None:
        """Wait for a running save to finish (its outcome accounted for and, if it failed, logged)."""
        job = self._pending
        if job is not None:
            try:
                job.result()
            except Exception:  # noqa: BLE001 - accounted for and logged by _reap
                pass
            self._reap()

    def close(self, weights: np.ndarray | None) -> bool:
        """Wait for a running save, then save ``weights`` (None: nothing to save) now, unless they
        equal what is on disk (``unchanged`` is then True). True if the final save succeeded (or
        there was nothing to save); a failure is logged, never raised."""
        self.flush()
        self._pool.shutdown(wait=True)
        if weights is None:
            return True
        if self._saved is not None and np.array_equal(weights, self._saved):
            self.unchanged = True
            log.info("weights: unchanged since %s, not written", "the last save" if self.saves else "the start")
            return True
        try:
            save_weights(self.path, weights, self.cell_width_m, self.generations)
        except (OSError, ValueError) as exc:
            self.failures += 1
            log.error("weights: final save to %s failed: %s", self.path, exc)
            return False
        self.saves += 1
        self._saved = np.array(weights, dtype=float)
        log.info("weights: saved to %s", self.path)
        return True
