"""Crafted frames for bad-input and pass-through tests (scapy, independent of civic.wire)."""
from __future__ import annotations

import copy
import struct
from pathlib import Path

import numpy as np

from scapy.layers.inet import IP, UDP
from scapy.layers.inet6 import IPv6
from scapy.layers.l2 import ARP, CookedLinux, CookedLinuxV2, Ether
from scapy.packet import Raw
from scapy.utils import rdpcap, wrpcap

from civic.scapy_layer import PlantMessage
from civic.wire import OFF_PAYLOAD, OFF_UDP_CSUM, SIGNALS, build_frames, read_pcap, write_pcap

LEAK_CASE = Path(__file__).resolve().parents[1] / "traces" / "diagnose" / "example_leak_t3" / "case.pcap"


def plant(src="10.0.0.1", seq=1, l3=7000, dport=50000, **fields):
    msg = PlantMessage(seq=seq, l3=l3, **fields)
    return Ether(src="02:00:00:00:00:01", dst="02:00:00:00:00:02") / IP(src=src, dst="10.0.0.2") / \
        UDP(sport=50001, dport=dport) / msg


def junk_frames() -> list[bytes]:
    """Frames a switch must pass untouched: none of them is a plant message."""
    base = Ether(src="02:00:00:00:00:01", dst="02:00:00:00:00:02")
    return [
        bytes(base / ARP(psrc="10.0.0.1", pdst="10.0.0.2")),
        bytes(base / IPv6(src="fe80::1", dst="fe80::2") / UDP(sport=50001, dport=50000) / Raw(b"x" * 20)),
        bytes(base / IP(src="10.0.0.1", dst="10.0.0.2") / UDP(sport=50001, dport=50000) / Raw(b"\x00" * 19)),
        bytes(base / IP(src="10.0.0.1", dst="10.0.0.2") / UDP(sport=50001, dport=50000) / Raw(b"\x00" * 21)),
        bytes(plant(dport=50001)),
        bytes(plant(src="192.168.7.1")),
        bytes(base / IP(src="10.0.0.1", dst="10.0.0.2", options=[b"\x01\x01\x01\x01"]) /
              UDP(sport=50001, dport=50000) / PlantMessage(seq=1)),
        bytes(base / IP(src="10.0.0.1", dst="10.0.0.2", flags="MF") / UDP(sport=50001, dport=50000) / PlantMessage()),
        bytes(plant())[:50],  # truncated capture of a plant message
        bytes(base / IP(src="10.0.0.1", dst="10.0.0.2", proto=6) / Raw(b"\x00" * 28)),
    ]


def interleave(paths, tmp_path, junk=True, name="mixed.pcap"):
    """Several recordings as plants 10.0.0.1, .2, ... in one capture, junk frames in between. An
    item may be a list: that plant runs those recordings one after the other, its sequence
    numbers going on, the r-th starting r * (the longest recording + 1 s) after the first."""
    runs = [[read_pcap(p) for p in (item if isinstance(item, (list, tuple)) else [item])] for item in paths]
    period = max(c.messages["t"][-1] - c.messages["t"][0] for run in runs for c in run) + 1.0
    frames, times = [], []
    for k, run in enumerate(runs):
        last_seq = None
        for r, cap in enumerate(run):
            fields = {s: cap.messages[s] for s in SIGNALS + ("seq",)}
            if last_seq is not None:
                fields["seq"] = (last_seq + 1 + np.arange(len(cap))) % (1 << 32)
            last_seq = int(fields["seq"][-1])
            f = build_frames(fields, src_ip=f"10.0.0.{k + 1}")
            frames += [row.tobytes() for row in f]
            times += list(cap.messages["t"] - cap.messages["t"][0] + run[0].messages["t"][0] + r * period + 0.01 * k)
    order = np.argsort(times, kind="stable")
    frames = [frames[i] for i in order]
    times = [times[i] for i in order]
    if junk:
        extra = junk_frames()
        for j, fr in enumerate(extra):
            pos = (j * 37) % len(frames)
            frames.insert(pos, fr)
            times.insert(pos, times[pos])
    out = tmp_path / name
    write_pcap(out, np.array(times), frames)
    return out


def edge_frames() -> list[bytes]:
    """Frames at the edges of the contract (docs/pipeline.md section 1), beyond junk_frames()."""
    from scapy.layers.inet import TCP
    from scapy.layers.l2 import Dot1Q

    base = Ether(src="02:00:00:00:00:01", dst="02:00:00:00:00:02")
    ip = IP(src="10.0.0.1", dst="10.0.0.2")
    udp = UDP(sport=50001, dport=50000)
    short = bytes(base / ip / udp / Raw(b"\x01\x02\x03\x04"))                      # 46 bytes
    full = bytes(PlantMessage(seq=7, l3=6000, v2=1000))
    ffff = PlantMessage(seq=0xFFFFFFFF, l1=0xFFFF, l2=0xFFFF, l3=0xFFFF, l4=0xFFFF, p1=0xFFFF, v1=0xFFFF,
                        v2=0xFFFF, verdict=0xFFFF)
    return [
        bytes(base / ip / TCP(sport=50001, dport=50000) / Raw(full)),               # TCP
        short,                                                                     # short payload, unpadded
        short + b"\x00" * (60 - len(short)),                                       # same, Ethernet padding
        bytes(base / ip / udp / Raw(full[:10])) + b"\x00" * 8,                     # 10-byte payload, padded
        bytes(base / IP(src="10.0.0.3", dst="10.0.0.2", len=20 + 28 + 6) /         # UDP length 28 inside a
              UDP(sport=50001, dport=50000, len=28) / Raw(full + b"\xaa" * 6)),    # longer IP datagram
        bytes(base / ip / UDP(sport=50001, dport=50000, len=36) / Raw(full + b"\xbb" * 8)),  # UDP len 36
        bytes(base / ip / UDP(sport=50001, dport=9999) / PlantMessage(seq=8)),       # other port
        bytes(base / IP(src="10.0.0.2", dst="10.0.0.1") / UDP(sport=50000, dport=50001) /
              PlantMessage(seq=9, l3=6000)),                                       # reverse direction
        bytes(base / IP(src="10.0.0.200", dst="10.0.0.2") / udp / ffff),            # look-alike, in prefix
        bytes(base / IP(src="10.0.1.200", dst="10.0.0.2") / udp / ffff),            # look-alike, outside
        bytes(base / IP(src="10.0.0.201", dst="10.0.0.2") / UDP(sport=50001, dport=50000, chksum=0) / ffff),
        bytes(base / Dot1Q(vlan=5) / ip / udp / PlantMessage(seq=10)),               # VLAN tag
        bytes(base / ip / udp / Raw(b"j" * 20000)),                                 # jumbo datagram
        bytes(plant(src="10.0.0.202", seq=11, l3=5000)) + b"\xcc" * 9000,           # jumbo trailer
    ]


def sequence_edges(src="10.0.0.9") -> list[bytes]:
    """One plant's drain-like messages across the 32-bit wrap-around, with gaps and a repeat; L2
    sweeps 0..65535 so that aux = max(L2 - L3, 0) is 0 (saturated) and hits every compensate range."""
    seqs = ([0xFFFFFFFF - 24 + i for i in range(25)] + list(range(0, 30))      # wrap: no gap
            + list(range(33, 60)) + [59] + list(range(60, 90)))                # a gap, a repeated seq
    return [bytes(plant(src=src, seq=s, l3=7000 - 25 * i, v2=1000, l2=(i * i * 7) % 65536, l1=2000, l4=20000))
            for i, s in enumerate(seqs)]


def changing_fleet(path, plants: int = 8, gap_s: float = 20.0):
    """`plants` gateways 10.0.0.1.. in one capture, each replaying three bundled drain recordings of
    different classes one after the other (the class rotates per plant), so every plant's verdict
    changes twice; messages interleaved in time. Returns the path."""
    from data import TRAINING

    runs = ["drain_v075_normal_r1", "drain_v075_warning_r2", "drain_v075_error_r3"]
    frames, times = [], []
    for k in range(plants):
        order = runs[k % 3:] + runs[:k % 3]
        seq = 1000 * k
        for j, name in enumerate(order):
            msgs = read_pcap(TRAINING / f"{name}.pcap").messages
            fields = {c: msgs[c] for c in ("l1", "l2", "l3", "l4", "p1", "v1", "v2")}
            frames.extend(build_frames(fields, src_ip=f"10.0.0.{k + 1}", seq0=seq))
            times.extend(msgs["t"] - msgs["t"][0] + j * gap_s + k * 0.1 / plants)
            seq += len(msgs) + 5                          # a sequence gap between the runs
    order = np.argsort(np.asarray(times), kind="stable")
    write_pcap(path, 1_767_225_600 + np.asarray(times)[order], [bytes(frames[i]) for i in order])
    return path


def cooked(src, dst, version: int = 1) -> None:
    """An Ethernet capture as `tcpdump -i any` writes it: Linux cooked (SLL, or SLL2 for version 2)
    headers carrying the same payloads at the same times (scapy, independent of civic)."""
    out = []
    for pkt in rdpcap(str(src)):
        header = (CookedLinux(pkttype=4, lladdrtype=1, lladdrlen=6, src=pkt[Ether].src, proto=pkt[Ether].type)
                  if version == 1 else
                  CookedLinuxV2(proto=pkt[Ether].type, ifindex=3, lladdrtype=1, pkttype=4, lladdrlen=6,
                                src=pkt[Ether].src))
        c = header / pkt[Ether].payload
        c.time = pkt.time
        out.append(c)
    wrpcap(str(dst), out)


# pcapng by hand, block by block (tests of what scapy's writer cannot make: byte orders, clocks,
# several interfaces)
def block(order: str, kind: int, body: bytes) -> bytes:
    """One pcapng block: type, total length, body padded to 32 bits, total length again."""
    body += b"\0" * (-len(body) % 4)
    n = 12 + len(body)
    return struct.pack(order + "II", kind, n) + body + struct.pack(order + "I", n)


def section(order: str) -> bytes:
    return block(order, 0x0A0D0D0A, struct.pack(order + "IHHq", 0x1A2B3C4D, 1, 0, -1))


def interface(order: str, link: int = 1, options: bytes = b"") -> bytes:
    return block(order, 1, struct.pack(order + "HHI", link, 0, 262144) + options)


def option(order: str, code: int, value: bytes) -> bytes:
    return struct.pack(order + "HH", code, len(value)) + value + b"\0" * (-len(value) % 4)


def packet(order: str, iface: int, stamp: int, frame: bytes) -> bytes:
    return block(order, 6, struct.pack(order + "IIIII", iface, stamp >> 32, stamp & 0xFFFFFFFF, len(frame),
                                       len(frame)) + frame)


def mixed_pcapng(src, dst) -> None:
    """An Ethernet capture's frames alternately on an Ethernet and a Linux cooked (SLL2) interface
    of one pcapng, microsecond stamps."""
    ng = section("<") + interface("<", 1) + interface("<", 276)
    for i, pkt in enumerate(rdpcap(str(src))):
        stamp = round(float(pkt.time) * 1e6)
        frame = bytes(pkt) if i % 2 == 0 else bytes(
            CookedLinuxV2(proto=pkt[Ether].type, ifindex=3, lladdrtype=1, pkttype=4, lladdrlen=6,
                          src=pkt[Ether].src) / pkt[Ether].payload)
        ng += packet("<", i % 2, stamp, frame)
    with open(dst, "wb") as fh:
        fh.write(ng)


def with_readings(dst, signal: str, value: int | None, t_from: float, t_to: float, case=LEAK_CASE) -> None:
    """A bundled case with `signal` reading `value` (wire units; None: frozen at its reading at
    t_from) from t_from to t_to s (UDP checksums set to 0: no checksum, valid for IPv4)."""
    cap = copy.deepcopy(read_pcap(case))
    t = cap.messages["t"] - cap.messages["t"][0]
    buf = np.frombuffer(cap.data, np.uint8)
    at = cap.offset[(t >= t_from) & (t < t_to)]
    field = OFF_PAYLOAD + 4 + 2 * SIGNALS.index(signal)
    if value is None:
        value = int(buf[at[0] + field]) << 8 | int(buf[at[0] + field + 1])
    buf[at + field], buf[at + field + 1] = value >> 8, value & 0xFF
    buf[at + OFF_UDP_CSUM] = buf[at + OFF_UDP_CSUM + 1] = 0
    cap.write(dst)
