"""A run folder's append-only trial record and its writer's lock.

**The record** (``DIR/trials.jsonl``, JSON Lines). Line 1 is a header,
``{"format": "learn-trials", "format_version": 1, "project_version": ..., "config": {...}}``
(the run's configuration as ``dataclasses.asdict`` gives it, after a JSON round trip); every
further line is one finished trial's record, in order, trial ``k`` on line ``k + 2``. The file is
created with its header atomically (a temporary file renamed into place), so it always has a
complete header. Each trial is appended as one ``write`` of the whole line (newline included),
then flushed and fsynced before the next trial starts; SIGINT and SIGTERM are held back during
the append (and delivered right after it), so a signal never tears a line. What can still tear a line is a
``kill -9`` or a power cut in the middle of the write: on reading, a last line that has no final
newline or does not parse is dropped (with a logged warning) and the next append first cuts the
file back to its last complete line. A damaged line *before* the last is not a torn append but a
damaged file: :class:`controller.errors.InputError` naming the file and the line number.

**The lock** (``DIR/.lock``): :class:`FolderLock` takes ``fcntl.flock(LOCK_EX | LOCK_NB)`` on it
for as long as a run writes the folder, so a second ``learn`` or a sweep's cell into the same
folder is refused at once (:class:`FolderBusy`, an ``InputError``, exit 3) instead of two
writers meeting in one file. The kernel drops the lock when the process dies, however it dies,
so a killed run never leaves the folder locked; the empty ``.lock`` file stays (it is part of a
run folder, see :data:`RUN_FILES`).

May import: the standard library and :mod:`controller` only.
"""

from __future__ import annotations

import json
import logging
import os
import signal
import tempfile
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from controller.atomic import write_text_atomic
from controller.errors import InputError, check_stamp, stamp

log = logging.getLogger(__name__)

TRIALS_FILE = "trials.jsonl"
LOCK_FILE = ".lock"
TRIALS_FORMAT = "learn-trials"
TRIALS_VERSION = 1


class FolderBusy(InputError):
    """The folder is locked by another run that is writing it (exit 3)."""


class FolderLock:
    """An exclusive, non-blocking ``flock`` on ``DIR/.lock`` held while a run writes ``DIR``.

    Use as a context manager; ``what`` names the folder in the refusal (``--out DIR``, a cell).
    Raises :class:`FolderBusy` when another process (or another open of the lock in this one)
    holds it.
    """

    def __init__(self, folder: str | Path, what: str | None = None) -> None:
        self.folder = Path(folder)
        self.what = what or str(self.folder)
        self._fd: int | None = None

    def acquire(self) -> "FolderLock":
        import fcntl

        fd = os.open(self.folder / LOCK_FILE, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            raise FolderBusy(f"{self.what}: another run is writing this folder (it holds {self.folder / LOCK_FILE}); "
                             f"wait for it to finish or stop it, then run again") from None
        except BaseException:
            os.close(fd)
            raise
        self._fd = fd
        return self

    def release(self) -> None:
        if self._fd is not None:
            os.close(self._fd)  # closing the only descriptor drops the flock
            self._fd = None

    def __enter__(self) -> "FolderLock":
        return self.acquire()

    def __exit__(self, *exc: object) -> None:
        self.release()


def is_locked(folder: str | Path) -> bool:
    """Whether another holder has ``folder``'s lock now (a folder without a lock file is not locked)."""
    import fcntl

    path = Path(folder) / LOCK_FILE
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return True
    finally:
        os.close(fd)  # also drops the lock if we got it
    return False


class _SignalsHeld:
    """Hold SIGINT and SIGTERM back for the duration of an append, then deliver them.

    Python runs signal handlers in the main thread, whichever thread the kernel hands the signal
    to, so a mask (``pthread_sigmask``) would not hold them while other threads exist: the
    handlers are swapped for a recorder instead, and each recorded signal is raised again once
    the original handlers are back. Outside the main thread (where handlers cannot be set, and
    where Python never runs them) this does nothing."""

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __enter__(self) -> None:
        self._old: dict[int, Any] = {}
        self._seen: list[int] = []
        if threading.current_thread() is threading.main_thread():
            for sig in self.SIGNALS:
                if signal.getsignal(sig) is not None:  # None: a handler not set from Python, left alone
                    self._old[sig] = signal.signal(sig, lambda signum, frame: self._seen.append(signum))

    def __exit__(self, *exc: object) -> None:
        for sig, handler in self._old.items():
            signal.signal(sig, handler)
        for sig in dict.fromkeys(self._seen):
            signal.raise_signal(sig)  # now handled as it would have been


def _canonical(x: Any) -> Any:
    """``x`` as a JSON round trip gives it back (tuples become lists)."""
    return json.loads(json.dumps(x))


@dataclass
class Journal:
    """What a ``trials.jsonl`` holds: its header's configuration, the complete trial records, and
    where the last complete line ends (``good_bytes``; anything after it is a torn append)."""

    path: Path
    version: int
    config: dict[str, Any]
    records: list[dict[str, Any]]
    good_bytes: int
    torn: bool


def read_journal(path: str | Path) -> Journal:
    """Read ``path`` (see the module docstring): the header and every complete trial record.

    Raises:
        InputError: the header is not a learn-trials header of a known version, a line before the
            last is damaged, or a record is not the next trial's (its ``index``).
    """
    path = Path(path)
    data = path.read_bytes()
    lines = data.split(b"\n")
    tail = lines.pop()  # b"" when the file ends with a newline, else an unterminated (torn) line
    torn = bool(tail)
    parsed: list[Any] = []
    for n, raw in enumerate(lines, start=1):
        try:
            parsed.append(json.loads(raw))
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            if n == len(lines) and not torn:
                torn = True  # a last line that does not parse: a torn append, dropped below
                break
            raise InputError(f"{path}: line {n} is damaged ({type(exc).__name__}: {exc}); the trial record is "
                             f"not an append-only record this version wrote") from None
    good_bytes = sum(len(raw) + 1 for raw in lines[:len(parsed)])
    if torn:
        log.warning("%s: the last line is incomplete (a write stopped mid-line); dropping it", path)
    if not parsed:
        raise InputError(f"{path}: no header line (not a learn run's trial record)")
    header = parsed[0]
    version = check_stamp(header, TRIALS_FORMAT, (TRIALS_VERSION,), str(path))
    if not isinstance(header.get("config"), dict):
        raise InputError(f"{path}: line 1 has no 'config' object (not a learn run's trial record)")
    records = parsed[1:]
    for k, record in enumerate(records):
        if not isinstance(record, dict) or record.get("index") != k or not isinstance(record.get("success"), bool):
            raise InputError(f"{path}: line {k + 2} is not trial {k}'s record (an 'index' {k} and a 'success' "
                             f"flag expected)")
    return Journal(path, version, header["config"], records, good_bytes, torn)


class JournalWriter:
    """Appends trial records to ``trials.jsonl``: one line each, flushed and fsynced."""

    def __init__(self, path: Path, keep_bytes: int | None = None) -> None:
        self.path = path
        self.appended = 0  # records this writer made durable (a signal held during an append is raised after it)
        self._f = open(path, "r+b")
        if keep_bytes is not None:
            self._f.truncate(keep_bytes)  # cut a torn last line before the next append
            os.fsync(self._f.fileno())
        self._f.seek(0, os.SEEK_END)

    @classmethod
    def create(cls, path: str | Path, config: dict[str, Any]) -> "JournalWriter":
        """A new record at ``path`` with its header (written atomically: never a file without one)."""
        path = Path(path)
        header = {**stamp(TRIALS_FORMAT, TRIALS_VERSION), "config": _canonical(config)}
        write_text_atomic(path, json.dumps(header) + "\n")  # the header whole, or no file
        return cls(path)

    def append(self, record: dict[str, Any]) -> None:
        line = (json.dumps(record) + "\n").encode()
        with _SignalsHeld():
            self._f.write(line)
            self._f.flush()
            os.fsync(self._f.fileno())
            self.appended += 1

    def close(self) -> None:
        self._f.close()

    def __enter__(self) -> "JournalWriter":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


__all__ = ["FolderBusy", "FolderLock", "Journal", "JournalWriter", "LOCK_FILE", "TRIALS_FILE", "is_locked",
           "read_journal"]


def prepare_folder(path: str | Path | None, what: str = "--out", create: bool = True) -> Path:
    """Check that ``path`` can be an output folder and create it (with its parents; with
    ``create`` False, only check what can be checked without writing), before any work starts;
    the folder.

    Raises:
        InputError: an empty path, a path that is a file or lies under a file, or a folder that
            cannot be created or written here; the message names ``what`` and the path.
    """
    if path is None or not str(path).strip():
        raise InputError(f"{what}: an empty path; give a folder (e.g. {what} runs/seed0)")
    out = Path(path)
    if out.exists() and not out.is_dir():
        raise InputError(f"{what} {out}: is a file, not a folder")
    for parent in out.parents:
        if parent.exists():
            if not parent.is_dir():
                raise InputError(f"{what} {out}: {parent} is a file, so no folder can be made under it")
            if not create and not os.access(out if out.exists() else parent, os.W_OK | os.X_OK):
                raise InputError(f"{what} {out}: {out if out.exists() else parent} is not writable")
            break
    if not create:
        return out
    try:
        out.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(prefix=".write-test.", dir=out)
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        raise InputError(f"{what} {out}: cannot be written here ({exc.strerror or exc})") from None
    return out
