"""The range encoder: distance to the obstacle as one active cell among non-overlapping cells.

Cells of width ``cell_width_m`` tile ``[0, max_range_m)``; a distance activates exactly one
(index ``floor(d / width)``), no distance or one out of range activates none. The learner sees
only the index: it assumes no spatial ordering of the cells (the paper's "no spatial ordering of
units"); the distances are kept only to draw the weights in order (Fig. 4).
"""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class RangeEncoderConfig:
    """Attributes:
    cell_width_m: width of one cell [m]; default 0.04. Narrower cells
        learn the same map but visit each cell less often: with 3 cm cells, late trials met
        cells that had never been trained; see the README's learning section.
    max_range_m: the encoded range [m]; default 1.12 (28 cells), about three strides of the
        natural gait (0.36 m) beyond the take-off window. The paper's robot "makes at most three
        discrete decisions prior to going over the obstacle": farther gates see no cell, so the
        modulation acts in the last three step cycles only. The range sensor itself sees 3 m,
        and the range filter tracks the obstacle from there on.
    """

    cell_width_m: float = 0.04
    max_range_m: float = 1.12

    def __post_init__(self) -> None:
        if not (0.001 <= self.cell_width_m <= self.max_range_m):
            raise ValueError(f"encoder.cell_width_m must be in [0.001, {self.max_range_m}] m, got {self.cell_width_m}")

    @property
    def n_cells(self) -> int:
        return int(math.ceil(self.max_range_m / self.cell_width_m - 1e-9))


class RangeEncoder:
    def __init__(self, config: RangeEncoderConfig = RangeEncoderConfig()) -> None:
        self.config = config
        self.n_cells = config.n_cells

    def cell(self, distance_m: float | None) -> int | None:
        """Index of the active cell, or None."""
        if distance_m is None or not math.isfinite(distance_m) or distance_m < 0.0:
            return None
        if distance_m >= self.config.max_range_m:
            return None
        index = int(distance_m / self.config.cell_width_m)
        return index if index < self.n_cells else None
