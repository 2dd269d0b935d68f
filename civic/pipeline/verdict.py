"""Twin of control/verdict.p4: verdict bits per monitor and the UDP checksum update."""
from __future__ import annotations

import numpy as np

from civic.wire import incremental_checksum

__all__ = ["verdict_bits", "incremental_checksum"]


def verdict_bits(codes: list[np.ndarray]) -> np.ndarray:
    """Monitor m's 2-bit code goes to bits 2m+1..2m of the 16-bit verdict."""
    out = np.zeros(len(codes[0]) if codes else 0, dtype=np.uint16)
    for m, c in enumerate(codes):
        out |= (np.asarray(c, dtype=np.uint16) & 0x3) << (2 * m)
    return out
