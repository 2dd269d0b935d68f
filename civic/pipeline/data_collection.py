"""Twin of the registers in control/monitor.p4: ring buffer, pointer, run counter, running sums.

The ring holds 32-bit values (the level, or a balance monitor's level minus its accumulated
expected inflow); every sum is taken modulo 2^32, as the switch's bit<32> registers do.
"""
from __future__ import annotations

import numpy as np

RUN_MAX = 255
U32 = 0xFFFFFFFF


def next_run(run: int, qualified: bool, gap: bool) -> int:
    """Qualifying-run counter: restarts on a sequence gap, zero when the precondition fails."""
    if not qualified:
        return 0
    return 1 if gap else min(run + 1, RUN_MAX)


def runs(qualified: np.ndarray, gap: np.ndarray) -> np.ndarray:
    """next_run over a whole stream starting from run = 0 (vectorized)."""
    n = len(qualified)
    idx = np.arange(n)
    reset = np.where(~qualified, idx + 1, np.where(gap, idx, 0))
    start = np.maximum.accumulate(reset) if n else reset
    return np.where(qualified, np.minimum(idx - start + 1, RUN_MAX), 0)


class RingState:
    """Per-plant registers of one monitor: ring[slot][R], ptr, run, s0, s1."""

    def __init__(self, plants: int, ring_len: int):
        self.ring_len = ring_len
        self.ring = np.zeros((plants, ring_len), dtype=np.int64)
        self.ptr = np.zeros(plants, dtype=np.int64)
        self.run = np.zeros(plants, dtype=np.int64)
        self.s0 = np.zeros(plants, dtype=np.int64)
        self.s1 = np.zeros(plants, dtype=np.int64)

    def push(self, slot: int, x: int) -> int:
        """Write x at the pointer, update the sums (32-bit modular); return the value it replaced."""
        p = self.ptr[slot]
        old = int(self.ring[slot, p])
        self.ring[slot, p] = x & U32
        self.ptr[slot] = 0 if p + 1 == self.ring_len else p + 1
        s0 = int(self.s0[slot])
        self.s1[slot] = (int(self.s1[slot]) + s0 - self.ring_len * old) & U32
        self.s0[slot] = (s0 + x - old) & U32
        return old


def window_sums(x: np.ndarray, ring_len: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(old, s0, s1) after each push of x into an empty ring (vectorized), modulo 2^32.

    Prefix sums in uint64 wrap modulo 2^64, a multiple of 2^32, so the results are exact mod 2^32.
    """
    x = np.asarray(x, dtype=np.int64).astype(np.uint64) & np.uint64(U32)
    n = len(x)
    pad = np.concatenate((np.zeros(ring_len, np.uint64), x))
    c = np.concatenate((np.zeros(1, np.uint64), np.cumsum(pad, dtype=np.uint64)))
    d = np.concatenate((np.zeros(1, np.uint64), np.cumsum(pad * np.arange(len(pad), dtype=np.uint64),
                                                          dtype=np.uint64)))
    i = np.arange(n) + ring_len            # position of x[k] in pad
    s0 = c[i + 1] - c[i + 1 - ring_len]
    s1 = i.astype(np.uint64) * s0 - (d[i + 1] - d[i + 1 - ring_len])
    old = pad[i - ring_len]
    m = np.uint64(U32)
    return (old & m).astype(np.int64), (s0 & m).astype(np.int64), (s1 & m).astype(np.int64)
