"""Twin of control/plant_lookup.p4: which frames are plant messages, their slot, sequence gaps.

The parser-level checks (Ethernet/IPv4/UDP, port, length, prefix) happen when
a capture is decoded (`civic.wire.decode_frames` sets `plant`); here are the
per-plant parts that touch state.
"""
from __future__ import annotations

import numpy as np

from civic.config import STEP_FIELDS

MAX_PLANTS = 256
SEQ_MASK = 0xFFFFFFFF
COMMANDS = ("p1", "v1", "v2")
STEPS = STEP_FIELDS                       # |command - the plant's previous command|, in COMMANDS order


def plant_slot(src):
    """State slot of a plant: the last octet of its IPv4 source."""
    return np.asarray(src, dtype=np.uint32) & 0xFF


def seq_gap(seq: int, last_seq: int) -> bool:
    """True unless `seq` directly follows `last_seq` (modulo 2^32)."""
    return seq != ((last_seq + 1) & SEQ_MASK)


def seq_gaps(seq: np.ndarray) -> np.ndarray:
    """seq_gap over one plant's message stream, the stream starting from last_seq = 0."""
    seq = np.asarray(seq, dtype=np.uint64)
    prev = np.concatenate((np.zeros(1, np.uint64), seq[:-1]))
    return seq != ((prev + np.uint64(1)) & np.uint64(SEQ_MASK))


def command_steps(fields: dict, last: dict) -> dict:
    """Steps of one message's commands from the plant's previous ones (`last`, 0 at first)."""
    return {d: abs(int(fields[c]) - int(last[c])) for c, d in zip(COMMANDS, STEPS)}


def command_steps_stream(fields: dict) -> dict:
    """command_steps over one plant's message stream, starting from last = 0 (vectorized)."""
    out = {}
    for c, d in zip(COMMANDS, STEPS):
        v = np.asarray(fields[c], np.int64)
        out[d] = np.abs(np.diff(v, prepend=np.int64(0)))
    return out
