"""`civic monitor`: the streaming software switch on live frames from an interface.

Where a plant has no P4 switch, a mirror port or a tap carries the same messages: a raw
AF_PACKET socket receives every frame on the interface, frames are gathered in batches (up
to BATCH, or what has arrived when the socket runs dry), and each batch goes through one
`StreamingSwitch`, registers carried from batch to batch, so the verdicts and changes are
those of `civic replay --target model` on the same frames. What it knows is a `WatchState`,
so `civic watch`'s table, events, metrics and plot serve it unchanged.
"""
from __future__ import annotations

import select
import socket
import time

import numpy as np

from civic.entries import Entries
from civic.errors import CivicError
from civic.events import event
from civic.pcap_chunks import PcapWriter
from civic.pipeline.stream import StreamingSwitch, changes
from civic.watch import WatchState, publish
from civic.wire import frame_heads, frame_kinds, int_to_ip, plant_address

ETH_P_ALL = 0x0003
SOL_PACKET, PACKET_STATISTICS, PACKET_IGNORE_OUTGOING = 263, 6, 23
SO_RCVBUFFORCE = 33             # <linux/socket.h>; Python's socket module lacks the name
SNAP = 2048                    # bytes kept per frame: a whole Ethernet frame
BATCH = 1024                   # frames per kernel call at most
RCVBUF = 64 << 20              # socket buffer: bursts wait here while a batch is processed
COUNTS_EVERY_S = 1.0


def open_capture(iface: str) -> socket.socket:
    """A non-blocking raw socket receiving every frame arriving on iface; one-line errors."""
    if iface == "any":
        # tcpdump's pseudo-device sees a frame once on every interface it crosses (a bridge and
        # its port, both ends of a veth): each copy would be judged as a message of its own
        raise CivicError("cannot capture on 'any': name the one interface the plant's messages arrive on "
                         "(a frame crossing several interfaces would be counted once on each)")
    try:
        sock = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, socket.htons(ETH_P_ALL))
    except PermissionError:
        raise CivicError("capturing frames needs root or CAP_NET_RAW") from None
    try:
        sock.bind((iface, ETH_P_ALL))
    except OSError as exc:
        sock.close()
        raise CivicError(f"cannot capture on {iface!r}: {exc.strerror}") from None
    try:                       # frames this host sends on iface are not the plant's
        sock.setsockopt(SOL_PACKET, PACKET_IGNORE_OUTGOING, 1)
    except OSError:
        pass
    try:
        sock.setsockopt(socket.SOL_SOCKET, SO_RCVBUFFORCE, RCVBUF)
    except OSError:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RCVBUF)
    sock.setblocking(False)
    return sock


class Monitor:
    """One capture session: frames in, verdicts, events and counts out."""

    def __init__(self, iface: str, entries: Entries, events_file=None, write: str | None = None,
                 on_event=None):
        self.address = iface
        self.entries = entries
        self.names = [m.name for m in entries.monitors]
        self.state = WatchState(list(self.names))
        self.switch = StreamingSwitch(entries)
        self.events_file, self.on_event = events_file, on_event
        self.writer = PcapWriter(write) if write else None
        self.sock = open_capture(iface)
        self.state.switch_up = True            # civic_switch_up: the capture is running
        self.buf = np.zeros(BATCH * SNAP, np.uint8)
        self.views = [memoryview(self.buf)[i * SNAP:(i + 1) * SNAP] for i in range(BATCH)]
        self.offset = np.arange(BATCH, dtype=np.int64) * SNAP
        self.frames = self.plant_messages = self.dropped = 0
        self._seen: set[int] = set()             # plant sources seen
        self._counts_at = 0.0

    def poll(self, wait: float) -> None:
        """Process what arrives within `wait` s, batch by batch."""
        deadline = time.monotonic() + wait
        while True:
            n, lengths, times = self._receive()
            if n:
                self._process(n, lengths, times)
            left = deadline - time.monotonic()
            if left <= 0:
                break
            if n < BATCH:
                select.select([self.sock], [], [], left)
        if time.monotonic() - self._counts_at >= COUNTS_EVERY_S:
            self.update_counts()
            self.dropped += self.drops()

    def _receive(self) -> tuple[int, np.ndarray, list[float]]:
        """Up to BATCH frames that are waiting: (how many, their lengths on the wire, their times)."""
        lengths = np.zeros(BATCH, np.int64)
        times = []
        recv = self.sock.recv_into
        n = 0
        while n < BATCH:
            try:
                lengths[n] = recv(self.views[n], SNAP, socket.MSG_TRUNC)
            except BlockingIOError:
                break
            times.append(time.time())
            n += 1
        return n, lengths[:n], times

    def _process(self, n: int, lengths: np.ndarray, times: list[float]) -> None:
        caplen = np.minimum(lengths, SNAP).astype(np.uint32)
        offset = self.offset[:n]
        heads = frame_heads(self.buf, offset, caplen)
        plant = frame_kinds(heads, caplen, self.entries.udp_port, self.entries.plant_prefix)[2]
        rows = self.switch.process(self.buf, offset, plant)
        self._note_plants(heads["src"][plant.astype(bool)])
        self.frames += n
        self.plant_messages += int(np.count_nonzero(plant))
        if self.writer is not None:
            self.writer.write(times, (self.views[i][:caplen[i]] for i in range(n)), lengths)
        if len(rows):
            now = time.time()
            self.state.last_digest = now          # a verdict change: what a digest would say
            for c in changes(rows, heads["src"], heads["seq"]):
                publish(self.state, event(c, times[c.index], self.names), now, self.events_file, self.on_event)

    def _note_plants(self, sources: np.ndarray) -> None:
        """A plant is in the state (class none) from its first message, before its first verdict."""
        for src in np.unique(sources):
            if int(src) not in self._seen:
                self._seen.add(int(src))
                for name in self.names:
                    self.state.cell(int_to_ip(int(src)), name)

    def update_counts(self) -> None:
        """The verdict counters of every plant seen, into the state."""
        counts = self.switch.counts
        for m, name in enumerate(self.names):
            for slot in np.flatnonzero(counts[m].sum(axis=1)):
                self.state.apply_counts(plant_address(self.entries.plant_prefix, slot), name,
                                        {k: int(counts[m, slot, k]) for k in (1, 2, 3)})
        self._counts_at = time.monotonic()

    def drops(self) -> int:
        """Frames the kernel dropped for want of buffer since the last call (PACKET_STATISTICS)."""
        raw = self.sock.getsockopt(SOL_PACKET, PACKET_STATISTICS, 8)
        return int.from_bytes(raw[4:8], "little")

    def close(self) -> None:
        self.update_counts()
        self.dropped += self.drops()
        self.sock.close()
        self.state.switch_up = False
        if self.writer is not None:
            self.writer.close()
