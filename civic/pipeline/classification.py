"""Twin of the precondition, compensate and classify tables in control/monitor.p4
(and of the aux difference in control/signal_select.p4)."""
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


def aux(fields: dict, plus: str, minus: str) -> np.ndarray:
    """max(x[plus] - x[minus], 0): the level difference that drives the inflow (16 bit)."""
    return np.maximum(np.asarray(fields[plus], np.int64) - np.asarray(fields[minus], np.int64), 0)


def compensate(aux_value, offsets: np.ndarray) -> np.ndarray:
    """Compensate table lookup on aux: the offset of the entry whose range holds it, 0 on a miss."""
    a = np.asarray(aux_value, dtype=np.int64)
    out = np.zeros(a.shape, dtype=np.int64)
    for lo, hi, off in offsets:
        out[(a >= lo) & (a <= hi)] = off
    return out


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
