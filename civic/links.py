"""Link layers of captured frames: how each maps onto the Ethernet frame the parser reads.

A switch sees Ethernet. A capture taken with `tcpdump -i any` holds Linux cooked frames
instead (SLL, or SLL2 from libpcap 1.10 on), whose header stands for the Ethernet one. Every
frame is read through its Ethernet view: the 14 bytes before its IPv4 packet and what follows,
so every offset of the parser (docs/pipeline.md section 1) holds on every link type, and a
verdict patched in the view lands in the captured frame.
"""
from __future__ import annotations

import numpy as np

from civic.errors import CivicError

LINKTYPE_ETHERNET = 1
LINKTYPE_LINUX_SLL = 113        # tcpdump -i any: Linux cooked capture, a 16-byte header
LINKTYPE_LINUX_SLL2 = 276       # its version 2 (libpcap 1.10 on), a 20-byte header
# Each link type's shift from a frame's first byte to its Ethernet view: the 14 bytes before the
# IPv4 packet, so that every offset of the parser holds. SLL's protocol field falls where an
# Ethernet frame has its ethertype; SLL2 has it in its first 2 bytes (SLL2_ETHERTYPE, from the view).
LINK_VIEW = {LINKTYPE_ETHERNET: 0, LINKTYPE_LINUX_SLL: 2, LINKTYPE_LINUX_SLL2: 6}
SLL2_ETHERTYPE = -6


def check_link(linktype: int, path: str) -> None:
    """A link type CIVIC does not read (`LINK_VIEW`) is a one-line error."""
    if linktype not in LINK_VIEW:
        raise CivicError(f"{path}: link type {linktype} is neither Ethernet (1) nor a Linux cooked "
                         f"capture (113, 276)")


def link_views(offset: np.ndarray, caplen: np.ndarray,
               linktype: int) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Frames of one link type: the offsets and captured lengths of their Ethernet views, and
    each one's link type (None on Ethernet, whose frames are their own views)."""
    shift = LINK_VIEW[linktype]
    if not shift:
        return offset, caplen, None
    return (offset + shift, np.maximum(caplen.astype(np.int64) - shift, 0).astype(np.uint32),
            np.full(len(offset), linktype, np.uint16))


def ethertypes(head: np.ndarray, buf: np.ndarray, offset: np.ndarray, link: np.ndarray | None) -> np.ndarray:
    """Each frame's ethertype: in its Ethernet view, or in its SLL2 header (link: per frame, None
    for an all-Ethernet capture)."""
    sll2 = None if link is None else link == LINKTYPE_LINUX_SLL2
    if sll2 is None or not sll2.any():
        return head["ethertype"]
    at = offset[sll2] + SLL2_ETHERTYPE
    out = np.array(head["ethertype"], dtype=np.uint16)
    out[sll2] = buf[at].astype(np.uint16) << 8 | buf[at + 1]
    return out
