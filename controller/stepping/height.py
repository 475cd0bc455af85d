"""The obstacle's height, as the controller can tell it: a context index from the range profile.

The sensor board's profile (SB_Profile) is a few horizontal beams at fixed heights above the
ground, lowest first. An obstacle of height H stops every beam below H and none above it, so the
number of beams that see *the target* (the thing the range filter tracks) is a height bin:
context k means the obstacle is taller than beam k-1 and lower than beam k (0: lower than the
lowest beam, ``n_beams``: taller than the highest).

A beam sees the target when its reading lies within ``match_tolerance_m`` of the filtered range
(the ray and the beams start at the same boom and meet the obstacle's near face at the same
distance, to well under a millimetre at these heights). Each profile sample casts one vote per
beam (on the target or not); a beam counts as seeing the target when it did in at least
``seen_fraction`` of the last ``window`` samples (a majority per beam, so independent dropouts
of a sizeable fraction of the samples do not change the count), and the context is the number of
such beams. The votes are cleared when the target leaves view (the filter withdraws its estimate)
and when the filtered range jumps by more than ``jump_m`` between two samples (a new target: the
filter re-acquired). With no votes the context is None (unknown).

The estimator never sees the scenario: only the profile frames and the filtered range.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

from controller.settings.schema import check_settings, setting
from protocol.compiled import interpreted


def _increasing(heights: tuple[float, ...]) -> str | None:
    if any(b <= a for a, b in zip(heights, heights[1:])):
        return "must be strictly increasing (lowest beam first) [m]"
    return None


@interpreted  # a configuration: plain Python even when compiled (protocol.compiled)
@dataclass(frozen=True)
class HeightEstimatorConfig:
    """The estimator.

    ``beam_heights_m`` are the beams as mounted on the rig (Beam_0 upward). Only their number
    matters to the context; the heights say what each context means
    (:meth:`HeightEstimator.bounds_m`). The default ``match_tolerance_m`` is 5 standard deviations
    of the range reading noise; the default ``window`` holds the last 0.2 s of profile samples
    (50 Hz); a ``seen_fraction`` of 0.5 is a majority, a tie counting as seen; the default
    ``jump_m`` is far more than the carriage covers between two samples.
    """

    beam_heights_m: tuple[float, ...] = setting((0.05, 0.09, 0.13), "m", 0.001, 0.5,
                                                "profile beam heights, lowest first", items=(1, 8),
                                                check=_increasing)
    match_tolerance_m: float = setting(0.10, "m", 0.001, 1.0, "a beam sees the target within this of the range")
    window: int = setting(10, "samples", 1, 1000, "profile samples voted over")
    seen_fraction: float = setting(0.5, "(fraction of samples)", 0.01, 1.0, "a beam sees the target this often")
    jump_m: float = setting(0.30, "m", 0.001, 10.0, "a range jump this large clears the votes")

    def __post_init__(self) -> None:
        check_settings(self, "height")

    @property
    def n_contexts(self) -> int:
        """Number of context indices: 0 .. number of beams."""
        return len(self.beam_heights_m) + 1


class HeightEstimator:
    """Context index (height bin) of the target in view, from profile samples and the filtered range.

    ``samples``: profile samples offered; ``votes``: those that voted (a target was in view).
    """

    def __init__(self, config: HeightEstimatorConfig = HeightEstimatorConfig()) -> None:
        self.config = config
        self.n_contexts = config.n_contexts
        self._n_beams = len(config.beam_heights_m)
        self._votes: deque[tuple[bool, ...]] = deque(maxlen=config.window)
        self._last_range_m = math.nan
        self.samples = 0
        self.votes = 0

    def clear(self) -> None:
        """Forget the votes (no target in view)."""
        self._votes.clear()
        self._last_range_m = math.nan

    def beams_on_target(self, profile_m: tuple[float | None, ...], range_m: float) -> tuple[bool, ...]:
        """For each configured beam (lowest first): does it read within the tolerance of ``range_m``?
        Beams missing from a short profile read nothing."""
        tol = self.config.match_tolerance_m
        padded = tuple(profile_m[: self._n_beams]) + (None,) * max(0, self._n_beams - len(profile_m))
        return tuple(d is not None and abs(d - range_m) <= tol for d in padded)

    def update(self, profile_m: tuple[float | None, ...], range_m: float | None) -> None:
        """One profile sample (distances [m] lowest beam first, None: no return) with the filtered
        range at that moment (None: no target in view, which clears the votes)."""
        self.samples += 1
        if range_m is None or not math.isfinite(range_m):
            self.clear()
            return
        if not math.isnan(self._last_range_m) and abs(range_m - self._last_range_m) > self.config.jump_m:
            self._votes.clear()
        self._last_range_m = range_m
        self._votes.append(self.beams_on_target(profile_m, range_m))
        self.votes += 1

    @property
    def context(self) -> int | None:
        """The number of beams that saw the target in at least ``seen_fraction`` of the recent
        samples, or None with no votes."""
        votes = self._votes
        if not votes:
            return None
        need = self.config.seen_fraction * len(votes) - 1e-9
        return sum(1 for k in range(self._n_beams) if sum(v[k] for v in votes) >= need)

    def bounds_m(self, context: int) -> tuple[float, float]:
        """The obstacle heights a context stands for [m]: (lower, upper); 0 and inf at the ends."""
        if not 0 <= context < self.n_contexts:
            raise ValueError(f"context must be in [0, {self.n_contexts - 1}], got {context!r}")
        h = self.config.beam_heights_m
        return (0.0 if context == 0 else h[context - 1], math.inf if context == self._n_beams else h[context])
