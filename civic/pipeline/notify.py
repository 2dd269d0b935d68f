"""Twin of control/notify.p4 and the last_class / verdicts objects of control/monitor.p4.

Per (plant slot, monitor): `last_class`, the last class (1..3) the monitor gave
that plant; a message whose class c is not 0 and not last_class is a verdict
change (an event; its `from` is 0, "none yet", for the plant's first verdict)
and sets last_class = c. Per (slot, monitor, class): a counter of verdicts.
Messages without a verdict (class 0) change neither (docs/pipeline.md section 7).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

CLASSES = 4          # counter cells per (slot, monitor): class 0 (never counted), 1..3


@dataclass
class Change:
    """One verdict change: message index in the capture and what the digest carries."""

    index: int
    plant: int           # IPv4 source
    monitor: int
    prev: int            # 0: the plant's first verdict from this monitor
    cls: int
    seq: int
    slope: int
    level: int


def changes(slot: np.ndarray, code: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(changed, prev) per message of one monitor, the messages in capture order, from
    a freshly reset switch: prev = the last nonzero class of the same slot before it."""
    slot = np.asarray(slot, np.int64)
    code = np.asarray(code, np.int64)
    n = len(code)
    prev = np.zeros(n, np.int64)
    given = np.flatnonzero(code != 0)
    if len(given):
        s = slot[given]
        order = np.argsort(s, kind="stable")          # each slot's verdicts, in capture order
        g, ss = given[order], s[order]
        first = np.concatenate(([True], ss[1:] != ss[:-1]))
        before = np.concatenate(([0], code[g][:-1]))
        prev[g] = np.where(first, 0, before)
    changed = (code != 0) & (code != prev)
    return changed, prev


def verdict_counts(slot: np.ndarray, code: np.ndarray, plants: int) -> np.ndarray:
    """Counter cells (plants, 4) of one monitor: verdicts per slot and class."""
    counts = np.zeros((plants, CLASSES), np.int64)
    np.add.at(counts, (np.asarray(slot, np.int64), np.asarray(code, np.int64)), 1)
    counts[:, 0] = 0
    return counts
