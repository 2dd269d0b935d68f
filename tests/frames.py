"""Crafted frames for bad-input and pass-through tests (scapy, independent of civic.wire)."""
from __future__ import annotations

import numpy as np

from scapy.layers.inet import IP, UDP
from scapy.layers.inet6 import IPv6
from scapy.layers.l2 import ARP, Ether
from scapy.packet import Raw

from civic.scapy_layer import PlantMessage
from civic.wire import SIGNALS, build_frames, read_pcap, write_pcap


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
    """Several recordings as plants 10.0.0.1, .2, ... in one capture, junk frames in between."""
    frames, times = [], []
    for k, path in enumerate(paths):
        cap = read_pcap(path)
        fields = {s: cap.messages[s] for s in SIGNALS + ("seq",)}
        f = build_frames(fields, src_ip=f"10.0.0.{k + 1}")
        frames += [row.tobytes() for row in f]
        times += list(cap.messages["t"] + 0.01 * k)
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
