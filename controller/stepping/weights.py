"""Learned weights on disk: crash-safe ``.npz`` files with a schema version, the project's version
and a checksum, never pickle.

``weights`` is 1-D, one weight per range cell (:class:`controller.stepping.learner.AdaptivePremotor`), or
2-D, one row of cells per height context (:class:`controller.stepping.context.ContextPremotor`).

The format (schema version :data:`SCHEMA_VERSION` = 3) is an uncompressed ``.npz`` (a zip of
``.npy`` arrays, read with ``allow_pickle=False`` always) holding exactly these arrays:

- ``weights``: float64, shape ``(n_cells,)`` or ``(n_contexts, n_cells)`` [s];
- ``cell_width_m``: float64 scalar, the range encoder's cell width [m];
- ``schema_version``: int64 scalar, 3;
- ``project_version``: a unicode scalar (0-d array, no pickle), the version of elegant-stepping
  that wrote the file (:func:`controller.errors.project_version`), for the person reading an
  error about the file and for :func:`read_stored_weights`;
- ``checksum``: a unicode scalar, the SHA-256 (hex) of :func:`checksum`'s canonical encoding
  of (schema version, shape, dtype, cell width, the weight bytes, and from schema 3 the project
  version).

Readers accept schema 3, schema 2 (the same without ``project_version``; its checksum does not
cover one) and legacy schema 1 files (below). Any other schema version is refused with a
:class:`UnknownWeightsVersion` naming the file, the version and, where the file says it, the
elegant-stepping that wrote it. Such a file (a newer program's weights) is intact weights this
version cannot read, so it is kept like a good copy: :func:`resume_weights` sets it aside, and a
save (with ``generations`` >= 2) keeps it as ``<name>.prev`` and rotates it like any good copy.

Saving (:func:`save_weights`) writes a temporary file in the same folder, flushes and fsyncs it,
rotates the older good copies (``generations`` files in all, default 2: ``<name>``, ``<name>.prev``,
then ``<name>.prev2``, ``<name>.prev3``, ...; each older copy moves one place down if it is itself a
valid file, the oldest drops out), keeps the current file (if it is itself valid) as ``<name>.prev``
(hard link to a temporary name, then rename, so the main path always names a complete file),
renames the temporary file over the main path and fsyncs the folder. A process killed at any instant leaves the main path naming
the old file or the new one, never half of one. Stale temporary files (``<name>.<pid>.*.tmp``)
of processes that no longer exist are removed by the next save; loading never writes.

Loading (:func:`load_weights`) raises :class:`WeightsError` naming the file and the reason:
missing, not an ``.npz``, truncated or damaged, an array missing, an unknown schema version, a
checksum mismatch, the wrong shape or cell width for this controller, NaN or infinity.
:func:`load_weights_or_fallback` tries the generations in order (the file, ``<name>.prev``,
``<name>.prev2``, ...), then starts from zeros, logging each failure; it never returns garbage.

:func:`resume_weights` is the daemon's loader: the same order, and a file that is intact but does
not fit this controller (:class:`IncompatibleWeights`: another shape or cell width, i.e. another
configuration's weights, or an unknown schema version) is never left where a save could rotate it
away or write over it: it is renamed aside to ``<name>.incompatible-<UTC timestamp>``
(:func:`set_aside`) and reported.

Legacy files (schema 1: exactly ``weights`` and ``cell_width_m``, written before schema
versions existed, e.g. old ``learn`` output folders) are still loaded, with a logged warning:
they were written by an atomic save, and the zip's CRC-32 of each array still catches damaged
bytes. The next save rewrites them in schema 3. Any other set of arrays (so a damaged array name
never passes for a legacy file) or any other schema version is rejected.
"""

from __future__ import annotations

import functools
import glob
import hashlib
import logging
import os
import secrets
import shutil
import struct
import tempfile
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from controller.atomic import fsync_dir
from controller.errors import project_version as _installed_version

log = logging.getLogger(__name__)

SCHEMA_VERSION = 3
LEGACY_SCHEMA_VERSION = 1  # no schema_version array: weights and cell_width_m only
READ_VERSIONS = (1, 2, 3)
"""The schema versions :func:`read_weights` reads (1: legacy, with a warning)."""
_MAGIC = b"elegant-stepping weights\x00"
_DTYPE = np.dtype("<f8")
_LEGACY_ARRAYS = frozenset({"weights", "cell_width_m"})
_ARRAYS_BY_VERSION = {
    2: frozenset({"weights", "cell_width_m", "schema_version", "checksum"}),
    3: frozenset({"weights", "cell_width_m", "schema_version", "project_version", "checksum"}),
}
_ARRAYS = _ARRAYS_BY_VERSION[SCHEMA_VERSION]


@functools.lru_cache(maxsize=1)
def project_version() -> str:
    """The installed elegant-stepping's version (:func:`controller.errors.project_version`), looked
    up once per process: the lookup costs about 3 ms, more than a save's own work."""
    return _installed_version()


class WeightsError(ValueError):
    """A weights file that is missing, corrupt or does not fit this controller."""


class IncompatibleWeights(WeightsError):
    """An intact weights file that does not fit this controller (shape or cell width)."""


class UnknownWeightsVersion(IncompatibleWeights):
    """A weights file of a schema version this program does not read (a newer program's): intact
    weights, kept like another configuration's (set aside, kept as ``.prev``), never written over."""


@dataclass(frozen=True)
class StoredWeights:
    """What a weights file holds (:func:`read_stored_weights`).

    Attributes:
        weights: float64, shape ``(n_cells,)`` or ``(n_contexts, n_cells)`` [s].
        cell_width_m: the range encoder's cell width [m].
        schema_version: 1 (legacy), 2 or 3.
        project_version: the elegant-stepping that wrote it (schema 3), else None.
    """

    weights: np.ndarray
    cell_width_m: float
    schema_version: int
    project_version: str | None


def prev_path(path: str | Path) -> Path:
    """Where the previous good copy of ``path`` is kept: ``<name>.prev`` beside it."""
    return generation_path(path, 1)


def generation_path(path: str | Path, k: int) -> Path:
    """The ``k``-th good copy of ``path``: 0 the file itself, 1 ``<name>.prev``, k >= 2 ``<name>.prev<k>``."""
    path = Path(path)
    if k < 0:
        raise ValueError(f"generation {k} < 0")
    return path if k == 0 else path.with_name(path.name + (".prev" if k == 1 else f".prev{k}"))


def generation_name(k: int) -> str:
    """The source name of the ``k``-th generation: ``file``, ``prev``, ``prev2``, ..."""
    return "file" if k == 0 else ("prev" if k == 1 else f"prev{k}")


def set_aside(path: str | Path, now: float | None = None) -> Path:
    """Rename ``path`` to ``<name>.incompatible-<UTC timestamp>`` beside it (never over another
    file: ``-1``, ``-2``, ... if that name is taken) and fsync the folder; the new path."""
    import time

    path = Path(path)
    stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime(time.time() if now is None else now))
    target = path.with_name(f"{path.name}.incompatible-{stamp}")
    n = 0
    while target.exists():
        n += 1
        target = path.with_name(f"{path.name}.incompatible-{stamp}-{n}")
    os.rename(path, target)
    fsync_dir(path.parent)
    return target


def checksum(weights: np.ndarray, cell_width_m: float, schema_version: int = SCHEMA_VERSION,
             project_version: str = "") -> str:
    """SHA-256 (hex) of the canonical encoding: a magic string, the schema version, the number of
    dimensions and each dimension (int64 little endian), the dtype (``<f8``), the cell width
    (float64 little endian), the weights (float64 little endian, C order) and, from schema 3, the
    project version (its UTF-8 length as int64 little endian, then its bytes)."""
    w = np.ascontiguousarray(weights, dtype=_DTYPE)
    h = hashlib.sha256(_MAGIC)
    h.update(struct.pack("<qq", int(schema_version), w.ndim))
    h.update(struct.pack(f"<{w.ndim}q", *w.shape))
    h.update(_DTYPE.str.encode("ascii") + b"\x00")
    h.update(struct.pack("<d", float(cell_width_m)))
    h.update(w.tobytes(order="C"))
    if int(schema_version) >= 3:
        text = str(project_version).encode("utf-8")
        h.update(struct.pack("<q", len(text)) + text)
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


def _keep_previous(path: Path) -> None:
    """Make ``<name>.prev`` name the current file (if valid, or of a schema version this program
    does not read) without the main path ever missing."""
    try:
        read_weights(path)
    except UnknownWeightsVersion as exc:
        log.warning("%s; kept as %s", exc, prev_path(path))
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


def _is_valid(path: Path) -> bool:
    """True for a file :func:`read_weights` reads, or one of a schema version it does not (kept)."""
    try:
        read_weights(path)
    except UnknownWeightsVersion:
        return True
    except WeightsError:
        return False
    return True


def _rotate_older(path: Path, generations: int) -> None:
    """Move each valid ``<name>.prev<k-1>`` to ``<name>.prev<k>``, oldest first (k from
    ``generations - 1`` down to 2); an invalid one stays and is overwritten by the next move."""
    for k in range(generations - 1, 1, -1):
        src = generation_path(path, k - 1)
        if src.exists() and _is_valid(src):
            os.replace(src, generation_path(path, k))


def save_weights(path: str | Path, weights: np.ndarray, cell_width_m: float, generations: int = 2) -> None:
    """Write ``weights`` [s] (shape ``(n_cells,)`` or ``(n_contexts, n_cells)``, finite) and the
    cell width [m] to ``path`` atomically, keeping the previous good files: ``generations`` in all
    (default 2: the file and ``<name>.prev``; 3 adds ``<name>.prev2``, ...; 1 keeps none)."""
    generations = int(generations)
    if generations < 1:
        raise ValueError(f"generations must be at least 1, got {generations}")
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
            version = project_version()
            np.savez(f, weights=weights, cell_width_m=np.float64(cell_width_m),
                     schema_version=np.int64(SCHEMA_VERSION), project_version=np.array(version, dtype=np.str_),
                     checksum=np.array(checksum(weights, cell_width_m, SCHEMA_VERSION, version), dtype="U64"))
            f.flush()
            os.fsync(f.fileno())
        if generations >= 2:
            _rotate_older(path, generations)
            _keep_previous(path)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    fsync_dir(path.parent)


# -- loading -----------------------------------------------------------------------------------


def _scalar(data, name: str, path: Path, kind: str):
    a = data[name]
    if a.shape != () or a.dtype.kind not in kind:
        raise WeightsError(f"{path}: {name} is {a.dtype} of shape {a.shape}, expected a scalar")
    return a[()]


def _writer(data, names) -> str:
    """Who wrote a file of an unknown schema version, for the message: its project_version if it
    holds a readable one."""
    try:
        if "project_version" in names:
            a = data["project_version"]
            if a.shape == () and a.dtype.kind == "U":
                return f" (written by elegant-stepping {str(a[()])})"
    except Exception:  # noqa: BLE001 - only for the message: the file is refused anyway
        pass
    return ""


def read_stored_weights(path: str | Path) -> StoredWeights:
    """Everything in the weights file ``path`` (weights [s], cell width [m], schema version,
    project version), checked for integrity (format, schema version, arrays, checksum, dtype,
    finiteness) but not against any controller's shape.

    Raises:
        WeightsError: naming the file and what is wrong; :class:`UnknownWeightsVersion` for a schema
            version other than :data:`READ_VERSIONS`.
    """
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
    stored_sum = stored_project = None
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
                expected = _ARRAYS_BY_VERSION.get(version)
                if version == LEGACY_SCHEMA_VERSION:
                    raise WeightsError(f"{path}: schema version 1 in a schema_version array: a legacy file has "
                                       f"exactly {sorted(_LEGACY_ARRAYS)}, this one {sorted(names)}")
                if expected is None:
                    raise UnknownWeightsVersion(
                        f"{path}: weights schema version {version}{_writer(data, names)} is not one this version of "
                        f"elegant-stepping ({project_version()}) reads ({', '.join(map(str, READ_VERSIONS))}); use a "
                        f"matching elegant-stepping")
                if names != expected:
                    missing, unknown = sorted(expected - names), sorted(names - expected)
                    raise WeightsError(f"{path}: " + (f"array {missing[0]!r} missing" if missing else
                                                      f"unknown arrays {unknown}") +
                                       f" (schema {version} has exactly {sorted(expected)})")
                stored_sum = str(_scalar(data, "checksum", path, "U"))
                if "project_version" in expected:
                    stored_project = str(_scalar(data, "project_version", path, "U"))
            raw = data["weights"]
            width = float(_scalar(data, "cell_width_m", path, "fiu"))
    except WeightsError:
        raise
    except (zipfile.BadZipFile, EOFError) as exc:
        raise WeightsError(f"{path}: not a readable weights file: truncated or damaged .npz archive ({exc})") from None
    except (OSError, ValueError, TypeError, KeyError, MemoryError, NotImplementedError, zipfile.LargeZipFile) as exc:
        raise WeightsError(f"{path}: not a readable weights file ({type(exc).__name__}: {exc})") from None
    if version != LEGACY_SCHEMA_VERSION:
        if raw.dtype != _DTYPE:
            raise WeightsError(f"{path}: weights are {raw.dtype}, schema {version} stores float64")
        if stored_sum != checksum(raw, width, version, stored_project or ""):
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
    return StoredWeights(weights, width, version, stored_project)


def read_weights(path: str | Path) -> tuple[np.ndarray, float]:
    """The weights [s] and cell width [m] in ``path``, checked for integrity (format, schema
    version, checksum, dtype, finiteness) but not against any controller's shape
    (:func:`read_stored_weights` also gives the versions)."""
    stored = read_stored_weights(path)
    return stored.weights, stored.cell_width_m


def load_weights(path: str | Path, n_cells: int, cell_width_m: float, n_contexts: int | None = None) -> np.ndarray:
    """The weights in ``path``, checked for integrity (:func:`read_weights`) and to be
    ``(n_cells,)`` (``n_contexts`` None) or ``(n_contexts, n_cells)``, saved with this cell width [m]."""
    path = Path(path)
    weights, width = read_weights(path)
    if n_contexts is None and weights.shape != (n_cells,):
        raise IncompatibleWeights(f"{path}: {weights.shape} weights, this controller has {n_cells} cells")
    if n_contexts is not None and weights.shape != (n_contexts, n_cells):
        raise IncompatibleWeights(f"{path}: {weights.shape} weights, this controller has {n_contexts} contexts x "
                                  f"{n_cells} cells")
    if not np.isclose(width, cell_width_m):
        raise IncompatibleWeights(f"{path}: cell width {width} m, this controller uses {cell_width_m} m")
    return weights


def load_weights_or_fallback(path: str | Path, n_cells: int, cell_width_m: float,
                             n_contexts: int | None = None, generations: int = 2) -> tuple[np.ndarray, str]:
    """``(weights, source)``: the first of the ``generations`` good copies that loads, in order (the
    file ``"file"``, ``<name>.prev`` ``"prev"``, ``<name>.prev2`` ``"prev2"``, ...), else zeros of the
    controller's shape (``"zeros"``). A file that exists but cannot be used is logged as an error, a
    missing one at info level; starting from zeros is a warning. Never writes."""
    r = resume_weights(path, n_cells, cell_width_m, n_contexts, generations, set_aside_incompatible=False)
    return r.weights, r.source


@dataclass
class Resumed:
    """What :func:`resume_weights` found.

    Attributes:
        weights: the weights to start from (zeros of the controller's shape when no copy loaded).
        source: ``"file"``, ``"prev"``, ``"prev2"``, ... or ``"zeros"``.
        path: the file they came from (None for zeros).
        set_aside: ``(where it was, where it is now, why)`` for each incompatible file renamed aside.
        reasons: why each generation before the one used (or every one, for zeros) was not used.
    """

    weights: np.ndarray
    source: str
    path: Path | None = None
    set_aside: list[tuple[str, str, str]] = field(default_factory=list)
    reasons: list[str] = field(default_factory=list)


def resume_weights(path: str | Path, n_cells: int, cell_width_m: float, n_contexts: int | None = None,
                   generations: int = 3, set_aside_incompatible: bool = True) -> Resumed:
    """The daemon's loader: every generation of ``path`` is read in order (the file, ``.prev``,
    ``.prev2``, ... ``generations`` in all); the first that loads is used. With
    ``set_aside_incompatible``, each generation that is intact but does not fit this controller
    (:class:`IncompatibleWeights`) is renamed aside (:func:`set_aside`), logged at ERROR, and
    listed, so no later save rotates it away or writes over it; then, if none fits, the run
    starts from zeros with nothing left at the generations' names to write over. A damaged file
    is logged at ERROR and left where it is (a save writes over a damaged file only)."""
    shape = (n_cells,) if n_contexts is None else (n_contexts, n_cells)
    out = Resumed(np.zeros(shape), "zeros")
    for k in range(max(1, int(generations))):
        candidate = generation_path(path, k)
        try:
            weights = load_weights(candidate, n_cells, cell_width_m, n_contexts)
        except IncompatibleWeights as exc:
            if set_aside_incompatible:
                try:
                    moved = set_aside(candidate)
                except OSError as err:
                    log.error("weights: %s; and it could not be renamed aside (%s)", exc, err)
                    raise WeightsError(f"{exc}; it could not be renamed aside ({err}), so the daemon will not "
                                       f"run where it could write over it") from None
                log.error("weights: %s: another configuration's weights, kept aside as %s", exc, moved)
                out.set_aside.append((str(candidate), str(moved), str(exc)))
            else:
                log.error("weights: %s", exc)
            if out.path is None:
                out.reasons.append(str(exc))
            continue
        except WeightsError as exc:
            if out.path is None:
                out.reasons.append(str(exc))
            if candidate.exists():
                log.error("weights: %s", exc)
            else:
                log.info("weights: %s", exc)
            continue
        if out.path is None:
            out.weights, out.source, out.path = weights, generation_name(k), candidate
            if k > 0:
                log.warning("weights: loaded the previous good copy %s", candidate)
            if not set_aside_incompatible:
                break  # nothing more to look for
    if out.path is None:
        log.warning("weights: starting from zeros %s (%s)", shape, "; ".join(out.reasons))
    return out


__all__ = ["READ_VERSIONS", "SCHEMA_VERSION", "IncompatibleWeights", "Resumed", "StoredWeights", "UnknownWeightsVersion",
           "WeightsError", "checksum", "generation_name", "generation_path", "load_weights", "load_weights_or_fallback",
           "prev_path", "read_stored_weights", "read_weights", "resume_weights", "save_weights", "set_aside",
           "stale_temporaries"]
