"""Twin of the precondition, compensate and classify tables and of the hold step in
control/monitor.p4 (and of the aux difference in control/signal_select.p4)."""
from __future__ import annotations

from functools import lru_cache

import numpy as np

from civic.config import PRECONDITION_FIELDS

SLOPE_BIAS = 0x80000000
HOLD_MAX = 255


class RangeTable:
    """A range-match table on k keys, looked up by a binary search per key over the entries'
    edges into a grid of entry indices (-1 on a miss). Where entries overlap, the earlier one
    wins, as in the switch, where entry i gets priority PRIORITY_BASE - i (entries that
    `civic train` writes never overlap; the grid is resolved once, when it is built)."""

    def __init__(self, lo: np.ndarray, hi: np.ndarray):
        lo, hi = np.atleast_2d(np.asarray(lo, np.int64)), np.atleast_2d(np.asarray(hi, np.int64))
        self.edges = [np.unique(np.concatenate((lo[:, j], hi[:, j] + 1))) for j in range(lo.shape[1])]
        self.grid = np.full([len(e) + 1 for e in self.edges], -1, np.int64)
        for r in reversed(range(len(lo))):          # the highest-priority entry written last
            cells = tuple(slice(int(np.searchsorted(e, lo[r, j], "right")), int(np.searchsorted(e, hi[r, j], "right")) + 1)
                          for j, e in enumerate(self.edges))
            self.grid[cells] = r

    def lookup(self, *keys) -> np.ndarray:
        """Index of the entry holding each key tuple, -1 where none does."""
        return self.grid[tuple(np.searchsorted(e, np.asarray(k, np.int64), "right") for e, k in zip(self.edges, keys))]


@lru_cache(maxsize=64)
def _table(rows: bytes, n: int, keys: int) -> RangeTable:
    a = np.frombuffer(rows, np.int64).reshape(n, -1)
    return RangeTable(a[:, 0:2 * keys:2], a[:, 1:2 * keys:2])


def range_table(rows: np.ndarray, keys: int) -> RangeTable:
    """The RangeTable of rows whose first 2*keys columns are (lo, hi) per key (cached by content)."""
    rows = np.ascontiguousarray(rows, np.int64)
    return _table(rows.tobytes(), len(rows), keys)


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
    if not len(offsets):
        return np.zeros(a.shape, dtype=np.int64)
    hit = range_table(offsets, 1).lookup(a)
    return np.where(hit >= 0, np.asarray(offsets, np.int64)[hit, 2], 0)


def slope_key(slope):
    """Order-preserving unsigned key of a signed 32-bit slope."""
    return (np.asarray(slope, dtype=np.int64) & 0xFFFFFFFF) ^ SLOPE_BIAS


def classify(slope, level, classes: np.ndarray, default_class: int) -> np.ndarray:
    """Class table lookup on (slope_key, level); a miss gives default_class."""
    key = slope_key(slope)
    if not len(classes):
        return np.full(key.shape, default_class, dtype=np.int64)
    rows = np.asarray(classes, np.int64).copy()
    rows[:, 0], rows[:, 1] = slope_key(rows[:, 0]), slope_key(rows[:, 1])   # ranges on the biased key
    hit = range_table(rows, 2).lookup(key, np.asarray(level, dtype=np.int64))
    return np.where(hit >= 0, rows[hit, 4], default_class)


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
