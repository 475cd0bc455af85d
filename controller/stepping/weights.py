"""Learned weights on disk: crash-safe ``.npz`` files with a schema version and a checksum, never pickle.

``weights`` is 1-D, one weight per range cell (:class:`controller.stepping.learner.AdaptivePremotor`), or
2-D, one row of cells per height context (:class:`controller.stepping.context.ContextPremotor`).

The format (schema version :data:`SCHEMA_VERSION` = 2) is an uncompressed ``.npz`` (a zip of
``.npy`` arrays, read with ``allow_pickle=False`` always) holding exactly these arrays:

- ``weights``: float64, shape ``(n_cells,)`` or ``(n_contexts, n_cells)`` [s];
- ``cell_width_m``: float64 scalar, the range encoder's cell width [m];
- ``schema_version``: int64 scalar, 2;
- ``checksum``: a unicode scalar, the SHA-256 (hex) of :func:`checksum`'s canonical encoding
  of (schema version, shape, dtype, cell width, the weight bytes).

Saving (:func:`save_weights`) writes a temporary file in the same folder, flushes and fsyncs it,
keeps the current file (if it is itself valid) as ``<name>.prev`` (hard link to a temporary name,
then rename, so the main path always names a complete file), renames the temporary file over
the main path and fsyncs the folder. A process killed at any instant leaves the main path naming
the old file or the new one, never half of one. Stale temporary files (``<name>.<pid>.*.tmp``)
of processes that no longer exist are removed by the next save; loading never writes.

Loading (:func:`load_weights`) raises :class:`WeightsError` naming the file and the reason:
missing, not an ``.npz``, truncated or damaged, an array missing, an unknown schema version, a
checksum mismatch, the wrong shape or cell width for this controller, NaN or infinity.
:func:`load_weights_or_fallback` tries the file, then ``<name>.prev``, then starts from zeros,
logging each failure; it never returns garbage.

Legacy files (schema 1: exactly ``weights`` and ``cell_width_m``, written before schema
versions existed, e.g. old ``learn`` output folders) are still loaded, with a logged warning:
they were written by an atomic save, and the zip's CRC-32 of each array still catches damaged
bytes. The next save rewrites them in schema 2. Any other set of arrays (so a damaged array name
never passes for a legacy file) or any other schema version is rejected.
"""

from __future__ import annotations

import glob
import hashlib
import logging
import os
import secrets
import shutil
import struct
import tempfile
import zipfile
from pathlib import Path

import numpy as np

log = logging.getLogger(__name__)

SCHEMA_VERSION = 2
LEGACY_SCHEMA_VERSION = 1  # no schema_version array: weights and cell_width_m only
_MAGIC = b"elegant-stepping weights\x00"
_DTYPE = np.dtype("<f8")
_ARRAYS = {"weights", "cell_width_m", "schema_version", "checksum"}
_LEGACY_ARRAYS = {"weights", "cell_width_m"}


class WeightsError(ValueError):
    """A weights file that is missing, corrupt or does not fit this controller."""


def prev_path(path: str | Path) -> Path:
    """Where the previous good copy of ``path`` is kept: ``<name>.prev`` beside it."""
    path = Path(path)
    return path.with_name(path.name + ".prev")


def checksum(weights: np.ndarray, cell_width_m: float, schema_version: int = SCHEMA_VERSION) -> str:
    """SHA-256 (hex) of the canonical encoding: a magic string, the schema version, the number of
    dimensions and each dimension (int64 little endian), the dtype (``<f8``), the cell width
    (float64 little endian) and the weights (float64 little endian, C order)."""
    w = np.ascontiguousarray(weights, dtype=_DTYPE)
    h = hashlib.sha256(_MAGIC)
    h.update(struct.pack("<qq", int(schema_version), w.ndim))
    h.update(struct.pack(f"<{w.ndim}q", *w.shape))
    h.update(_DTYPE.str.encode("ascii") + b"\x00")
    h.update(struct.pack("<d", float(cell_width_m)))
    h.update(w.tobytes(order="C"))
    return h.hexdigest()


# -- saving ------------------------------------------------------------------------------------


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True  # someone else's process
    return True


def stale_temporaries(path: str | Path) -> list[Path]:
    """Temporary files of saves to ``path`` by processes that no longer exist (killed mid-save)."""
    path = Path(path)
    stale = []
    for name in glob.glob(glob.escape(str(path)) + ".*.tmp"):
        field = Path(name).name[len(path.name) + 1 :].split(".", 1)[0]
        if field.isdigit() and int(field) != os.getpid() and not _pid_alive(int(field)):
            stale.append(Path(name))
    return stale


def _fsync_dir(folder: Path) -> None:
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


def _keep_previous(path: Path) -> None:
    """Make ``<name>.prev`` name the current file (if valid) without the main path ever missing."""
    try:
        read_weights(path)
    except WeightsError as exc:
        if path.exists():
            log.warning("%s is not a valid weights file, so %s is left as it is (%s)", path, prev_path(path), exc)
        return
    link = path.with_name(f"{path.name}.{os.getpid()}.{secrets.token_hex(4)}.link.tmp")
    try:
        try:
            os.link(path, link)
        except OSError:  # a file system without hard links: a copy, made durable before the rename
            shutil.copyfile(path, link)
            with open(link, "rb+") as f:
                os.fsync(f.fileno())
        os.replace(link, prev_path(path))
    except BaseException:
        link.unlink(missing_ok=True)
        raise


def save_weights(path: str | Path, weights: np.ndarray, cell_width_m: float) -> None:
    """Write ``weights`` [s] (shape ``(n_cells,)`` or ``(n_contexts, n_cells)``, finite) and the
    cell width [m] to ``path`` atomically, keeping the previous good file as ``<name>.prev``."""
    weights = np.array(weights, dtype=_DTYPE)
    if weights.ndim not in (1, 2) or weights.size == 0:
        raise ValueError(f"weights must be a non-empty 1-D or 2-D array, got shape {weights.shape}")
    if not np.all(np.isfinite(weights)):
        raise ValueError("weights contain NaN or infinity: not saved")
    cell_width_m = float(cell_width_m)
    if not (np.isfinite(cell_width_m) and cell_width_m > 0):
        raise ValueError(f"cell_width_m must be positive, got {cell_width_m!r}")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    for stale in stale_temporaries(path):
        stale.unlink(missing_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f"{path.name}.{os.getpid()}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            np.savez(f, weights=weights, cell_width_m=np.float64(cell_width_m),
                     schema_version=np.int64(SCHEMA_VERSION),
                     checksum=np.array(checksum(weights, cell_width_m), dtype="U64"))
            f.flush()
            os.fsync(f.fileno())
        _keep_previous(path)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    _fsync_dir(path.parent)


# -- loading -----------------------------------------------------------------------------------


def _scalar(data, name: str, path: Path, kind: str):
    a = data[name]
    if a.shape != () or a.dtype.kind not in kind:
        raise WeightsError(f"{path}: {name} is {a.dtype} of shape {a.shape}, expected a scalar")
    return a[()]


def read_weights(path: str | Path) -> tuple[np.ndarray, float]:
    """The weights [s] and cell width [m] in ``path``, checked for integrity (format, schema
    version, checksum, dtype, finiteness) but not against any controller's shape."""
    path = Path(path)
    if not path.exists():
        raise WeightsError(f"{path}: no such weights file")
    try:
        with open(path, "rb") as f:
            head = f.read(4)
    except OSError as exc:
        raise WeightsError(f"{path}: cannot be read ({exc})") from None
    if head != b"PK\x03\x04":
        raise WeightsError(f"{path}: not a readable weights file: " + ("empty" if not head else "not an .npz archive"))
    try:
        with np.load(path, allow_pickle=False) as data:
            names = set(data.files)
            for name in ("weights", "cell_width_m"):
                if name not in names:
                    raise WeightsError(f"{path}: array {name!r} missing (the file has {sorted(names)})")
            if names == _LEGACY_ARRAYS:
                version = LEGACY_SCHEMA_VERSION
            else:
                if "schema_version" not in names:  # e.g. a damaged name in the zip's directory
                    raise WeightsError(f"{path}: array 'schema_version' missing (the file has {sorted(names)})")
                version = int(_scalar(data, "schema_version", path, "iu"))
                if version != SCHEMA_VERSION:
                    raise WeightsError(f"{path}: schema version {version}, this controller reads version "
                                       f"{SCHEMA_VERSION} (and legacy files without one)")
                if names != _ARRAYS:
                    missing, unknown = sorted(_ARRAYS - names), sorted(names - _ARRAYS)
                    raise WeightsError(f"{path}: " + (f"array {missing[0]!r} missing" if missing else
                                                      f"unknown arrays {unknown}") +
                                       f" (schema {SCHEMA_VERSION} has exactly {sorted(_ARRAYS)})")
                stored_sum = str(_scalar(data, "checksum", path, "U"))
            raw = data["weights"]
            width = float(_scalar(data, "cell_width_m", path, "fiu"))
    except WeightsError:
        raise
    except (zipfile.BadZipFile, EOFError) as exc:
        raise WeightsError(f"{path}: not a readable weights file: truncated or damaged .npz archive ({exc})") from None
    except (OSError, ValueError, TypeError, KeyError, MemoryError, NotImplementedError, zipfile.LargeZipFile) as exc:
        raise WeightsError(f"{path}: not a readable weights file ({type(exc).__name__}: {exc})") from None
    if version == SCHEMA_VERSION:
        if raw.dtype != _DTYPE:
            raise WeightsError(f"{path}: weights are {raw.dtype}, schema {SCHEMA_VERSION} stores float64")
        if stored_sum != checksum(raw, width, version):
            raise WeightsError(f"{path}: checksum mismatch (the file is damaged or was not written by save_weights)")
    else:
        if raw.dtype.kind not in "fiu":
            raise WeightsError(f"{path}: weights are {raw.dtype}, expected numbers")
        log.warning("%s: legacy weights file (schema %d, no version or checksum); loading it, the next save "
                    "rewrites it in schema %d", path, LEGACY_SCHEMA_VERSION, SCHEMA_VERSION)
    weights = np.array(raw, dtype=np.float64)
    if weights.ndim not in (1, 2) or weights.size == 0:
        raise WeightsError(f"{path}: weights of shape {weights.shape}, expected a non-empty 1-D or 2-D array")
    if not np.all(np.isfinite(weights)):
        raise WeightsError(f"{path}: weights contain NaN or infinity")
    if not (np.isfinite(width) and width > 0):
        raise WeightsError(f"{path}: cell width {width} m is not positive")
    return weights, width


def load_weights(path: str | Path, n_cells: int, cell_width_m: float, n_contexts: int | None = None) -> np.ndarray:
    """The weights in ``path``, checked for integrity (:func:`read_weights`) and to be
    ``(n_cells,)`` (``n_contexts`` None) or ``(n_contexts, n_cells)``, saved with this cell width [m]."""
    path = Path(path)
    weights, width = read_weights(path)
    if n_contexts is None and weights.shape != (n_cells,):
        raise WeightsError(f"{path}: {weights.shape} weights, this controller has {n_cells} cells")
    if n_contexts is not None and weights.shape != (n_contexts, n_cells):
        raise WeightsError(f"{path}: {weights.shape} weights, this controller has {n_contexts} contexts x "
                           f"{n_cells} cells")
    if not np.isclose(width, cell_width_m):
        raise WeightsError(f"{path}: cell width {width} m, this controller uses {cell_width_m} m")
    return weights


def load_weights_or_fallback(path: str | Path, n_cells: int, cell_width_m: float,
                             n_contexts: int | None = None) -> tuple[np.ndarray, str]:
    """``(weights, source)``: the weights in ``path`` (source ``"file"``), else in ``<name>.prev``
    (``"prev"``), else zeros of the controller's shape (``"zeros"``). A file that exists but cannot
    be used is logged as an error, a missing one at info level; starting from zeros is a warning."""
    shape = (n_cells,) if n_contexts is None else (n_contexts, n_cells)
    reasons = []
    for candidate, source in ((Path(path), "file"), (prev_path(path), "prev")):
        try:
            weights = load_weights(candidate, n_cells, cell_width_m, n_contexts)
        except WeightsError as exc:
            reasons.append(str(exc))
            if candidate.exists():
                log.error("weights: %s", exc)
            else:
                log.info("weights: %s", exc)
            continue
        if source == "prev":
            log.warning("weights: loaded the previous good copy %s", candidate)
        return weights, source
    log.warning("weights: starting from zeros %s (%s)", shape, "; ".join(reasons))
    return np.zeros(shape), "zeros"


__all__ = ["SCHEMA_VERSION", "WeightsError", "checksum", "load_weights", "load_weights_or_fallback", "prev_path",
           "read_weights", "save_weights", "stale_temporaries"]
