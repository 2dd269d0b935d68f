"""Wire format: bulk pcap I/O against scapy, bad files, checksums."""
from __future__ import annotations

import struct

import numpy as np
import pytest
from scapy.layers.inet import UDP
from scapy.layers.l2 import Ether
from scapy.utils import rdpcap

from civic.errors import CivicError
from civic.scapy_layer import PlantMessage
from civic.wire import SIGNALS, build_frames, read_pcap, udp_checksum, write_pcap
from data import DIAGNOSE, TRAINING
from frames import junk_frames, plant


def test_bundled_recordings_round_trip_byte_identical():
    for path in sorted(TRAINING.glob("*.pcap")) + sorted(DIAGNOSE.glob("*/case.pcap")):
        cap = read_pcap(path)
        assert cap.to_bytes() == path.read_bytes()
        assert cap.messages["plant"].all()


def test_bulk_decode_matches_scapy():
    path = TRAINING / "fill_warning_r3.pcap"
    cap = read_pcap(path)
    for i, pkt in enumerate(rdpcap(str(path))):
        msg = pkt[PlantMessage]
        row = cap.messages[i]
        assert [int(row[k]) for k in ("seq",) + SIGNALS + ("verdict",)] == \
            [msg.seq, msg.l1, msg.l2, msg.l3, msg.l4, msg.p1, msg.v1, msg.v2, msg.verdict]
        assert abs(row["t"] - float(pkt.time)) < 1e-6


def test_build_frames_reproduces_recorded_frames():
    cap = read_pcap(TRAINING / "drain_v075_error_r2.pcap")
    fields = {k: cap.messages[k] for k in SIGNALS + ("seq",)}
    first_id = struct.unpack("!H", cap.frame(0)[18:20])[0]
    frames = build_frames(fields, ip_id0=first_id)
    assert all(frames[i].tobytes() == cap.frame(i) for i in range(len(cap)))


def test_junk_frames_are_not_plant_messages(tmp_path):
    frames = junk_frames() + [bytes(plant())]
    write_pcap(tmp_path / "j.pcap", np.arange(len(frames)) * 0.1, frames)
    cap = read_pcap(tmp_path / "j.pcap")
    assert cap.messages["plant"].tolist() == [False] * (len(frames) - 1) + [True]


def test_trailer_bytes_are_not_payload(tmp_path):
    frame = bytes(plant(l3=4321)) + b"\xaa\xbb\xcc\xdd"
    write_pcap(tmp_path / "t.pcap", [0.0], [frame])
    cap = read_pcap(tmp_path / "t.pcap")
    assert cap.messages["plant"][0] and cap.messages["l3"][0] == 4321
    cap.set_verdicts(np.array([7]))
    assert cap.frame(0)[-4:] == b"\xaa\xbb\xcc\xdd"


def test_fields_at_0xffff_decode_unchanged(tmp_path):
    frame = bytes(plant(l1=0xFFFF, l3=0xFFFF, p1=0xFFFF, v2=0xFFFF, seq=0xFFFFFFFF))
    write_pcap(tmp_path / "f.pcap", [0.0], [frame])
    row = read_pcap(tmp_path / "f.pcap").messages[0]
    assert (row["l1"], row["l3"], row["p1"], row["v2"], row["seq"]) == (0xFFFF, 0xFFFF, 0xFFFF, 0xFFFF, 0xFFFFFFFF)


@pytest.mark.parametrize("verdict", [0, 1, 0x5A, 0xFFFF])
def test_set_verdicts_keeps_udp_checksum_valid(tmp_path, verdict):
    frames = [bytes(plant(seq=s, l3=7000 - 37 * s, v2=1000)) for s in range(50)]
    write_pcap(tmp_path / "c.pcap", np.arange(50) * 0.1, frames)
    cap = read_pcap(tmp_path / "c.pcap")
    cap.set_verdicts(np.full(50, verdict))
    for i in range(50):
        pkt = Ether(cap.frame(i))
        assert pkt[PlantMessage].verdict == verdict
        sent = pkt[UDP].chksum
        del pkt[UDP].chksum
        assert Ether(bytes(pkt))[UDP].chksum == sent


def test_zero_udp_checksum_stays_zero(tmp_path):
    pkt = plant()
    pkt[UDP].chksum = 0
    write_pcap(tmp_path / "z.pcap", [0.0], [bytes(pkt)])
    cap = read_pcap(tmp_path / "z.pcap")
    cap.set_verdicts(np.array([3]))
    assert Ether(cap.frame(0))[UDP].chksum == 0


def test_udp_checksum_matches_scapy():
    pkt = Ether(bytes(plant(l1=1234, l2=65535)))
    raw = np.frombuffer(bytes(pkt[UDP]), np.uint8).copy()[None, :]
    raw[0, 6:8] = 0
    got = udp_checksum(np.array([0x0A000001], np.uint64), np.array([0x0A000002], np.uint64), raw)
    assert int(got[0]) == pkt[UDP].chksum


@pytest.mark.parametrize("mutate, message", [
    (lambda b: b[:-7], "truncated pcap"),
    (lambda b: b[:24 + 10], "truncated pcap"),
    (lambda b: b"\x0a\x0d\x0d\x0a" + b[4:], "corrupt pcapng"),   # a pcap relabelled pcapng
    (lambda b: b"\x00\x01\x02\x03" + b[4:], "not a pcap"),
    (lambda b: b[:20] + struct.pack("<I", 101) + b[24:], "neither Ethernet"),
    (lambda b: b[:24 + 8] + struct.pack("<I", 10_000_000) + b[36:], "corrupt pcap"),
    (lambda b: b[:10], "not a pcap"),
])
def test_bad_pcaps_give_one_clear_error(tmp_path, mutate, message):
    data = (TRAINING / "drain_v075_normal_r1.pcap").read_bytes()
    path = tmp_path / "bad.pcap"
    path.write_bytes(mutate(data))
    with pytest.raises(CivicError, match=message):
        read_pcap(path)


def test_empty_pcap_and_nanosecond_big_endian(tmp_path):
    path = tmp_path / "empty.pcap"
    path.write_bytes(struct.pack("<IHHiIII", 0xA1B2C3D4, 2, 4, 0, 0, 65535, 1))
    assert len(read_pcap(path)) == 0
    frame = bytes(plant(l2=777))
    be = struct.pack(">IHHiIII", 0xA1B23C4D, 2, 4, 0, 0, 65535, 1) + \
        struct.pack(">IIII", 5, 500_000_000, len(frame), len(frame)) + frame
    path.write_bytes(be)
    cap = read_pcap(path)
    assert cap.messages["l2"][0] == 777 and cap.messages["t"][0] == pytest.approx(5.5)
    assert cap.to_bytes() == be
