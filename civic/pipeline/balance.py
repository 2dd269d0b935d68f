"""Twin of control/balance.p4: a balance monitor's expected flows and accumulator (pipeline.md 3b).

Each flow term is a range table on (head, cmd) = (f[plus] - f[minus] mod 2^16, f[command]),
whose entry gives the expected net inflow of one sample period (1/64 mL) and a band
contribution; the terms are summed, the sum accumulated per plant, and the ring gets
z = (x << 6) - acc, so the monitor's slope over z is the balance residual; the bands are
summed over the same window (accb and its ring) for the class table's second key.
"""
from __future__ import annotations

import numpy as np

from civic.entries import BALANCE_SHIFT, BAND_SUM_SHIFT, FlowTerm

U16, U32 = 0xFFFF, 0xFFFFFFFF


def operand(fields: dict, name: str):
    """A flow term's operand: a wire field, or 0 for 'zero'."""
    if name == "zero":
        return np.zeros_like(np.asarray(fields["l1"], np.int64))
    return np.asarray(fields[name], np.int64)


def keys(fields: dict, term: FlowTerm) -> tuple[np.ndarray, np.ndarray]:
    """(head, cmd) of a term: head = f[plus] - f[minus] modulo 2^16."""
    head = (operand(fields, term.head[0]) - operand(fields, term.head[1])) & U16
    return head, operand(fields, term.command)


def flow(fields: dict, term: FlowTerm) -> tuple[np.ndarray, np.ndarray]:
    """The term's table lookup: (flow, band) of the entry holding (head, cmd); a miss gives (0, 0)."""
    head, cmd = keys(fields, term)
    if not len(term.rows):
        return np.zeros(head.shape, np.int64), np.zeros(head.shape, np.int64)
    hit = term.table.lookup(head, cmd)
    return (np.where(hit >= 0, term.rows[hit, 4], 0).astype(np.int64),
            np.where(hit >= 0, term.rows[hit, 5], 0).astype(np.int64))


def expected(fields: dict, terms: list[FlowTerm]) -> tuple[np.ndarray, np.ndarray]:
    """(e, band): the terms' flows summed (32 bit) and their bands summed (16 bit)."""
    e = np.zeros(np.shape(fields["l1"]), np.int64)
    band = np.zeros(np.shape(fields["l1"]), np.int64)
    for term in terms:
        f, b = flow(fields, term)
        e += f
        band += b
    return e & U32, band & U16


def pushed(x, acc):
    """What the ring gets: (x << 6) - acc, modulo 2^32 (acc after this message's e)."""
    return ((np.asarray(x, np.int64) << BALANCE_SHIFT) - np.asarray(acc, np.int64)) & U32


def accumulate(e: np.ndarray) -> np.ndarray:
    """acc after each message of one plant's stream, starting from 0 (modulo 2^32)."""
    return (np.cumsum(np.asarray(e, np.int64).astype(np.uint64), dtype=np.uint64) & np.uint64(U32)).astype(np.int64)


def window_band(accb, oldb):
    """band_w: the band summed over the ring's R messages (accb now minus R messages ago), >> 7."""
    return ((np.asarray(accb, np.int64) - np.asarray(oldb, np.int64)) & U32) >> BAND_SUM_SHIFT


def window_bands(band: np.ndarray, ring_len: int) -> np.ndarray:
    """band_w after each message of one plant's stream from an empty ring (vectorized)."""
    accb = accumulate(band)
    old = np.concatenate((np.zeros(ring_len, np.int64), accb))[:len(accb)]
    return window_band(accb, old)
