"""The plant's UDP control message (wire format v1) and fast pcap I/O.

Captures (classic pcap, or pcapng via `civic.pcapng`) are read into numpy arrays in bulk: no
per-packet Python object. Frames are Ethernet, or Linux cooked captures (`tcpdump -i any`),
which are viewed as Ethernet from 14 bytes before their IPv4 packet (`civic.links`).
`read_pcap` returns a `Capture` holding the file's bytes, each record's offset and a
structured array of decoded message fields; `Capture.write` writes it back byte-identical
except for patched verdicts and checksums.
`scapy_layer.PlantMessage` is the scapy twin, for crafting and dissecting.
"""
from __future__ import annotations

import ipaddress
import os
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from civic.errors import CivicError
from civic.links import LINKTYPE_ETHERNET, LINKTYPE_LINUX_SLL2, SLL2_ETHERTYPE, check_link, ethertypes, link_views
from civic.pcapng import PCAPNG_MAGIC, PcapNgBlocks, write_pcapng

DEFAULT_UDP_PORT = 50000
DEFAULT_PLANT_PREFIX = "10.0.0.0/24"
PAYLOAD_LEN = 20
UDP_LEN = 8 + PAYLOAD_LEN
ETH_LEN, IPV4_LEN = 14, 20
FRAME_LEN = ETH_LEN + IPV4_LEN + UDP_LEN  # 62 bytes: a plant message frame

# byte offsets inside an Ethernet frame carrying a plant message
OFF_IP = ETH_LEN
OFF_UDP = ETH_LEN + IPV4_LEN
OFF_UDP_CSUM = OFF_UDP + 6
OFF_PAYLOAD = OFF_UDP + 8
OFF_VERDICT = OFF_PAYLOAD + 18

SIGNALS = ("l1", "l2", "l3", "l4", "p1", "v1", "v2")
VERDICT_NAMES = {0: "not evaluated", 1: "normal", 2: "warning", 3: "error"}
CLASS_CODES = {"normal": 1, "warning": 2, "error": 3}
CLASS_NAMES = {v: k for k, v in CLASS_CODES.items()}
MAX_MONITORS = 8

PCAP_MAGICS = {  # magic as read little-endian -> (byte order, fraction per second)
    0xA1B2C3D4: ("<", 1_000_000),
    0xA1B23C4D: ("<", 1_000_000_000),
    0xD4C3B2A1: (">", 1_000_000),
    0x4D3CB2A1: (">", 1_000_000_000),
}
PCAP_HEADER = struct.pack("<IHHiIII", 0xA1B2C3D4, 2, 4, 0, 0, 262144, LINKTYPE_ETHERNET)   # what civic writes

MESSAGE_DTYPE = np.dtype([
    ("t", "f8"),          # capture time, seconds since the epoch
    ("plant", "?"),       # a plant message per docs/pipeline.md section 1
    ("src", "u4"),        # IPv4 source (0 for non-IPv4 frames)
    ("dport", "u2"),
    ("udp_csum", "u2"),
    ("seq", "u4"),
    ("l1", "u2"), ("l2", "u2"), ("l3", "u2"), ("l4", "u2"),
    ("p1", "u2"), ("v1", "u2"), ("v2", "u2"),
    ("verdict", "u2"),
])


def ip_to_int(text: str) -> int:
    try:
        return int(ipaddress.IPv4Address(text))
    except ValueError as exc:
        raise CivicError(f"not an IPv4 address: {text!r}") from exc


def int_to_ip(value: int) -> str:
    return str(ipaddress.IPv4Address(int(value)))


def plant_address(plant_prefix: str, slot: int) -> str:
    """The plant in a state slot: the prefix's /24 with the slot as last octet."""
    net = ipaddress.IPv4Network(plant_prefix, strict=False)
    return int_to_ip((int(net.network_address) & ~0xFF) | int(slot))


def parse_prefix(text: str) -> tuple[int, int]:
    """'10.0.0.0/24' -> (network, prefix length); the slot is the last octet."""
    try:
        net = ipaddress.IPv4Network(text, strict=True)
    except ValueError as exc:
        raise CivicError(f"bad plant prefix {text!r}: {exc}") from exc
    if net.prefixlen < 24:
        raise CivicError(f"plant prefix {text!r} must be /24 or longer (slot = last octet)")
    return int(net.network_address), net.prefixlen


@dataclass
class Capture:
    """A pcap file in memory: its bytes, where each frame is, and the decoded messages.

    Frames are patched in place (`set_verdicts`); writing gives the file back
    byte-identical except for what was patched.
    """

    data: bytearray                 # the whole file
    offset: np.ndarray              # int64 start of each frame's Ethernet view in `data`
    caplen: np.ndarray              # uint32 captured length of each frame's Ethernet view
    messages: np.ndarray            # MESSAGE_DTYPE, one row per record
    path: str = ""
    link: np.ndarray | None = None  # uint16 link type of each frame; None: all Ethernet

    def __len__(self) -> int:
        return len(self.offset)

    def frame(self, i: int) -> bytes:
        """Frame i as an Ethernet frame: a cooked capture's view, its ethertype in place."""
        out = bytes(self.data[self.offset[i]:self.offset[i] + self.caplen[i]])
        if self.link is not None and self.link[i] == LINKTYPE_LINUX_SLL2 and len(out) >= ETH_LEN:
            at = self.offset[i] + SLL2_ETHERTYPE
            out = out[:12] + bytes(self.data[at:at + 2]) + out[ETH_LEN:]
        return out

    def set_verdicts(self, verdict: np.ndarray) -> None:
        """Write verdicts into the plant messages, updating UDP checksums (RFC 1624)."""
        plant = self.messages["plant"]
        idx = None if plant.all() else np.flatnonzero(plant)
        pick = (lambda a: a) if idx is None else (lambda a: a[idx])
        new = pick(np.asarray(verdict, dtype=np.uint32))
        old = pick(self.messages["verdict"]).astype(np.uint32)
        csum = incremental_checksum(pick(self.messages["udp_csum"]), old, new)
        if idx is None:
            self.messages["udp_csum"], self.messages["verdict"] = csum, new
        else:
            self.messages["udp_csum"][idx], self.messages["verdict"][idx] = csum, new
        buf = np.frombuffer(self.data, dtype=np.uint8)
        off = pick(self.offset)
        for base, values in ((OFF_VERDICT, new), (OFF_UDP_CSUM, csum)):
            buf[off + base] = (values >> 8) & 0xFF
            buf[off + base + 1] = values & 0xFF

    def to_bytes(self) -> bytes:
        return bytes(self.data)

    def write(self, path: str | Path) -> None:
        Path(path).write_bytes(self.data)


def incremental_checksum(csum, old, new):
    """RFC 1624 eq. 3 for one 16-bit word change; 0 (no checksum) stays 0."""
    csum = np.asarray(csum, dtype=np.uint32)
    s = ((~csum) & 0xFFFF) + ((~np.asarray(old, dtype=np.uint32)) & 0xFFFF) + np.asarray(new, dtype=np.uint32)
    s = (s & 0xFFFF) + (s >> 16)
    s = (s & 0xFFFF) + (s >> 16)
    out = (~s) & 0xFFFF
    out = np.where(out == 0, 0xFFFF, out)
    return np.where(csum == 0, 0, out).astype(np.uint16)


def even_step(positions: np.ndarray) -> int:
    """The distance between evenly spaced positions (equal-sized records back to back, the
    usual capture), 0 when there are fewer than two or they are not evenly spaced."""
    n = len(positions)
    if n < 2:
        return 0
    step = int(positions[1] - positions[0])
    return step if step > 0 and bool(np.all(np.diff(positions) == step)) else 0


def _u32_at(arr: np.ndarray, positions: np.ndarray, order: str) -> np.ndarray:
    """The 32-bit unsigned integers at byte positions, in the file's byte order (a strided view
    where the positions are evenly spaced)."""
    step = even_step(positions)
    if step >= 4:
        return np.ndarray((len(positions),), order + "u4", arr, int(positions[0]), (step,)).astype(np.uint32)
    return np.ascontiguousarray(arr[positions[:, None] + np.arange(4)]).view(order + "u4").ravel()


def record_offsets(raw, order: str, start: int, path: str, final: bool = True,
                   base: int = 0) -> tuple[np.ndarray, np.ndarray, int]:
    """(record offsets, caplens, end) of the records in raw[start:]; runs of equal-length records
    are found vectorized. A record cut off at the end is an error when `final`, else where the
    scan stops (`end`). `base`: raw's offset in the file, for error messages."""
    size = len(raw)
    arr = np.frombuffer(raw, dtype=np.uint8)
    len_fmt = order + "I"
    offsets: list[np.ndarray] = []
    pos = start
    look = 64
    while pos < size:
        if size - pos < 16:
            if not final:
                break
            raise CivicError(f"{path}: truncated pcap: {size - pos} stray bytes at offset {base + pos}")
        (cap,) = struct.unpack_from(len_fmt, raw, pos + 8)
        if cap > 0x40000:
            raise CivicError(f"{path}: corrupt pcap: record at offset {base + pos} claims {cap} bytes")
        if pos + 16 + cap > size:
            if not final:
                break
            raise CivicError(f"{path}: truncated pcap: record at offset {base + pos} needs {cap} bytes, "
                             f"{size - pos - 16} remain")
        step = 16 + cap
        k = min(look, (size - pos) // step)
        lens = np.ndarray((k,), order + "u4", arr, pos + 8, (step,))
        bad = np.flatnonzero(lens != cap)
        good = int(bad[0]) if len(bad) else k
        offsets.append(pos + step * np.arange(good, dtype=np.int64))
        pos += good * step
        look = look * 2 if good == k else 64
    if not offsets:
        return np.zeros(0, np.int64), np.zeros(0, np.uint32), pos
    rec = np.concatenate(offsets)
    return rec, _u32_at(arr, rec + 8, order), pos


def record_times(arr: np.ndarray, rec: np.ndarray, order: str, frac: int) -> np.ndarray:
    """Capture time (s) of the records at offsets rec."""
    return _u32_at(arr, rec, order) + _u32_at(arr, rec + 4, order) / frac


def is_pcapng(head) -> bool:
    """A file that starts with a pcapng Section Header Block (`civic.pcapng` reads it)."""
    return len(head) >= 4 and struct.unpack_from("<I", head)[0] == PCAPNG_MAGIC


def pcap_header(head: bytes, path: str) -> tuple[str, int, int]:
    """(byte order, fraction per second, link type) of a classic pcap's file header; errors are one line."""
    if len(head) < 24:
        raise CivicError(f"{path}: not a pcap file (only {len(head)} bytes)")
    (magic,) = struct.unpack_from("<I", head)
    if magic not in PCAP_MAGICS:
        raise CivicError(f"{path}: not a pcap file (magic 0x{magic:08x})")
    order, frac = PCAP_MAGICS[magic]
    linktype = struct.unpack_from(order + "I", head, 20)[0] & 0x0FFFFFFF
    check_link(linktype, path)
    return order, frac, linktype


# the first FRAME_LEN bytes of a frame, as big-endian fields at their byte offsets
HEAD_DTYPE = np.dtype({
    "names": ["ethertype", "ver_ihl", "flags_frag", "proto", "src", "dport", "udp_len", "udp_csum",
              "seq", *SIGNALS, "verdict"],
    "formats": [">u2", "u1", ">u2", "u1", ">u4", ">u2", ">u2", ">u2", ">u4"] + [">u2"] * 8,
    "offsets": [12, OFF_IP, OFF_IP + 6, OFF_IP + 9, OFF_IP + 12, OFF_UDP + 2, OFF_UDP + 4, OFF_UDP_CSUM,
                OFF_PAYLOAD] + [OFF_PAYLOAD + 4 + 2 * j for j in range(8)],
    "itemsize": FRAME_LEN,
})


def frame_heads(buf: np.ndarray, offset: np.ndarray, caplen: np.ndarray) -> np.ndarray:
    """Every frame's first FRAME_LEN bytes viewed as HEAD_DTYPE; bytes past caplen read zeros."""
    n = len(offset)
    complete = bool(np.all(caplen >= FRAME_LEN))
    step = even_step(offset) if complete else 0
    if step >= FRAME_LEN:
        # equal-sized records back to back (the usual capture): a zero-copy strided view
        return np.ndarray(shape=(n,), dtype=HEAD_DTYPE, buffer=buf, offset=int(offset[0]), strides=(step,))
    idx = np.minimum(offset[:, None] + np.arange(FRAME_LEN), len(buf) - 1)
    head = buf[idx]
    if not complete:
        head *= np.arange(FRAME_LEN)[None, :] < caplen[:, None]
    return head.view(HEAD_DTYPE).reshape(n)


def frame_kinds(head: np.ndarray, caplen: np.ndarray, udp_port: int, plant_prefix: str,
                ethertype: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(ipv4, udp, plant) masks of frames from their heads: the parser's checks (pipeline.md 1).
    `ethertype`: where it is not in the heads (`ethertypes`)."""
    ethertype = head["ethertype"] if ethertype is None else ethertype
    ipv4 = (caplen >= ETH_LEN + IPV4_LEN) & (ethertype == 0x0800) & (head["ver_ihl"] == 0x45)
    udp = ipv4 & (head["proto"] == 17) & ((head["flags_frag"] & 0x3FFF) == 0) & (caplen >= OFF_UDP + 8)
    net, plen = parse_prefix(plant_prefix)
    mask = (0xFFFFFFFF << (32 - plen)) & 0xFFFFFFFF
    plant = (udp & (head["dport"] == udp_port) & (head["udp_len"] == UDP_LEN) & (caplen >= FRAME_LEN)
             & ((head["src"] & mask) == net))
    return ipv4, udp, plant


def decode_frames(data, offset: np.ndarray, caplen: np.ndarray, udp_port: int = DEFAULT_UDP_PORT,
                  plant_prefix: str = DEFAULT_PLANT_PREFIX, link: np.ndarray | None = None) -> np.ndarray:
    """Decode the plant-message fields of every frame (docs/pipeline.md section 1); offset and
    caplen are the frames' Ethernet views, link their link types (None: all Ethernet)."""
    n = len(offset)
    msg = np.zeros(n, dtype=MESSAGE_DTYPE)
    if n == 0:
        return msg
    buf = np.frombuffer(data, dtype=np.uint8)
    head = frame_heads(buf, offset, caplen)
    ipv4, udp, plant = frame_kinds(head, caplen, udp_port, plant_prefix, ethertypes(head, buf, offset, link))
    msg["plant"] = plant
    if plant.all():
        msg["src"], msg["dport"] = head["src"], head["dport"]
        for name in ("udp_csum", "seq", *SIGNALS, "verdict"):
            msg[name] = head[name]
        return msg
    msg["src"] = np.where(ipv4, head["src"], 0)
    msg["dport"] = np.where(udp, head["dport"], 0)
    for name in ("udp_csum", "seq", *SIGNALS, "verdict"):
        msg[name] = np.where(plant, head[name], 0)
    return msg


def read_pcap(path: str | Path, udp_port: int = DEFAULT_UDP_PORT,
              plant_prefix: str = DEFAULT_PLANT_PREFIX) -> Capture:
    """Read a pcap or pcapng capture (Ethernet or Linux cooked) into a Capture, without scapy."""
    path = str(path)
    try:
        with open(path, "rb") as fh:
            data = bytearray(os.fstat(fh.fileno()).st_size)
            data = data[:fh.readinto(data)]
    except OSError as exc:
        raise CivicError(f"cannot read {path}: {exc.strerror}") from exc
    if is_pcapng(data):
        offset, caplen, t, link, _ = PcapNgBlocks(path).walk(memoryview(data))
    else:
        order, frac, linktype = pcap_header(bytes(data[:24]), path)
        rec, caplen, _ = record_offsets(memoryview(data), order, 24, path)
        offset, caplen, link = link_views(rec + 16, caplen, linktype)
        t = record_times(np.frombuffer(data, np.uint8), rec, order, frac)
    messages = decode_frames(data, offset, caplen, udp_port, plant_prefix, link)
    messages["t"] = t
    return Capture(data=data, offset=offset, caplen=caplen, messages=messages, path=path, link=link)


def ipv4_checksum(headers: np.ndarray) -> np.ndarray:
    """Internet checksum of (n, 20) IPv4 header bytes with the checksum field zeroed."""
    words = headers[:, 0::2].astype(np.uint32) << 8 | headers[:, 1::2].astype(np.uint32)
    s = words.sum(axis=1)
    while np.any(s >> 16):
        s = (s & 0xFFFF) + (s >> 16)
    return (~s & 0xFFFF).astype(np.uint16)


def udp_checksum(src: np.ndarray, dst: np.ndarray, udp: np.ndarray) -> np.ndarray:
    """UDP checksum over the IPv4 pseudo-header and (n, 28) UDP header+payload bytes."""
    words = udp[:, 0::2].astype(np.uint64) << 8 | udp[:, 1::2].astype(np.uint64)
    s = words.sum(axis=1) + (src >> 16) + (src & 0xFFFF) + (dst >> 16) + (dst & 0xFFFF) + 17 + udp.shape[1]
    while np.any(s >> 16):
        s = (s & 0xFFFF) + (s >> 16)
    out = (~s & 0xFFFF).astype(np.uint16)
    return np.where(out == 0, 0xFFFF, out).astype(np.uint16)


def build_frames(fields: dict, src_ip="10.0.0.1", dst_ip="10.0.0.2", sport=50001,
                 dport=DEFAULT_UDP_PORT, seq0: int = 0, ip_id0: int = 0) -> np.ndarray:
    """Plant-message frames (n, 62) from per-message field arrays (l1..v2, optional seq/verdict).

    Values must already be integers in wire units; out-of-range values are an error,
    never wrapped.
    """
    n = len(next(iter(fields.values())))
    for name in SIGNALS:
        v = np.asarray(fields.get(name, np.zeros(n)))
        if len(v) != n:
            raise CivicError(f"field {name}: {len(v)} values, expected {n}")
        if np.any(v < 0) or np.any(v > 0xFFFF):
            raise CivicError(f"field {name}: values outside 0..65535 cannot be sent")
    src = np.full(n, ip_to_int(src_ip), dtype=np.uint64) if isinstance(src_ip, str) else np.asarray(src_ip, np.uint64)
    dst = np.uint64(ip_to_int(dst_ip))
    f = np.zeros((n, FRAME_LEN), dtype=np.uint8)
    f[:, 0:6] = [0x02, 0, 0, 0, 0, 0x02]
    f[:, 6:12] = [0x02, 0, 0, 0, 0, 0x01]
    f[:, 12:14] = [0x08, 0x00]
    ip = f[:, OFF_IP:OFF_IP + 20]
    ip[:, 0] = 0x45
    ip[:, 3] = IPV4_LEN + UDP_LEN
    ip_id = (ip_id0 + np.arange(n)) & 0xFFFF
    ip[:, 4], ip[:, 5] = ip_id >> 8, ip_id & 0xFF
    ip[:, 6] = 0x40  # don't fragment
    ip[:, 8], ip[:, 9] = 64, 17
    for k in range(4):
        ip[:, 12 + k] = (src >> np.uint64(24 - 8 * k)) & np.uint64(0xFF)
        ip[:, 16 + k] = (int(dst) >> (24 - 8 * k)) & 0xFF
    c = ipv4_checksum(ip)
    ip[:, 10], ip[:, 11] = c >> 8, c & 0xFF
    u = f[:, OFF_UDP:OFF_UDP + UDP_LEN]
    u[:, 0], u[:, 1] = sport >> 8, sport & 0xFF
    u[:, 2], u[:, 3] = dport >> 8, dport & 0xFF
    u[:, 5] = UDP_LEN
    seq = np.asarray(fields["seq"], dtype=np.uint64) if "seq" in fields else (seq0 + np.arange(n, dtype=np.uint64)) & np.uint64(0xFFFFFFFF)
    for k in range(4):
        u[:, 8 + k] = (seq >> np.uint64(24 - 8 * k)) & np.uint64(0xFF)
    for j, name in enumerate(SIGNALS + ("verdict",)):
        v = np.asarray(fields.get(name, np.zeros(n)), dtype=np.int64)
        u[:, 12 + 2 * j], u[:, 13 + 2 * j] = v >> 8, v & 0xFF
    c = udp_checksum(src, np.full(n, dst, np.uint64), u)
    u[:, 6], u[:, 7] = c >> 8, c & 0xFF
    return f


def write_pcap(path: str | Path, t: np.ndarray, frames) -> None:
    """Write frames (an (n, k) uint8 array or a list of bytes) with times t (s) as a microsecond pcap,
    or as pcapng where the path ends in .pcapng."""
    if str(path).endswith(".pcapng"):
        write_pcapng(path, t, frames)
        return
    t = np.asarray(t, dtype=np.float64)
    us = np.round(t * 1e6).astype(np.int64)
    sec, frac = us // 1_000_000, us % 1_000_000
    header = PCAP_HEADER
    if isinstance(frames, np.ndarray):
        n, k = frames.shape
        rec = np.zeros((n, 16 + k), dtype=np.uint8)
        hdr = np.stack([sec, frac, np.full(n, k), np.full(n, k)], axis=1).astype("<u4")
        rec[:, :16] = hdr.view(np.uint8).reshape(n, 16)
        rec[:, 16:] = frames
        body = rec.tobytes()
    else:
        body = b"".join(struct.pack("<IIII", int(s), int(fr), len(b), len(b)) + bytes(b)
                        for s, fr, b in zip(sec, frac, frames))
    Path(path).write_bytes(header + body)


def monitor_verdict(verdict: np.ndarray, m: int) -> np.ndarray:
    """Monitor m's 2-bit code from 16-bit verdict words."""
    return (np.asarray(verdict) >> (2 * m)) & 0x3
