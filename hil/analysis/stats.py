"""Small statistics shared by the analysis, the figures and the sweep report (numpy only)."""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

# two-sided 95% Student t quantiles by degrees of freedom (1..30); above 30, the normal's 1.96
_T95 = (12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228, 2.201, 2.179, 2.160, 2.145,
        2.131, 2.120, 2.110, 2.101, 2.093, 2.086, 2.080, 2.074, 2.069, 2.064, 2.060, 2.056, 2.052, 2.048,
        2.045, 2.042)


def t95(dof: int) -> float:
    """The two-sided 95% quantile of Student's t with ``dof`` degrees of freedom."""
    if dof < 1:
        raise ValueError(f"need at least 1 degree of freedom, got {dof}")
    return _T95[dof - 1] if dof <= len(_T95) else 1.96


def running_success(success: Sequence[bool], window: int = 10) -> list[float]:
    """Mean success over the last ``window`` trials at each trial (fewer at the start)."""
    s = np.asarray(success, dtype=float)
    return [float(s[max(0, i - window + 1) : i + 1].mean()) for i in range(len(s))]


def mean_ci95(rows: Sequence[Sequence[float]]) -> tuple[list[float], list[float], list[float]]:
    """Column mean and 95% t-interval over rows (e.g. one row per seed); with one row the
    interval collapses to the mean. Rows are cut to the shortest."""
    if not rows:
        raise ValueError("mean_ci95 needs at least one row")
    n = min(len(r) for r in rows)
    a = np.array([list(r[:n]) for r in rows], dtype=float)
    mean = a.mean(axis=0)
    if len(a) < 2:
        return mean.tolist(), mean.tolist(), mean.tolist()
    half = t95(len(a) - 1) * a.std(axis=0, ddof=1) / math.sqrt(len(a))
    return mean.tolist(), (mean - half).tolist(), (mean + half).tolist()


def trials_to_criterion(success: Sequence[bool], window: int = 10, threshold: float = 0.9) -> int | None:
    """Trials run before the first ``window``-trial window whose success rate is at least
    ``threshold`` (0: good from the first trial); None if no window reaches it."""
    s = [bool(x) for x in success]
    need = math.ceil(threshold * window - 1e-9)
    for start in range(0, len(s) - window + 1):
        if sum(s[start : start + window]) >= need:
            return start
    return None
