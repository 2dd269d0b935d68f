"""Twin of control/balance.p4: a balance monitor's expected flows and accumulator (pipeline.md 3b).

Each flow term is a range table on (head, cmd) = (f[plus] - f[minus] mod 2^16, f[command]),
whose entry gives the expected net inflow of one sample period (sixteenths of a mL) and a band
contribution; the terms are summed, the sum accumulated per plant, and the ring gets
z = (x << 4) - acc, so the monitor's slope over z is the balance residual.
"""
from __future__ import annotations

import numpy as np

from civic.entries import BALANCE_SHIFT, FlowTerm

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
    f = np.zeros(head.shape, np.int64)
    b = np.zeros(head.shape, np.int64)
    for hlo, hhi, clo, chi, fl, bd in term.rows:
        hit = (head >= hlo) & (head <= hhi) & (cmd >= clo) & (cmd <= chi)
        f[hit] = fl
        b[hit] = bd
    return f, b


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
    """What the ring gets: (x << 4) - acc, modulo 2^32 (acc after this message's e)."""
    return ((np.asarray(x, np.int64) << BALANCE_SHIFT) - np.asarray(acc, np.int64)) & U32


def accumulate(e: np.ndarray) -> np.ndarray:
    """acc after each message of one plant's stream, starting from 0 (modulo 2^32)."""
    return (np.cumsum(np.asarray(e, np.int64).astype(np.uint64), dtype=np.uint64) & np.uint64(U32)).astype(np.int64)
