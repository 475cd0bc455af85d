"""Learned weights on disk: ``.npz`` with arrays ``weights`` and ``cell_width_m``, never pickle.

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
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=path.name + ".", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            np.savez(f, weights=np.asarray(weights, dtype=np.float64), cell_width_m=np.float64(cell_width_m))
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def load_weights(path: str | Path, n_cells: int, cell_width_m: float) -> np.ndarray:
    path = Path(path)
    if not path.exists():
        raise WeightsError(f"{path}: no such weights file")
    try:
        with np.load(path, allow_pickle=False) as data:
            weights = np.array(data["weights"], dtype=np.float64)
            width = float(data["cell_width_m"])
    except (OSError, ValueError, KeyError, zipfile.BadZipFile, EOFError) as exc:
        raise WeightsError(f"{path}: not a readable weights file ({exc})") from None
    if weights.shape != (n_cells,):
        raise WeightsError(f"{path}: {weights.shape} weights, this controller has {n_cells} cells")
    if not np.isclose(width, cell_width_m):
        raise WeightsError(f"{path}: cell width {width} m, this controller uses {cell_width_m} m")
    if not np.all(np.isfinite(weights)):
        raise WeightsError(f"{path}: weights contain NaN or infinity")
    return weights
