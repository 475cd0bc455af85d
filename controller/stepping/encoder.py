"""The range encoder: distance to the obstacle as one active cell among non-overlapping cells.

Cells of width ``cell_width_m`` tile ``[0, max_range_m)``; a distance activates exactly one
(index ``floor(d / width)``), no distance or one out of range activates none. The learner sees
only the index: it assumes no spatial ordering of the cells (the paper's "no spatial ordering of
units"); the distances are kept only to draw the weights in order (Fig. 4).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from controller.settings.schema import check_settings, setting
from protocol.compiled import interpreted


@interpreted  # a configuration: plain Python even when compiled (protocol.compiled)
@dataclass(frozen=True)
class RangeEncoderConfig:
    """The cells. Narrower cells learn the same map but visit each cell less often, so cells met
    late may never have been trained (see docs/results.md).

    ``max_range_m`` defaults to 28 cells, about three strides of the natural gait beyond the
    take-off window. The paper's robot "makes at most three discrete decisions prior to going over
    the obstacle": farther gates see no cell, so the modulation acts in the last three step cycles
    only. The range sensor itself sees farther, and the range filter tracks the obstacle from there.
    """

    cell_width_m: float = setting(0.04, "m", 0.001, 1.0, "width of one range cell")
    max_range_m: float = setting(1.12, "m", 0.01, 10.0, "the encoded range")

    def __post_init__(self) -> None:
        check_settings(self, "encoder")
        if not self.cell_width_m <= self.max_range_m:
            raise ValueError(f"encoder.cell_width_m must be at most encoder.max_range_m = {self.max_range_m} m, "
                             f"got {self.cell_width_m!r}")

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
