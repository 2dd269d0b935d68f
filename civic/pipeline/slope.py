"""Twin of control/slope.p4: the slope estimators (and a limit monitor's value), integer only."""
from __future__ import annotations

import numpy as np

INT32 = 1 << 32


def to_int32(v):
    """Reinterpret a 32-bit register value as signed, as the P4 cast does."""
    v = np.asarray(v, dtype=np.int64) & (INT32 - 1)
    return np.where(v >= INT32 // 2, v - INT32, v)


def endpoint(x, old):
    """Newest minus oldest of the window (the CIVIC paper's estimator)."""
    return to_int32(np.asarray(x, np.int64) - np.asarray(old, np.int64))


def lsq(s0, s1, window: int):
    """Twice the least-squares numerator: (W-1)*s0 - 2*s1 (docs/pipeline.md section 3)."""
    return to_int32((window - 1) * np.asarray(s0, np.int64) - 2 * np.asarray(s1, np.int64))


def value(x):
    """A limit monitor's 'slope': the value itself (the value estimator)."""
    return to_int32(x)


def estimate(estimator: str, x, old, s0, s1, window: int):
    """The estimator named in the monitor's entries."""
    if estimator == "lsq":
        return lsq(s0, s1, window)
    if estimator == "endpoint":
        return endpoint(x, old)
    return value(x)
