"""Twin of the precondition, compensate and classify tables and of the hold step in
control/monitor.p4 (and of the aux difference in control/signal_select.p4)."""
from __future__ import annotations

import numpy as np

from civic.config import PRECONDITION_FIELDS

SLOPE_BIAS = 0x80000000
HOLD_MAX = 255


def qualified(fields: dict, ranges: list[tuple[int, int]]) -> np.ndarray:
    """Precondition table hit: every field (wire fields and command steps) within its [lo, hi]."""
    ok = np.ones(len(fields[PRECONDITION_FIELDS[0]]), dtype=bool)
    for name, (lo, hi) in zip(PRECONDITION_FIELDS, ranges):
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


def next_hold(cand: int, hold: int, c_raw: int) -> tuple[int, int]:
    """(cand, hold) after a table result: count how long the same result has been given."""
    return (cand, min(hold + 1, HOLD_MAX)) if c_raw == cand else (c_raw, 1)


def holds(c_raw: np.ndarray) -> np.ndarray:
    """hold after each message of one plant's stream, starting from cand = 0, hold = 0."""
    c_raw = np.asarray(c_raw, np.int64)
    n = len(c_raw)
    if n == 0:
        return np.zeros(0, np.int64)
    idx = np.arange(n)
    prev = np.concatenate(([0], c_raw[:-1]))
    start = np.maximum.accumulate(np.where(c_raw != prev, idx, 0))
    # cand starts at 0 with hold 0: a leading run of 0s counts from 1 like any run
    return np.minimum(idx - start + 1, HOLD_MAX)


def held(c_raw, hold, min_hold: int):
    """The class written: the table's result once it held for min_hold messages, else 0."""
    return np.where(np.asarray(hold) >= min_hold, c_raw, 0)
