"""Noise levels of recorded signals (robust: outliers and slow trends do not count)."""
from __future__ import annotations

import numpy as np


def robust_sigma(x: np.ndarray) -> float:
    """Standard deviation from the median absolute deviation (the std, or 1e-9, if that is 0)."""
    x = np.asarray(x, float)
    if x.size == 0:
        return 1.0
    return float(1.4826 * np.median(np.abs(x - np.median(x)))) or float(np.std(x)) or 1e-9


def noise_sigma(x: np.ndarray) -> float:
    """Noise level of a signal from its second differences (robust to slow trends)."""
    d2 = np.diff(np.asarray(x, float), 2)
    return robust_sigma(d2) / np.sqrt(6.0) if d2.size else 1e-9
