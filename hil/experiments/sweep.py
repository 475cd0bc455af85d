"""The sweep engine: every (method, obstacle height, seed) cell on a process pool or a Dask cluster.

A cell is one learning run, :func:`hil.experiments.learn.run_method`, written to ``DIR/cells/<cell>/``,
a learn run folder (``trials.jsonl``, ``weights.npz``, ``metrics.json``: :func:`hil.experiments.learn.learn_into`).
The pool and the Dask path submit the same top-level, picklable function, :func:`run_cell`. A cell
that raises is recorded and the others are kept.

**Nothing is lost, nothing is deleted.** ``DIR/config.json`` holds the sweep's configuration; a
sweep into a folder whose configuration differs (any key, ``trials`` included) is refused
(:class:`controller.errors.InputError`, naming the first differing key) and nothing is touched;
``--overwrite`` (``overwrite=True``) first clears the sweep's own files (:data:`SWEEP_FILES`), and
only in a folder that is a sweep's. A cell counts as done only when its ``metrics.json`` verifies
(stamp, the whole learn configuration, the trial count, a success flag per trial) and, for a method
that learns weights, its ``weights.npz`` loads with its checksum verified; a cell with only a
``trials.jsonl`` resumes through learn's resume; a cell that holds something else is *refused*
(reported, its files kept), never run over. One writer per folder: the sweep holds ``DIR/.lock``
while it runs (a second sweep into ``DIR`` is refused), each cell's run holds its own folder's
lock (a cell another process is writing is reported ``busy``, not run twice).

**Workers die with their parent.** Each pool worker asks the kernel for SIGKILL when its parent
dies (``prctl(PR_SET_PDEATHSIG)``, Linux) and, as a fallback, watches its parent id from a daemon
thread; it ignores SIGINT (the parent decides), and when the parent stops on an exception
(SIGINT, or SIGTERM mapped to it by the command line) it terminates its workers before returning.
A killed worker leaves its cell's finished trials in ``trials.jsonl``: the next sweep resumes it.
(The Dask path leaves its workers to Dask.)

The sweep folder ``DIR``:

- ``config.json``: ``{"format": "sweep-config", "format_version": 1, ...}`` and the sweep's
  configuration (methods, heights, mixed_heights, seeds, trials);
- ``summary.json``: ``{"format": "sweep-summary", ..., "rows": [...]}``, one row per finished cell
  (:func:`summary_row`), sorted by method (in the given order), height, seed; no wall-clock time
  in it, so it does not depend on the executor (version 0, before stamps, was the bare list);
- ``timing.json``: stamped ``sweep-timing``: wall time per cell and in total, which executor ran
  them, each cell's status (``ran``, ``resumed`` = finished before, ``failed``, ``refused``,
  ``busy``) and the errors.

The figures and ``report.md`` are :mod:`hil.analysis.report`'s. With a remote Dask cluster, ``DIR`` must be
on a filesystem that the workers share with the caller: the cells write their files themselves.
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import multiprocessing
import os
import re
import shutil
import signal
import sys
import threading
import time
import traceback
import uuid
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterator, Sequence

from controller.atomic import fsync_dir, write_json_atomic
from controller.errors import InputError, check_stamp, stamp
from hil.analysis.metrics import success_last
from hil.analysis.stats import trials_to_criterion
from hil.experiments.conditions import Conditions, check_leg_limit
from hil.experiments.journal import FolderBusy, FolderLock, is_locked, prepare_folder
from hil.experiments.methods import DEFAULT_SWEEP_METHODS, METHODS

log = logging.getLogger(__name__)

DEFAULT_METHODS = DEFAULT_SWEEP_METHODS
SWEEP_VERSION = 1
SWEEP_FILES = ("cells", "config.json", "summary.json", "timing.json", "report.md", "figures")
"""What a sweep writes in its folder, and all that ``--overwrite`` removes."""
# as hil.experiments.conditions: the sensor sees above 3 cm (and the leg's limit, checked apart)
MIN_HEIGHT_M, MAX_HEIGHT_M = 0.03, 0.50

Height = float | tuple[float, ...]


def parse_seeds(text: str) -> tuple[int, ...]:
    """Seeds from ``"0,1,2"``, a range ``"0-9"`` (inclusive) or both (``"0-2,7"``)."""
    seeds: list[int] = []
    for part in str(text).split(","):
        part = part.strip()
        m = re.fullmatch(r"(\d+)\s*-\s*(\d+)", part)
        try:
            if m:
                lo, hi = int(m.group(1)), int(m.group(2))
                if lo > hi:
                    raise ValueError
                seeds.extend(range(lo, hi + 1))
            else:
                seeds.append(int(part))
        except ValueError:
            raise ValueError(f"seeds: {part!r} in {text!r} is not a seed or a range like 0-9") from None
    return tuple(seeds)


def parse_heights(text: str) -> tuple[float, ...]:
    """Obstacle heights [m] from a comma list such as ``"0.06,0.10"``."""
    try:
        return tuple(float(p) for p in str(text).split(","))
    except ValueError:
        raise ValueError(f"obstacle_heights_m: {text!r} is not a comma list of heights in metres") from None


def parse_methods(text: str) -> tuple[str, ...]:
    """Methods from a comma list such as ``"paper,none"`` (checked by :class:`SweepConfig`)."""
    return tuple(p.strip() for p in str(text).split(",") if p.strip())


def height_tag(height: Height) -> str:
    """A height as a file-name tag: ``60mm``, or ``60mm+100mm`` for a mixed scenario."""
    heights = height if isinstance(height, tuple) else (height,)
    return "+".join(f"{round(h * 1000.0, 6):g}mm" for h in heights)


@dataclass(frozen=True)
class Cell:
    """One learning run of a sweep.

    Attributes:
        method: the method's registry name (:mod:`hil.experiments.methods`); a cell read from an
            older sweep folder may carry the old alias ``learner``.
        obstacle_height_m: obstacle height [m]; a tuple mixes these heights, one drawn per trial.
        seed: the run's seed.
        trials: number of trials.
        conditions: the sweep's other conditions (its heights aside: the cell's are
            ``obstacle_height_m``); the same for every cell of a sweep, so not in the cell's name.
    """

    method: str
    obstacle_height_m: Height
    seed: int
    trials: int
    conditions: Conditions = Conditions()

    @property
    def name(self) -> str:
        return f"{self.method}_h{height_tag(self.obstacle_height_m)}_s{self.seed}"

    def folder(self, out_dir: Path) -> Path:
        return Path(out_dir) / "cells" / self.name

    def mismatch(self, metrics: Any) -> str | None:
        """Why ``metrics`` (a parsed ``metrics.json``) is not this cell's finished run; None if it is."""
        try:
            config, trials = metrics["config"], metrics["trials"]
            mixed = isinstance(self.obstacle_height_m, tuple)
            heights = list(self.obstacle_height_m) if mixed else []
            want = {"method": self.method, "seed": self.seed, "trials": self.trials, "obstacle_heights_m": heights}
            if not mixed:
                want["obstacle_height_m"] = self.obstacle_height_m
            for key, value in want.items():
                if config.get(key) != value:
                    return f"config {key} is {config.get(key)!r}, the cell's is {value!r}"
            if len(trials) != self.trials or not all(isinstance(t["success"], bool) for t in trials):
                return f"it holds {len(trials)} trials, not {self.trials} with a success flag each"
        except (KeyError, TypeError) as exc:
            return f"it is not a learn run's metrics ({type(exc).__name__}: {exc})"
        return None


def grid(methods: Sequence[str], obstacle_heights_m: Sequence[float], mixed_heights: bool, seeds: Sequence[int],
         trials: int, conditions: Conditions = Conditions()) -> list[Cell]:
    """The cells in summary order: methods as given, then heights (ascending), then seeds."""
    scenarios: list[Height] = [tuple(obstacle_heights_m)] if mixed_heights else sorted(obstacle_heights_m)
    return [Cell(m, h, s, trials, conditions) for m in methods for h in scenarios for s in sorted(seeds)]


@dataclass(frozen=True)
class SweepConfig:
    """A sweep over seeds x obstacle heights x methods.

    Attributes:
        out_dir: the sweep folder (see the module docstring); required.
        seeds: the runs' seeds (start distances and sensor noise); default 0..9.
        obstacle_heights_m: obstacle heights [m], each in (0.03, 0.20], one scenario each;
            default (0.08,).
        methods: the methods compared, in report order: names of the method registry
            (:data:`hil.experiments.methods.METHODS`); default paper, none, oracle, rl.
        trials: trials per run, >= 1; default 150.
        mixed_heights: True makes ``obstacle_heights_m`` ONE scenario in which each trial draws
            its height from the list; default False.
        workers: processes of the local pool, or of the ``dask="local"`` cluster, >= 1;
            default os.cpu_count().
        conditions: every cell's other experimental conditions (rail speeds, start range, sensor
            noise and dropout, obstacle depth: :class:`hil.experiments.conditions.Conditions`;
            their ``obstacle_heights_m`` is not used: the grid's are this config's); default
            the declared defaults, the paper's set-up.
        dask: None runs the cells on a local process pool; ``"local"`` starts a
            ``distributed.LocalCluster`` (processes, one thread each) and closes it afterwards;
            anything else is a Dask scheduler's address (``tcp://host:8786``); default None.
    """

    out_dir: Path
    seeds: tuple[int, ...] = tuple(range(10))
    obstacle_heights_m: tuple[float, ...] = (0.08,)
    methods: tuple[str, ...] = DEFAULT_METHODS
    trials: int = 150
    mixed_heights: bool = False
    workers: int = field(default_factory=lambda: os.cpu_count() or 1)
    dask: str | None = None
    conditions: Conditions = Conditions()

    def __post_init__(self) -> None:
        if not str(self.out_dir).strip():  # Path("") would be the current folder
            raise InputError("--out: an empty path; give a folder (e.g. --out sweeps/heights)")
        object.__setattr__(self, "out_dir", Path(self.out_dir))
        for name in ("seeds", "obstacle_heights_m", "methods"):
            object.__setattr__(self, name, tuple(getattr(self, name)))
            values = getattr(self, name)
            if not values:
                raise ValueError(f"{name}: need at least one")
            if len(set(values)) != len(values):
                raise ValueError(f"{name}: duplicates in {list(values)}")
        for s in self.seeds:
            if isinstance(s, bool) or not isinstance(s, int) or s < 0:
                raise ValueError(f"seeds: need non-negative integers, got {s!r}")
        for h in self.obstacle_heights_m:
            if not (isinstance(h, (int, float)) and math.isfinite(h) and MIN_HEIGHT_M < h <= MAX_HEIGHT_M):
                raise ValueError(f"obstacle_heights_m: each must be in ({MIN_HEIGHT_M}, {MAX_HEIGHT_M}] m, got {h!r}")
        self._check_leg_limit()
        for m in self.methods:
            if m not in METHODS:
                raise ValueError(f"methods: unknown method {m!r}; choose from {', '.join(METHODS)}")
        if isinstance(self.trials, bool) or not isinstance(self.trials, int) or not 1 <= self.trials <= 100000:
            raise ValueError(f"trials: must be an integer in [1, 100000], got {self.trials!r}")
        if isinstance(self.workers, bool) or not isinstance(self.workers, int) or self.workers < 1:
            raise ValueError(f"workers: must be a positive integer, got {self.workers!r}")
        if self.dask is not None and not str(self.dask).strip():
            raise ValueError("dask: give 'local' or a scheduler address such as tcp://host:8786")
        if len({c.name for c in self.cells()}) != len(self.cells()):
            raise ValueError(f"obstacle_heights_m: heights closer than 1 nm give the same cell names: "
                             f"{list(self.obstacle_heights_m)}")

    def _check_leg_limit(self) -> None:
        """The tallest height within what the leg can clear at all, for the controller told the
        sweep's rail speed (:func:`hil.experiments.conditions.check_leg_limit`, as ``learn``)."""
        from dataclasses import replace as _replace

        from controller.config import ControllerConfig

        c = self.conditions
        ctl = ControllerConfig()
        ctl = _replace(ctl, gait=_replace(ctl.gait, ground_speed_m_s=c.believed_rail_speed_m_s or c.rail_speed_m_s))
        check_leg_limit(self.obstacle_heights_m, c.obstacle_depth_m, ctl, "obstacle_heights_m")

    def cells(self) -> list[Cell]:
        return grid(self.methods, self.obstacle_heights_m, self.mixed_heights, self.seeds, self.trials,
                    self.conditions)

    def to_json(self) -> dict[str, Any]:
        """What the results depend on (not where or how they were computed)."""
        return {"methods": list(self.methods), "obstacle_heights_m": list(self.obstacle_heights_m),
                "mixed_heights": self.mixed_heights, "seeds": list(self.seeds), "trials": self.trials,
                "conditions": conditions_json(self.conditions)}


def conditions_json(conditions: Conditions) -> dict[str, Any]:
    """A sweep's conditions as its ``config.json`` holds them: all but the heights (the grid's)."""
    return {k: v for k, v in conditions.to_json().items() if k != "obstacle_heights_m"}


def cells_from_json(config: dict[str, Any]) -> list[Cell]:
    """The cells of a sweep from its ``config.json``."""
    try:
        return grid(config["methods"], config["obstacle_heights_m"], config["mixed_heights"], config["seeds"],
                    config["trials"])
    except (KeyError, TypeError) as exc:
        raise InputError(f"config.json: not a sweep configuration ({type(exc).__name__}: {exc})") from None


CONFIG_KEYS = ("methods", "obstacle_heights_m", "mixed_heights", "seeds", "trials")
"""The keys every sweep's ``config.json`` has (besides its stamp): what the results depend on.
Since issue 18 it also has ``conditions`` (:func:`conditions_json`); a file written before has
none, which reads as the default conditions (those its cells ran with)."""


def read_sweep_config(path: str | Path) -> dict[str, Any]:
    """A sweep's ``config.json`` (version 1 stamped ``sweep-config``, or version 0 of before
    stamps) without its stamp: the keys of :data:`CONFIG_KEYS`.

    Raises:
        FileNotFoundError: no such file.
        InputError: not JSON, another kind of file, an unknown version, or a key missing.
    """
    path = Path(path)
    try:
        data = json.loads(path.read_bytes())
    except FileNotFoundError:
        raise FileNotFoundError(f"{path}: not found (is {path.parent} a sweep folder?)") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: not valid JSON ({exc})") from None
    check_stamp(data, "sweep-config", (0, SWEEP_VERSION), str(path))
    missing = [k for k in CONFIG_KEYS if k not in data]
    if missing:
        raise InputError(f"{path}: not a sweep configuration ({', '.join(repr(k) for k in missing)} missing)")
    if not all(isinstance(data[k], list) for k in ("methods", "obstacle_heights_m", "seeds")):
        raise InputError(f"{path}: not a sweep configuration (methods, obstacle_heights_m and seeds must be lists)")
    conditions = data.get("conditions", conditions_json(Conditions()))
    if not isinstance(conditions, dict):
        raise InputError(f"{path}: not a sweep configuration (conditions must be a table of conditions)")
    return {**{k: data[k] for k in CONFIG_KEYS}, "conditions": conditions}


def summary_row(cell: Cell, success: Sequence[bool]) -> dict[str, Any]:
    """A ``summary.json`` row from a cell's trial outcomes (True: stepped over without contact).

    ``trials_to_criterion``: trials run before the first 10-trial window at least 90% successful
    (None if never); ``mistakes_after_100``: failures among trials 101..N (None if N <= 100);
    ``success_last_50``: :func:`hil.analysis.metrics.success_last` over 50 trials;
    ``success_rate``: over all trials.
    """
    s = [bool(x) for x in success]
    if not s:
        raise ValueError(f"success: cell {cell.name} has no trials")
    return {
        "method": cell.method,
        "obstacle_height_m": list(cell.obstacle_height_m) if isinstance(cell.obstacle_height_m, tuple)
        else cell.obstacle_height_m,
        "seed": cell.seed,
        "trials": len(s),
        "trials_to_criterion": trials_to_criterion(s, window=10, threshold=0.9),
        "mistakes_after_100": sum(not x for x in s[100:]) if len(s) > 100 else None,
        "success_last_50": success_last(s, 50),
        "success_rate": sum(s) / len(s),
        "cell": cell.name,
    }


def cell_config(cell: Cell):
    """The cell's learn configuration (:func:`hil.experiments.learn.learn_config`)."""
    from hil.experiments.learn import learn_config

    return learn_config(cell.method, seed=cell.seed, trials=cell.trials, obstacle_height_m=cell.obstacle_height_m,
                        conditions=cell.conditions)


def run_cell(method: str, seed: int, trials: int, obstacle_height_m: Height, out_dir: str,
             conditions: Conditions = Conditions()) -> dict[str, Any]:
    """Run one cell into ``out_dir`` (the task that the pool and Dask run): returns its wall time
    [s], how many trials were kept from a stopped run (``kept``), whether the folder was ``busy``
    and, if it raised, the error (the exception is caught here so that it always pickles)."""
    t0 = time.perf_counter()
    busy, kept = False, 0
    try:
        from hil.experiments.learn import learn_config, learn_into

        config = learn_config(method, seed=seed, trials=trials, obstacle_height_m=obstacle_height_m,
                              conditions=conditions)
        kept = learn_into(config, out_dir, what=f"cell {Path(out_dir).name}").kept
        error = tb = None
    except FolderBusy as exc:
        busy, error, tb = True, str(exc), None
    except Exception as exc:  # noqa: BLE001 - a failed cell is recorded, the sweep goes on
        error, tb = f"{type(exc).__name__}: {exc}", traceback.format_exc()
    return {"wall_s": time.perf_counter() - t0, "error": error, "traceback": tb, "busy": busy, "kept": kept}


def read_cell(cell: Cell, out_dir: Path) -> tuple[dict[str, Any] | None, str | None]:
    """A finished cell's verified metrics (:func:`hil.experiments.learn.folder_state`: the stamp,
    the whole configuration, every trial's success flag, the weights' checksum), or None and why
    its folder cannot be resumed either (None: it never ran, or it holds an unfinished run of the
    cell, which :func:`run_cell` resumes)."""
    from hil.experiments.learn import folder_state

    folder = cell.folder(out_dir)
    if not folder.is_dir():
        return None, None
    try:
        state = folder_state(folder, cell_config(cell), what=f"cell {cell.name}")
    except InputError as exc:
        return None, str(exc)
    if state.kind != "finished":
        return None, None
    reason = cell.mismatch(state.metrics)
    return (None, f"{folder / 'metrics.json'} does not match the cell: {reason}") if reason else (state.metrics, None)


def _task(cell: Cell, out_dir: Path) -> tuple:
    return (cell.method, cell.seed, cell.trials, cell.obstacle_height_m, str(cell.folder(out_dir)), cell.conditions)


def _outcome(get: Callable[[], dict[str, Any]]) -> dict[str, Any]:
    """A task's result, or the executor's error (a worker that died, a lost connection...)."""
    try:
        return get()
    except Exception as exc:  # noqa: BLE001
        return {"wall_s": None, "error": f"{type(exc).__name__}: {exc}", "traceback": traceback.format_exc()}


PR_SET_PDEATHSIG = 1  # <linux/prctl.h>
PARENT_POLL_S = 0.5


def _die_with_parent(parent_pid: int) -> None:
    """A pool worker's initializer: SIGKILL when the parent dies (prctl, Linux), and a daemon
    thread that exits the worker if its parent id changes (the fallback, and the check for a
    parent that died before the prctl); SIGINT is ignored (the parent stops its workers)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if sys.platform.startswith("linux"):
        try:
            import ctypes

            ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)
        except (OSError, AttributeError):  # no prctl here: the thread below still watches
            pass
    if os.getppid() != parent_pid:
        os._exit(1)

    def watch() -> None:
        while True:
            time.sleep(PARENT_POLL_S)
            if os.getppid() != parent_pid:
                os._exit(1)

    threading.Thread(target=watch, name="parent-watch", daemon=True).start()


def _on_pool(todo: list[Cell], out_dir: Path, workers: int) -> Iterator[tuple[Cell, dict[str, Any]]]:
    # spawn, not fork: the parent may hold threads (tqdm, logging) that a fork would copy mid-state
    context = multiprocessing.get_context("spawn")
    pool = ProcessPoolExecutor(max_workers=min(workers, len(todo)), mp_context=context,
                               initializer=_die_with_parent, initargs=(os.getpid(),))
    finished = False
    try:
        futures = {pool.submit(run_cell, *_task(c, out_dir)): c for c in todo}
        for future in as_completed(futures):
            yield futures[future], _outcome(future.result)
        finished = True
    finally:
        if not finished:  # stopped (SIGINT, SIGTERM, an error): stop the workers too, do not wait for their cells
            for process in list((getattr(pool, "_processes", None) or {}).values()):
                with contextlib.suppress(OSError, ValueError, AttributeError):
                    process.terminate()
        pool.shutdown(wait=True, cancel_futures=True)


def _on_dask(todo: list[Cell], out_dir: Path, address: str, workers: int) -> Iterator[tuple[Cell, dict[str, Any]]]:
    import distributed

    if not log.isEnabledFor(logging.DEBUG):  # the scheduler's INFO chatter would bury the progress bar
        logging.getLogger("distributed").setLevel(logging.WARNING)
    cluster = None
    if address == "local":
        log.info("starting a Dask LocalCluster of %d worker processes", workers)
        cluster = distributed.LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                           dashboard_address=None)
        client = distributed.Client(cluster)
    else:
        log.info("connecting to the Dask scheduler at %s", address)
        client = distributed.Client(address)
    try:
        run = uuid.uuid4().hex[:8]
        by_key = {}
        for c in todo:
            future = client.submit(run_cell, *_task(c, out_dir), key=f"cell-{c.name}-{run}", pure=False)
            by_key[future.key] = (c, future)
        for future in distributed.as_completed([f for _, f in by_key.values()]):
            yield by_key[future.key][0], _outcome(future.result)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


class SweepStopped(KeyboardInterrupt):
    """A sweep stopped by SIGINT (or SIGTERM, where the command line maps it): ``finished`` of
    ``total`` cells are done; the running cells keep their finished trials."""

    def __init__(self, finished: int, total: int) -> None:
        super().__init__(f"stopped with {finished} of {total} cells finished")
        self.finished, self.total = finished, total


def check_folder(out: Path, config: SweepConfig, overwrite: bool = False, shown: str | Path | None = None) -> None:
    """Refuse a sweep folder that holds another sweep (or, with ``overwrite``, clear its own files).

    Raises:
        InputError: ``config.json`` names another configuration (the first differing key; nothing
            is deleted), is damaged, or is missing in a folder holding anything but a sweep's own
            files (``--out /tmp``), or beside a ``cells/`` folder; with ``overwrite``,
            also a cell that another process is writing.
    """
    from hil.experiments.learn import config_difference

    out_shown = out if shown is None else shown  # the folder as the person gave it
    path = out / "config.json"
    if not path.exists():
        others = sorted(p.name for p in out.iterdir() if p.name not in SWEEP_FILES and p.name != ".lock") \
            if out.is_dir() else []
        if others:  # a sweep writes config.json first: a folder of other things is not one (e.g. --out /tmp)
            raise InputError(f"--out {out_shown}: holds {', '.join(others[:3])}{' ...' if len(others) > 3 else ''} "
                             f"and no sweep config.json: not a sweep's folder; give an empty or new --out")
        stray = [n for n in ("cells", "summary.json") if (out / n).exists()]
        if stray and overwrite:  # without --overwrite nothing is deleted: each cell is checked on its own
            raise InputError(f"--out {out_shown}: holds {', '.join(stray)} but no config.json: not a sweep's folder, "
                             f"so --overwrite does not clear it; move it away or give another --out")
        return
    have = read_sweep_config(path)
    if overwrite:
        cells = out / "cells"
        busy = [p.name for p in (sorted(cells.iterdir()) if cells.is_dir() else []) if p.is_dir() and is_locked(p)]
        if busy:
            raise InputError(f"--out {out_shown}: cell {busy[0]} is being written by another process; "
                             f"not clearing the sweep")
        for name in SWEEP_FILES:
            target = out / name
            if target.is_dir() and not target.is_symlink():
                shutil.rmtree(target)
            elif target.exists() or target.is_symlink():
                target.unlink()
        fsync_dir(out)
        log.info("cleared the sweep in %s (--overwrite)", out)
        return
    diff = config_difference(have, config.to_json())
    if diff:
        raise InputError(f"--out {out_shown}: holds a sweep of another configuration ({diff}); nothing was deleted: "
                         f"use another --out, or --overwrite to clear this sweep's files and start over")


def run_sweep(config: SweepConfig, progress: bool = True, overwrite: bool = False) -> dict[str, Any]:
    """Run the sweep's unfinished cells; write ``config.json``, ``summary.json`` and ``timing.json``.

    The folder is checked (:func:`check_folder`) and locked before any cell runs.

    Returns ``{"cells", "ran", "resumed", "failed", "refused", "busy": [cell names], "rows"}``
    (``resumed``: cells finished before; ``refused``: cells whose folder holds something that is
    not this cell's run, kept as it is; ``busy``: cells another process is writing).

    Raises:
        InputError: the folder (:func:`check_folder`, :func:`hil.experiments.journal.prepare_folder`).
        FolderBusy: another sweep is running in the folder.
        SweepStopped: SIGINT during the run (the workers are stopped).
    """
    from tqdm import tqdm
    from tqdm.contrib.logging import logging_redirect_tqdm

    wall0 = time.perf_counter()
    out = prepare_folder(config.out_dir, "--out").resolve()  # absolute: the workers may run elsewhere
    with FolderLock(out, f"--out {config.out_dir}"):
        check_folder(out, config, overwrite, shown=config.out_dir)
        write_json_atomic(out / "config.json", {**stamp("sweep-config", SWEEP_VERSION), **config.to_json()})
        cells = config.cells()
        rows: dict[str, dict[str, Any]] = {}
        timing: dict[str, dict[str, Any]] = {}
        todo: list[Cell] = []
        for cell in cells:
            if cell.folder(out).is_dir() and is_locked(cell.folder(out)):
                timing[cell.name] = {"status": "busy", "wall_s": None,
                                     "error": f"cell {cell.name}: another process is writing {cell.folder(out)}"}
                continue
            metrics, problem = read_cell(cell, out)
            if metrics is not None:
                rows[cell.name] = summary_row(cell, [t["success"] for t in metrics["trials"]])
                timing[cell.name] = {"status": "resumed", "wall_s": metrics.get("summary", {}).get("wall_s"),
                                     "error": None}
            elif problem:
                log.error("%s; the cell is kept as it is and not run (--overwrite starts the sweep over)", problem)
                timing[cell.name] = {"status": "refused", "wall_s": None, "error": problem}
            else:
                todo.append(cell)
        log.info("%d of %d cells to run (%d finished before)", len(todo), len(cells), len(rows))

        executor = "pool" if config.dask is None else f"dask {config.dask}"
        if todo:
            results = (_on_pool(todo, out, config.workers) if config.dask is None
                       else _on_dask(todo, out, config.dask, config.workers))
            try:
                with contextlib.closing(results), logging_redirect_tqdm(), \
                        tqdm(total=len(todo), unit="cell", desc="sweep", disable=not progress) as bar:
                    for cell, result in results:
                        _record(cell, result, out, config, rows, timing)
                        bar.set_postfix(failed=sum(t["status"] == "failed" for t in timing.values()), refresh=False)
                        bar.update(1)
            except KeyboardInterrupt:
                raise SweepStopped(len(rows), len(cells)) from None

        by_status = {status: [c.name for c in cells if timing[c.name]["status"] == status]
                     for status in ("ran", "resumed", "failed", "refused", "busy")}
        ordered = [rows[c.name] for c in cells if c.name in rows]
        write_json_atomic(out / "summary.json", {**stamp("sweep-summary", SWEEP_VERSION), "rows": ordered})
        write_json_atomic(out / "timing.json", {
            **stamp("sweep-timing", SWEEP_VERSION),
            "executor": executor,
            "workers": config.workers,
            "total_wall_s": time.perf_counter() - wall0,
            **{status: (len(names) if status in ("ran", "resumed") else names) for status, names in by_status.items()},
            "cells": [{"cell": c.name, **timing[c.name]} for c in cells],
        })
    return {"cells": len(cells), "ran": len(by_status["ran"]), "resumed": len(by_status["resumed"]),
            "failed": by_status["failed"], "refused": by_status["refused"], "busy": by_status["busy"],
            "rows": ordered}


def _record(cell: Cell, result: dict[str, Any], out: Path, config: SweepConfig, rows: dict[str, dict[str, Any]],
            timing: dict[str, dict[str, Any]]) -> None:
    """Book one finished task: its row if the cell now verifies, else why not."""
    error = result["error"]
    status = "busy" if result.get("busy") else "ran"
    if error is None:
        metrics, problem = read_cell(cell, out)
        if metrics is None:
            error = f"the run finished but left no valid metrics.json: {problem or 'missing'}" + (
                "" if config.dask in (None, "local") else " (is the folder shared with the workers?)")
        else:
            rows[cell.name] = summary_row(cell, [t["success"] for t in metrics["trials"]])
    if error is not None and status != "busy":
        status = "failed"
        log.error("cell %s failed: %s", cell.name, error)
        if result.get("traceback"):
            log.debug("%s", result["traceback"])
    elif status == "busy":
        log.error("%s", error)
    timing[cell.name] = {"status": status, "wall_s": result["wall_s"], "error": error,
                         **({"kept_trials": result["kept"]} if result.get("kept") else {}),
                         **({"traceback": result["traceback"]} if error and result.get("traceback") else {})}
