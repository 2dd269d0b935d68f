"""The plant's UDP control message (wire format v1) and fast pcap I/O.

Captures are read into numpy arrays in bulk: no per-packet Python object.
`read_pcap` returns a `Capture` holding the file's bytes, each record's
offset and a structured array of decoded message fields; `Capture.write`
writes it back byte-identical except for patched verdicts and checksums.
`scapy_layer.PlantMessage` is the scapy twin, for crafting and dissecting.
"""
from __future__ import annotations

import ipaddress
import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from civic.errors import CivicError

DEFAULT_UDP_PORT = 50000
DEFAULT_PLANT_PREFIX = "10.0.0.0/24"
PAYLOAD_LEN = 20
UDP_LEN = 8 + PAYLOAD_LEN
ETH_LEN, IPV4_LEN = 14, 20
FRAME_LEN = ETH_LEN + IPV4_LEN + UDP_LEN  # 62 bytes: a plant message frame

# byte offsets inside an Ethernet frame carrying a plant message
OFF_ETHERTYPE = 12
OFF_IP = ETH_LEN
OFF_UDP = ETH_LEN + IPV4_LEN
OFF_UDP_CSUM = OFF_UDP + 6
OFF_PAYLOAD = OFF_UDP + 8
OFF_VERDICT = OFF_PAYLOAD + 18

SIGNALS = ("l1", "l2", "l3", "l4", "p1", "v1", "v2")
FIELD_MAX = {"l1": 65535, "l2": 65535, "l3": 65535, "l4": 65535, "p1": 1000, "v1": 1000, "v2": 1000}
VERDICT_NAMES = {0: "not evaluated", 1: "normal", 2: "warning", 3: "error"}
CLASS_CODES = {"normal": 1, "warning": 2, "error": 3}
MAX_MONITORS = 8

PCAP_MAGICS = {  # magic as read little-endian -> (byte order, fraction per second)
    0xA1B2C3D4: ("<", 1_000_000),
    0xA1B23C4D: ("<", 1_000_000_000),
    0xD4C3B2A1: (">", 1_000_000),
    0x4D3CB2A1: (">", 1_000_000_000),
}
PCAPNG_MAGIC = 0x0A0D0D0A
LINKTYPE_ETHERNET = 1

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
    """A pcap file in memory: raw bytes, record layout and decoded messages."""

    header: bytes
    data: bytearray                 # every record's frame bytes, back to back
    rec_header: np.ndarray          # (n, 16) uint8, the per-record pcap headers
    offset: np.ndarray              # int64 start of each frame in `data`
    caplen: np.ndarray              # uint32 captured length of each frame
    messages: np.ndarray            # MESSAGE_DTYPE, one row per record
    path: str = ""
    frac_per_s: int = 1_000_000
    extra: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.offset)

    def frame(self, i: int) -> bytes:
        return bytes(self.data[self.offset[i]:self.offset[i] + self.caplen[i]])

    def set_verdicts(self, verdict: np.ndarray) -> None:
        """Write verdicts into the plant messages, updating UDP checksums (RFC 1624)."""
        idx = np.flatnonzero(self.messages["plant"])
        new = np.asarray(verdict, dtype=np.uint32)[idx]
        old = self.messages["verdict"][idx].astype(np.uint32)
        csum = self.messages["udp_csum"][idx].astype(np.uint32)
        self.messages["udp_csum"][idx] = incremental_checksum(csum, old, new)
        self.messages["verdict"][idx] = new
        buf = np.frombuffer(self.data, dtype=np.uint8)
        off = self.offset[idx]
        for base, values in ((OFF_VERDICT, new), (OFF_UDP_CSUM, self.messages["udp_csum"][idx])):
            buf[off + base] = (values >> 8) & 0xFF
            buf[off + base + 1] = values & 0xFF

    def to_bytes(self) -> bytes:
        if len(self) == 0:
            return self.header
        n = len(self)
        lens = 16 + self.caplen.astype(np.int64)
        out = np.empty(int(lens.sum()), dtype=np.uint8)
        starts = np.concatenate(([0], np.cumsum(lens)[:-1]))
        hdr_pos = starts[:, None] + np.arange(16)
        out[hdr_pos] = self.rec_header
        src = np.frombuffer(self.data, dtype=np.uint8)
        if np.all(self.caplen == self.caplen[0]):
            c = int(self.caplen[0])
            out.reshape(n, 16 + c)[:, 16:] = src[self.offset[:, None] + np.arange(c)]
        else:
            for i in range(n):  # variable-length frames: one memcpy each
                s, c = int(starts[i]) + 16, int(self.caplen[i])
                out[s:s + c] = src[self.offset[i]:self.offset[i] + c]
        return self.header + out.tobytes()

    def write(self, path: str | Path) -> None:
        Path(path).write_bytes(self.to_bytes())


def incremental_checksum(csum, old, new):
    """RFC 1624 eq. 3 for one 16-bit word change; 0 (no checksum) stays 0."""
    csum = np.asarray(csum, dtype=np.uint32)
    s = ((~csum) & 0xFFFF) + ((~np.asarray(old, dtype=np.uint32)) & 0xFFFF) + np.asarray(new, dtype=np.uint32)
    s = (s & 0xFFFF) + (s >> 16)
    s = (s & 0xFFFF) + (s >> 16)
    out = (~s) & 0xFFFF
    out = np.where(out == 0, 0xFFFF, out)
    return np.where(csum == 0, 0, out).astype(np.uint16)


def _record_offsets(raw: memoryview, order: str, start: int, path: str) -> tuple[np.ndarray, np.ndarray]:
    """Find every record: runs of equal-length records are found vectorized."""
    size = len(raw)
    arr = np.frombuffer(raw, dtype=np.uint8)
    len_fmt = order + "I"
    offsets: list[np.ndarray] = []
    pos = start
    look = 64
    while pos < size:
        if size - pos < 16:
            raise CivicError(f"{path}: truncated pcap: {size - pos} stray bytes at offset {pos}")
        (cap,) = struct.unpack_from(len_fmt, raw, pos + 8)
        if cap > 0x40000:
            raise CivicError(f"{path}: corrupt pcap: record at offset {pos} claims {cap} bytes")
        if pos + 16 + cap > size:
            raise CivicError(f"{path}: truncated pcap: record at offset {pos} needs {cap} bytes, "
                             f"{size - pos - 16} remain")
        step = 16 + cap
        k = min(look, (size - pos) // step)
        cand = pos + step * np.arange(k, dtype=np.int64)
        caps = arr[(cand + 8)[:, None] + np.arange(4)]
        if order == "<":
            vals = caps[:, 0] | (caps[:, 1].astype(np.uint32) << 8) | (caps[:, 2].astype(np.uint32) << 16) | (caps[:, 3].astype(np.uint32) << 24)
        else:
            vals = caps[:, 3] | (caps[:, 2].astype(np.uint32) << 8) | (caps[:, 1].astype(np.uint32) << 16) | (caps[:, 0].astype(np.uint32) << 24)
        bad = np.flatnonzero(vals != cap)
        good = int(bad[0]) if len(bad) else k
        offsets.append(cand[:good])
        pos += good * step
        look = look * 2 if good == k else 64
    if not offsets:
        return np.zeros(0, np.int64), np.zeros(0, np.uint32)
    rec = np.concatenate(offsets)
    caps = arr[(rec + 8)[:, None] + np.arange(4)].astype(np.uint32)
    if order == "<":
        caplen = caps[:, 0] | (caps[:, 1] << 8) | (caps[:, 2] << 16) | (caps[:, 3] << 24)
    else:
        caplen = caps[:, 3] | (caps[:, 2] << 8) | (caps[:, 1] << 16) | (caps[:, 0] << 24)
    return rec, caplen.astype(np.uint32)


def _be(cols: np.ndarray) -> np.ndarray:
    """Big-endian unsigned value from an (n, k) byte matrix."""
    out = np.zeros(cols.shape[0], dtype=np.uint64)
    for j in range(cols.shape[1]):
        out = (out << np.uint64(8)) | cols[:, j].astype(np.uint64)
    return out


def decode_frames(data, offset: np.ndarray, caplen: np.ndarray, udp_port: int = DEFAULT_UDP_PORT,
                  plant_prefix: str = DEFAULT_PLANT_PREFIX) -> np.ndarray:
    """Decode the plant-message fields of every frame (docs/pipeline.md section 1)."""
    n = len(offset)
    msg = np.zeros(n, dtype=MESSAGE_DTYPE)
    if n == 0:
        return msg
    buf = np.frombuffer(data, dtype=np.uint8)
    # gather the first FRAME_LEN bytes of every frame; short frames read zeros
    idx = offset[:, None] + np.arange(FRAME_LEN)
    present = np.arange(FRAME_LEN)[None, :] < caplen[:, None]
    head = np.zeros((n, FRAME_LEN), dtype=np.uint8)
    head[present] = buf[np.minimum(idx, len(buf) - 1)][present]
    ethertype = _be(head[:, 12:14])
    ihl = head[:, OFF_IP]
    flags_frag = _be(head[:, OFF_IP + 6:OFF_IP + 8])
    proto = head[:, OFF_IP + 9]
    ipv4 = (caplen >= ETH_LEN + IPV4_LEN) & (ethertype == 0x0800) & (ihl == 0x45)
    msg["src"] = np.where(ipv4, _be(head[:, OFF_IP + 12:OFF_IP + 16]), 0)
    dport = _be(head[:, OFF_UDP + 2:OFF_UDP + 4])
    udp_len = _be(head[:, OFF_UDP + 4:OFF_UDP + 6])
    udp = ipv4 & (proto == 17) & ((flags_frag & 0x3FFF) == 0) & (caplen >= OFF_UDP + 8)
    msg["dport"] = np.where(udp, dport, 0)
    net, plen = parse_prefix(plant_prefix)
    mask = (0xFFFFFFFF << (32 - plen)) & 0xFFFFFFFF
    in_prefix = (msg["src"].astype(np.uint64) & mask) == net
    plant = udp & (dport == udp_port) & (udp_len == UDP_LEN) & (caplen >= FRAME_LEN) & in_prefix
    msg["plant"] = plant
    msg["udp_csum"] = np.where(plant, _be(head[:, OFF_UDP_CSUM:OFF_UDP_CSUM + 2]), 0)
    msg["seq"] = np.where(plant, _be(head[:, OFF_PAYLOAD:OFF_PAYLOAD + 4]), 0)
    for j, name in enumerate(SIGNALS + ("verdict",)):
        o = OFF_PAYLOAD + 4 + 2 * j
        msg[name] = np.where(plant, _be(head[:, o:o + 2]), 0)
    return msg


def read_pcap(path: str | Path, udp_port: int = DEFAULT_UDP_PORT,
              plant_prefix: str = DEFAULT_PLANT_PREFIX) -> Capture:
    """Read a classic pcap (Ethernet link type) into a Capture, without scapy."""
    path = str(path)
    try:
        raw = Path(path).read_bytes()
    except OSError as exc:
        raise CivicError(f"cannot read {path}: {exc.strerror}") from exc
    if len(raw) < 24:
        if len(raw) >= 4 and struct.unpack_from("<I", raw)[0] == PCAPNG_MAGIC:
            raise CivicError(f"{path}: pcapng is not supported; convert it with 'editcap -F pcap'")
        raise CivicError(f"{path}: not a pcap file (only {len(raw)} bytes)")
    (magic,) = struct.unpack_from("<I", raw)
    if magic == PCAPNG_MAGIC:
        raise CivicError(f"{path}: pcapng is not supported; convert it with 'editcap -F pcap'")
    if magic not in PCAP_MAGICS:
        raise CivicError(f"{path}: not a pcap file (magic 0x{magic:08x})")
    order, frac = PCAP_MAGICS[magic]
    linktype = struct.unpack_from(order + "I", raw, 20)[0] & 0x0FFFFFFF
    if linktype != LINKTYPE_ETHERNET:
        raise CivicError(f"{path}: link type {linktype} is not Ethernet (1)")
    rec, caplen = _record_offsets(memoryview(raw), order, 24, path)
    arr = np.frombuffer(raw, dtype=np.uint8)
    rec_header = arr[rec[:, None] + np.arange(16)] if len(rec) else np.zeros((0, 16), np.uint8)
    data = bytearray(raw)
    offset = rec + 16
    messages = decode_frames(data, offset, caplen, udp_port, plant_prefix)
    ts = rec_header[:, 0:8].copy().view(order + "u4").reshape(-1, 2) if len(rec) else np.zeros((0, 2), np.uint32)
    messages["t"] = ts[:, 0].astype(np.float64) + ts[:, 1].astype(np.float64) / frac
    return Capture(header=raw[:24], data=data, rec_header=rec_header, offset=offset, caplen=caplen,
                   messages=messages, path=path, frac_per_s=frac)


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
    """Write frames (an (n, k) uint8 array or a list of bytes) with times t (s) as a microsecond pcap."""
    t = np.asarray(t, dtype=np.float64)
    us = np.round(t * 1e6).astype(np.int64)
    sec, frac = us // 1_000_000, us % 1_000_000
    header = struct.pack("<IHHiIII", 0xA1B2C3D4, 2, 4, 0, 0, 262144, LINKTYPE_ETHERNET)
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
