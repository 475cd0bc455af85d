"""Size-bounded output files for the daemon: its records (JSON lines) and its ticks (binary).

:class:`RotatingFile` writes to ``FILE``; once ``FILE`` has reached ``max_bytes`` it is renamed
``FILE.1`` (``FILE.1`` to ``FILE.2``, ... up to ``FILE.<keep>``; the oldest beyond ``keep`` is
dropped) and a new ``FILE`` is begun, so the disk holds at most about ``(keep + 1) * max_bytes``.
``FILE`` is always the newest: whatever reads a single file (replay reads ``controller.jsonl`` and
``controller.ticks``) reads the latest part. A rotation happens only between whole writes (a record
line, a block of whole tick pairs), and a new file begins with the ``header`` the caller gives
(the records' clock line and current phase), so each file reads on its own. With
``rotate_at_start`` an existing non-empty ``FILE`` is rotated instead of overwritten when the file is
opened (a restarted daemon keeps the records of the run before it, e.g. of a crash).
``max_bytes`` None: one file, never rotated (the harness's runs), overwritten at open.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Callable, Iterable


def rotated_path(path: Path, k: int) -> Path:
    return path if k == 0 else path.with_name(f"{path.name}.{k}")


class RotatingFile:
    def __init__(self, path: str | os.PathLike, max_bytes: int | None = None, keep: int = 3, binary: bool = False,
                 header: Callable[[], Iterable[str]] | None = None, rotate_at_start: bool = False) -> None:
        if max_bytes is not None and max_bytes <= 0:
            raise ValueError(f"max_bytes must be positive, got {max_bytes}")
        if keep < 0:
            raise ValueError(f"keep must be 0 or more, got {keep}")
        self.path = Path(path)
        self.max_bytes = max_bytes
        self.keep = keep
        self.binary = binary
        self.header = header
        self.rotations = 0
        if max_bytes is not None and rotate_at_start:
            try:
                if self.path.stat().st_size > 0:
                    self._shift()
            except FileNotFoundError:
                pass
        self.f = self._open()
        self.size = 0

    def _open(self):
        return open(self.path, "wb") if self.binary else open(self.path, "w", buffering=1 << 16)

    def _shift(self) -> None:
        for k in range(self.keep, 0, -1):
            src = rotated_path(self.path, k - 1)
            if src.exists():
                os.replace(src, rotated_path(self.path, k))
        if self.keep == 0:
            self.path.unlink(missing_ok=True)
        self.rotations += 1

    def rotate(self) -> None:
        """Close ``FILE``, shift the old ones, begin a new ``FILE`` with the header."""
        self.f.close()
        self._shift()
        self.f = self._open()
        self.size = 0
        if self.header is not None:
            for line in self.header():
                self._put(line)

    def _put(self, data) -> None:
        self.f.write(data)
        self.size += len(data)

    def write(self, data) -> None:
        """One whole record (a str line, or bytes); rotates first when ``FILE`` is full."""
        if self.f is None:
            return
        if self.max_bytes is not None and self.size >= self.max_bytes:
            self.rotate()
        self._put(data)

    def write_array(self, arr) -> None:
        """An ``array.array`` of whole records (binary files)."""
        if self.f is None:
            return
        if self.max_bytes is not None and self.size >= self.max_bytes:
            self.rotate()
        arr.tofile(self.f)
        self.size += len(arr) * arr.itemsize

    def flush(self) -> None:
        if self.f is not None:
            self.f.flush()

    def close(self) -> None:
        if self.f is not None:
            self.f.close()
            self.f = None


__all__ = ["RotatingFile", "rotated_path"]
