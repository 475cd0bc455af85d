"""Learned weights on disk: ``.npz`` with arrays ``weights`` and ``cell_width_m``, never pickle.

``weights`` is 1-D, one weight per range cell (:class:`controller.learner.AdaptivePremotor`), or
2-D, one row of cells per height context (:class:`controller.context.ContextPremotor`).

Saved atomically (a temporary file in the same folder, fsync, rename), so a reader sees the old
file or the new one, never half of one. Loading checks shape, dtype and finiteness and raises
:class:`WeightsError` with the reason.
"""

from __future__ import annotations

import os
import tempfile
import zipfile
from pathlib import Path

import numpy as np


class WeightsError(ValueError):
    """A weights file that is missing, corrupt or does not fit this controller."""


def save_weights(path: str | Path, weights: np.ndarray, cell_width_m: float) -> None:
    """Write ``weights`` [s] (shape ``(n_cells,)`` or ``(n_contexts, n_cells)``) and the cell width [m]."""
    weights = np.asarray(weights, dtype=np.float64)
    if weights.ndim not in (1, 2) or weights.size == 0:
        raise ValueError(f"weights must be a non-empty 1-D or 2-D array, got shape {weights.shape}")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=path.name + ".", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            np.savez(f, weights=weights, cell_width_m=np.float64(cell_width_m))
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def load_weights(path: str | Path, n_cells: int, cell_width_m: float, n_contexts: int | None = None) -> np.ndarray:
    """The weights in ``path``, checked to be ``(n_cells,)`` (``n_contexts`` None) or
    ``(n_contexts, n_cells)``, finite, and saved with this cell width [m]."""
    path = Path(path)
    if not path.exists():
        raise WeightsError(f"{path}: no such weights file")
    try:
        with np.load(path, allow_pickle=False) as data:
            weights = np.array(data["weights"], dtype=np.float64)
            width = float(data["cell_width_m"])
    except (OSError, ValueError, KeyError, zipfile.BadZipFile, EOFError) as exc:
        raise WeightsError(f"{path}: not a readable weights file ({exc})") from None
    if n_contexts is None and weights.shape != (n_cells,):
        raise WeightsError(f"{path}: {weights.shape} weights, this controller has {n_cells} cells")
    if n_contexts is not None and weights.shape != (n_contexts, n_cells):
        raise WeightsError(f"{path}: {weights.shape} weights, this controller has {n_contexts} contexts x "
                           f"{n_cells} cells")
    if not np.isclose(width, cell_width_m):
        raise WeightsError(f"{path}: cell width {width} m, this controller uses {cell_width_m} m")
    if not np.all(np.isfinite(weights)):
        raise WeightsError(f"{path}: weights contain NaN or infinity")
    return weights
