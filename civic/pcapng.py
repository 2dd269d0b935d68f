"""pcapng (Wireshark's and dumpcap's default format): where each frame is, and when it was captured.

`PcapNgBlocks(path).walk(raw, final)` walks the blocks of a pcapng file, or of consecutive
blocks of it read in chunks, and returns each Enhanced Packet Block's frame offset and captured
length (of its Ethernet view, `civic.links`), capture time and link type. The state that spans
chunks (the section's byte order, its interfaces' link types and time resolutions) lives in the
walker. Frames stay where they are in the file's bytes, so a patched verdict is written back
into the pcapng itself. Errors are one line: a cut-off or corrupt block, a frame on an
interface neither Ethernet nor Linux cooked, and the packet blocks that carry no capture time
(Simple) or are obsolete (Packet), which are never skipped silently.

`write_pcapng` and `packet_blocks` (which `pcap_chunks.PcapWriter` streams) write what civic
writes as pcap (one section, one Ethernet interface, microsecond stamps) as pcapng, for a path
that asks for it (`OUT.pcapng`).
"""
from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

from civic.errors import CivicError
from civic.links import LINKTYPE_ETHERNET, check_link, link_views

PCAPNG_MAGIC = 0x0A0D0D0A             # a Section Header Block's type: the file's first 4 bytes
BYTE_ORDER_MAGIC = 0x1A2B3C4D         # as read little-endian; 0x4D3C2B1A: the section is big-endian
IDB, EPB = 0x00000001, 0x00000006       # interface description, enhanced packet
UNSUPPORTED = {0x00000002: "obsolete Packet", 0x00000003: "Simple Packet (no capture time)"}
OPT_TSRESOL, OPT_TSOFFSET = 9, 14       # interface options: time resolution, seconds added
MAX_BLOCK = 1 << 24                     # larger than any frame: a length beyond it is corruption
MIN_BLOCK = 12                          # type, length, length again
SECTION_HEAD = 16                       # a section header's type, length and byte-order magic


class PcapNgBlocks:
    """The blocks of one pcapng file, walked in order (whole, or chunk after chunk)."""

    def __init__(self, path: str):
        self.path = path
        self.order = "<"
        self.interfaces: list[tuple[int, int, int]] = []    # (link type, units per second, offset s)

    def walk(self, raw, final: bool = True,
             base: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None, int]:
        """(frame offsets, captured lengths, capture times in s, link types, end) of the packets
        in the complete blocks of raw: offsets and lengths of the frames' Ethernet views, link
        types None when all are Ethernet. A block cut off at the end is an error when `final`,
        else where the walk stops (`end`). `base`: raw's offset in the file, for error messages."""
        arr = np.frombuffer(raw, np.uint8)
        offsets, caplens, times, links = [], [], [], []
        size, pos, look = len(raw), 0, 64
        while pos < size:
            at = base + pos
            if size - pos < MIN_BLOCK:
                if not final:
                    break
                raise CivicError(f"{self.path}: truncated pcapng: {size - pos} stray bytes at offset {at}")
            if struct.unpack_from("<I", raw, pos)[0] == PCAPNG_MAGIC:      # a section starts (palindromic type)
                if size - pos < SECTION_HEAD and not final:
                    break                                 # its byte-order magic is in the next chunk
                self._section(raw, pos, at)
            kind, length = struct.unpack_from(self.order + "II", raw, pos)
            if length < MIN_BLOCK or length % 4 or length > MAX_BLOCK:
                raise CivicError(f"{self.path}: corrupt pcapng: block at offset {at} claims {length} bytes")
            if pos + length > size:
                if not final:
                    break
                raise CivicError(f"{self.path}: truncated pcapng: block at offset {at} needs {length} bytes, "
                                 f"{size - pos} remain")
            if kind == EPB:
                if length < 32:
                    raise CivicError(f"{self.path}: corrupt pcapng: packet block at offset {at} of {length} bytes")
                # a run of packet blocks of this length on this interface, read at once (a capture's
                # packets of one size back to back: the usual case)
                k = min(look, (size - pos) // length)
                head = np.ndarray((k, 6), self.order + "u4", arr, pos, (length, 4))    # type .. captured length
                same = (head[:, 0] == EPB) & (head[:, 1] == length) & (head[:, 2] == head[0, 2])
                n = int(np.argmin(same)) if not same.all() else k
                t, linktype = self._times(head[:n], at)
                check_link(linktype, self.path)
                offset, caplen, link = link_views(pos + 28 + length * np.arange(n, dtype=np.int64),
                                                  head[:n, 5].astype(np.uint32), linktype)
                offsets.append(offset)
                caplens.append(caplen)
                times.append(t)
                links.append((n, link))
                pos += n * length
                look = look * 2 if n == k else 64
                continue
            if kind == IDB:
                self._interface(raw, pos, length, at)
            elif kind in UNSUPPORTED:
                raise CivicError(f"{self.path}: pcapng {UNSUPPORTED[kind]} blocks are not supported "
                                 f"(offset {at}); convert with 'editcap -F pcap'")
            pos += length
        if not offsets:
            return np.zeros(0, np.int64), np.zeros(0, np.uint32), np.zeros(0, np.float64), None, pos
        link = None if all(k is None for _, k in links) else np.concatenate(
            [np.full(n, LINKTYPE_ETHERNET, np.uint16) if k is None else k for n, k in links])
        return np.concatenate(offsets), np.concatenate(caplens), np.concatenate(times), link, pos

    def _times(self, head: np.ndarray, at: int) -> tuple[np.ndarray, int]:
        """(capture times in s, link type) of a run of packet blocks on one interface (their
        first 6 words)."""
        iface, length = int(head[0, 2]), int(head[0, 1])
        if iface >= len(self.interfaces) or np.any(32 + head[:, 5].astype(np.int64) > length):
            raise CivicError(f"{self.path}: corrupt pcapng: packet block at offset {at} or after it")
        link, units, shift = self.interfaces[iface]
        stamp = head[:, 3].astype(np.uint64) << np.uint64(32) | head[:, 4].astype(np.uint64)
        whole, part = np.divmod(stamp, np.uint64(units))
        return whole.astype(np.float64) + shift + part.astype(np.float64) / units, link

    def _section(self, raw, pos: int, at: int) -> None:
        """A Section Header Block: its byte order; interfaces are numbered afresh."""
        if len(raw) - pos < SECTION_HEAD:
            raise CivicError(f"{self.path}: truncated pcapng: section header at offset {at}")
        magic = struct.unpack_from("<I", raw, pos + 8)[0]
        if magic not in (BYTE_ORDER_MAGIC, 0x4D3C2B1A):
            raise CivicError(f"{self.path}: corrupt pcapng: section header at offset {at} has no byte-order magic")
        self.order = "<" if magic == BYTE_ORDER_MAGIC else ">"
        self.interfaces = []

    def _interface(self, raw, pos: int, length: int, at: int) -> None:
        """An Interface Description Block: link type, time resolution (default microseconds) and
        offset, from its options."""
        if length < 20:
            raise CivicError(f"{self.path}: corrupt pcapng: interface block at offset {at}")
        link = struct.unpack_from(self.order + "H", raw, pos + 8)[0]
        units, shift = 1_000_000, 0
        opt, end = pos + 16, pos + length - 4
        while opt + 4 <= end:
            code, n = struct.unpack_from(self.order + "HH", raw, opt)
            if code == 0:                            # opt_endofopt
                break
            if opt + 4 + n > end:
                raise CivicError(f"{self.path}: corrupt pcapng: interface options at offset {at + opt - pos}")
            if code == OPT_TSRESOL and n >= 1:
                r = raw[opt + 4]
                units = 2 ** (r & 0x7F) if r & 0x80 else 10 ** r
                if units > 1 << 63:
                    raise CivicError(f"{self.path}: pcapng interface at offset {at}: time resolution 0x{r:02x} "
                                     "is not supported (more than 2^63 units per second)")
            elif code == OPT_TSOFFSET and n >= 8:
                shift = struct.unpack_from(self.order + "q", raw, opt + 4)[0]
            opt += 4 + (n + 3) // 4 * 4
        self.interfaces.append((link, units, shift))


def _block(kind: int, body: bytes) -> bytes:
    """One little-endian block: type, total length, body padded to 32 bits, total length again."""
    body += b"\0" * (-len(body) % 4)
    return struct.pack("<II", kind, 12 + len(body)) + body + struct.pack("<I", 12 + len(body))


# a little-endian section of unknown length, with one Ethernet interface of microsecond stamps
# (the default resolution: no option) and a snapshot length as civic's pcap header's
PCAPNG_HEAD = (_block(PCAPNG_MAGIC, struct.pack("<IHHq", BYTE_ORDER_MAGIC, 1, 0, -1))
               + _block(IDB, struct.pack("<HHI", LINKTYPE_ETHERNET, 0, 262144)))


def packet_blocks(t, frames, lengths=None) -> bytes:
    """Enhanced Packet Blocks on interface 0: frames (an (n, k) uint8 array or bytes-likes)
    captured at times t (s); lengths: their lengths on the wire (default: as captured)."""
    us = np.round(np.asarray(t, dtype=np.float64) * 1e6).astype(np.uint64)
    if isinstance(frames, np.ndarray):                 # equal frames: one array of blocks
        n, k = frames.shape
        size = 32 + (k + 3) // 4 * 4
        out = np.zeros((n, size), np.uint8)
        words = np.zeros((n, 7), "<u4")            # type, length, interface, stamp, captured, on the wire
        words[:, 0], words[:, 1], words[:, 5] = EPB, size, k
        words[:, 3], words[:, 4] = us >> np.uint64(32), us & np.uint64(0xFFFFFFFF)
        words[:, 6] = k if lengths is None else np.asarray(lengths)
        out[:, :28] = words.view(np.uint8).reshape(n, 28)
        out[:, 28:28 + k] = frames
        out[:, -4:] = np.full(n, size, "<u4").view(np.uint8).reshape(n, 4)
        return out.tobytes()
    body = bytearray()
    for i, frame in enumerate(frames):
        stamp = int(us[i])
        wire = len(frame) if lengths is None else int(lengths[i])
        body += _block(EPB, struct.pack("<IIIII", 0, stamp >> 32, stamp & 0xFFFFFFFF, len(frame), wire)
                       + bytes(frame))
    return bytes(body)


def write_pcapng(path: str | Path, t, frames) -> None:
    """Write frames with times t (s) as a pcapng of one Ethernet interface."""
    Path(path).write_bytes(PCAPNG_HEAD + packet_blocks(t, frames))
