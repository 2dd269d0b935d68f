"""Twin of the precondition and classify range tables in control/monitor.p4."""
from __future__ import annotations

import numpy as np

from civic.wire import SIGNALS

SLOPE_BIAS = 0x80000000


def qualified(fields: dict, ranges: list[tuple[int, int]]) -> np.ndarray:
    """Precondition table hit: every wire field within its [lo, hi] range."""
    ok = np.ones(len(fields[SIGNALS[0]]), dtype=bool)
    for name, (lo, hi) in zip(SIGNALS, ranges):
        v = fields[name]
        ok &= (v >= lo) & (v <= hi)
    return ok


def slope_key(slope):
    """Order-preserving unsigned key of a signed 32-bit slope."""
    return (np.asarray(slope, dtype=np.int64) & 0xFFFFFFFF) ^ SLOPE_BIAS


def classify(slope, level, classes: np.ndarray, default_class: int) -> np.ndarray:
    """Class table lookup on (slope_key, level); a miss gives default_class."""
    key = slope_key(slope)
    level = np.asarray(level, dtype=np.int64)
    out = np.full(key.shape, default_class, dtype=np.int64)
    for lo, hi, llo, lhi, cls in classes:
        hit = (key >= slope_key(lo)) & (key <= slope_key(hi)) & (level >= llo) & (level <= lhi)
        out[hit] = cls
    return out
