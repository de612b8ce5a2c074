"""Statistics across seeds: Student-t interval of the mean and the interquartile mean
(Agarwal et al., NeurIPS 2021).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["T_975", "interquartile_mean", "t_interval"]

# two-sided 95 % Student-t quantiles for 1..30 degrees of freedom, then the normal's
T_975 = (
    12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228,
    2.201, 2.179, 2.160, 2.145, 2.131, 2.120, 2.110, 2.101, 2.093, 2.086,
    2.080, 2.074, 2.069, 2.064, 2.060, 2.056, 2.052, 2.048, 2.045, 2.042, 1.960,
)  # fmt: skip


def t_interval(values: np.ndarray) -> tuple[float, float]:
    """95 % Student-t interval of the mean of ``values`` (n,); nan with fewer than 2."""
    x = np.asarray(values, np.float64)
    n = len(x)
    if n < 2:
        return (math.nan, math.nan)
    half = T_975[min(n - 1, len(T_975)) - 1] * x.std(ddof=1) / math.sqrt(n)
    return (float(x.mean() - half), float(x.mean() + half))


def interquartile_mean(values: np.ndarray) -> float:
    """Mean of the middle 50 % of ``values`` (n,), fractional ends weighted."""
    x = np.sort(np.asarray(values, np.float64))
    n = len(x)
    lo, hi = 0.25 * n, 0.75 * n
    weights = np.clip(np.minimum(np.arange(1, n + 1), hi) - np.maximum(np.arange(n), lo), 0, 1)
    return float(np.sum(weights * x) / np.sum(weights))
