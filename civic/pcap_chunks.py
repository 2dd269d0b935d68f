"""Captures in chunks: read in whole records (bounded memory whatever the file's size),
written as frames arrive.

`PcapChunks(path)` checks the file header (one-line errors, as `read_pcap`) and iterates
`Chunk`s: the bytes of consecutive records (record headers included, so writing each chunk's
`data` after `header` gives the file back), where each frame starts and which frames are plant
messages. A record cut off at the end of the file is the same one-line error as `read_pcap`.
A pcapng is walked block by block (`civic.pcapng`): its `header` is empty, its chunks hold every
block, packets or not, so the file comes back as pcapng.
"""
from __future__ import annotations

import struct
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np

from civic.errors import CivicError
from civic.links import LINK_VIEW, ethertypes, link_views
from civic.pcapng import PCAPNG_HEAD, PcapNgBlocks, packet_blocks
from civic.wire import (DEFAULT_PLANT_PREFIX, DEFAULT_UDP_PORT, PCAP_HEADER, frame_heads, frame_kinds, is_pcapng,
                        pcap_header, record_offsets, record_times)

CHUNK_BYTES = 1 << 20          # file bytes read per chunk (13 k plant-message records: fits the caches)
RECORD_HEADER = 16


@dataclass
class Chunk:
    """Consecutive records of a capture: data[:end] holds them, offset[i] is where frame i's
    Ethernet view starts (`civic.links`)."""

    data: bytearray
    end: int
    offset: np.ndarray
    caplen: np.ndarray
    udp_port: int
    plant_prefix: str
    order: str = "<"                 # classic pcap: the record headers' byte order and time fraction
    frac: int = 1_000_000
    view: int = 0                    # classic pcap: from a record's frame to its Ethernet view
    t: np.ndarray | None = None      # pcapng: the capture times, read with the blocks
    link: np.ndarray | None = None   # the frames' link types; None: all Ethernet

    def __len__(self) -> int:
        return len(self.offset)

    @cached_property
    def buf(self) -> np.ndarray:
        return np.frombuffer(self.data, np.uint8)

    @cached_property
    def heads(self) -> np.ndarray:
        """Every frame's head fields (wire.HEAD_DTYPE), a view on data."""
        return frame_heads(self.buf, self.offset, self.caplen)

    @cached_property
    def plant(self) -> np.ndarray:
        """Which frames are plant messages (the parser's checks)."""
        if not len(self):
            return np.zeros(0, bool)
        return frame_kinds(self.heads, self.caplen, self.udp_port, self.plant_prefix,
                           ethertypes(self.heads, self.buf, self.offset, self.link))[2]

    def times(self, idx=slice(None)) -> np.ndarray:
        """Capture times (s) of the records idx."""
        if self.t is not None:
            return self.t[idx]
        return record_times(self.buf, self.offset[idx] - self.view - RECORD_HEADER, self.order, self.frac)

    def records(self) -> memoryview:
        """The records' bytes, as they go back into a file."""
        return memoryview(self.data)[:self.end]


class PcapChunks:
    """Iterate a pcap file's records in chunks of about `chunk_bytes`."""

    def __init__(self, path: str | Path, udp_port: int = DEFAULT_UDP_PORT,
                 plant_prefix: str = DEFAULT_PLANT_PREFIX, chunk_bytes: int = CHUNK_BYTES):
        self.path = str(path)
        self.udp_port, self.plant_prefix, self.chunk_bytes = udp_port, plant_prefix, chunk_bytes
        try:
            with open(self.path, "rb") as fh:
                self.header = fh.read(24)
        except OSError as exc:
            raise CivicError(f"cannot read {self.path}: {exc.strerror}") from exc
        self.blocks = PcapNgBlocks(self.path) if is_pcapng(self.header) else None
        if self.blocks is not None:
            self.header = b""            # a pcapng's first block is a block like the others
        else:
            self.order, self.frac, self.linktype = pcap_header(self.header, self.path)

    def __iter__(self):
        pending = bytearray()
        base = len(self.header)                      # file offset of pending's first byte
        try:
            fh = open(self.path, "rb")
        except OSError as exc:
            raise CivicError(f"cannot read {self.path}: {exc.strerror}") from exc
        with fh:
            fh.seek(base)
            while True:
                data = bytearray(len(pending) + self.chunk_bytes)
                data[:len(pending)] = pending
                got = fh.readinto(memoryview(data)[len(pending):])
                final = got == 0
                del data[len(pending) + got:]
                if self.blocks is not None:
                    offset, caplen, t, link, end = self.blocks.walk(memoryview(data), final, base)
                    chunk = Chunk(data, end, offset, caplen, self.udp_port, self.plant_prefix, t=t, link=link)
                else:
                    rec, caplen, end = record_offsets(memoryview(data), self.order, 0, self.path, final, base)
                    offset, caplen, link = link_views(rec + RECORD_HEADER, caplen, self.linktype)
                    chunk = Chunk(data, end, offset, caplen, self.udp_port, self.plant_prefix,
                                  self.order, self.frac, LINK_VIEW[self.linktype], link=link)
                if end:
                    yield chunk
                if final:
                    return
                pending = data[end:]
                base += end


class PcapWriter:
    """A microsecond pcap written as frames arrive (the file header first); pcapng where the path
    ends in .pcapng."""

    def __init__(self, path: str | Path):
        try:
            self.fh = open(path, "wb")
        except OSError as exc:
            raise CivicError(f"cannot write {path}: {exc.strerror}") from exc
        self.ng = str(path).endswith(".pcapng")
        self.fh.write(PCAPNG_HEAD if self.ng else PCAP_HEADER)

    def write(self, times, frames, lengths=None) -> None:
        """Append frames (bytes-likes) captured at times (s); lengths: their lengths on the wire."""
        if self.ng:
            self.fh.write(packet_blocks(times, list(frames), lengths))
            self.fh.flush()
            return
        out = bytearray()
        for k, (t, frame) in enumerate(zip(times, frames)):
            us = round(float(t) * 1e6)
            wire = len(frame) if lengths is None else int(lengths[k])
            out += struct.pack("<IIII", us // 1_000_000, us % 1_000_000, len(frame), wire)
            out += frame
        self.fh.write(out)
        self.fh.flush()

    def close(self) -> None:
        self.fh.close()
