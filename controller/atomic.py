"""Atomic file writes: a reader sees the old file or the new one, never half of one.

The one writer of text and JSON files for the whole project (configuration files, metrics,
records summaries, sweep cells, fault-matrix rows). The text goes to a temporary file in the same
folder with a name unique to this process and call (so two writers never meet on one temporary
file), is flushed and fsynced, then renamed over the destination; the folder is fsynced so the
rename survives a power cut. A failure removes the temporary file and re-raises. The new file keeps
the mode of the file it replaces, or is 0644 (``mkstemp``'s 0600 would hide metrics and
configurations from the other users of a shared machine; :func:`file_mode`).

The learned weights have their own writer (:func:`controller.stepping.weights.save_weights`),
which also keeps the previous good file as ``.prev``.
"""

from __future__ import annotations

import json
import os
import stat
import tempfile
from pathlib import Path
from typing import Any


def fsync_dir(folder: str | os.PathLike) -> None:
    """Make a rename in ``folder`` durable (a no-op where directories cannot be opened)."""
    try:
        fd = os.open(folder, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
    except OSError:
        return  # a platform without directory fds: the rename is as durable as it gets
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def file_mode(path: str | os.PathLike, default: int = 0o644) -> int:
    """The permission bits a file written over ``path`` gets: those of the file there, else ``default``."""
    try:
        return stat.S_IMODE(os.stat(path).st_mode)
    except OSError:
        return default


def write_text_atomic(path: str | os.PathLike, text: str) -> Path:
    """Write ``text`` to ``path`` atomically (UTF-8); the folder must exist. Returns the path."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.{os.getpid()}.", suffix=".tmp", dir=path.parent)
    try:
        os.fchmod(fd, file_mode(path))
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    fsync_dir(path.parent)
    return path


def write_json_atomic(path: str | os.PathLike, data: Any, indent: int | None = 2) -> Path:
    """Write ``data`` as JSON (with a final newline) to ``path`` atomically. Returns the path."""
    return write_text_atomic(path, json.dumps(data, indent=indent) + "\n")
