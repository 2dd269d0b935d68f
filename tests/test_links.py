"""Linux cooked captures (`tcpdump -i any`: SLL and SLL2 link headers): read as their Ethernet
capture, replayed with only the verdicts and checksums changed, mixed with Ethernet in a pcapng."""
from __future__ import annotations

import numpy as np
import pytest
from scapy.layers.inet import IP, UDP
from scapy.utils import rdpcap

from civic.cli import main
from civic.pcap_chunks import PcapChunks
from civic.wire import MESSAGE_DTYPE, OFF_UDP_CSUM, OFF_VERDICT, read_pcap, write_pcap
from data import TRAINING
from frames import cooked, junk_frames, mixed_pcapng

RECORDING = TRAINING / "drain_v075_error_r2.pcap"


@pytest.fixture(scope="module")
def captures(tmp_path_factory):
    """The recording with junk frames between its messages, as Ethernet, SLL, SLL2 and mixed pcapng."""
    d = tmp_path_factory.mktemp("cooked")
    rec, junk = read_pcap(RECORDING), junk_frames()
    frames, times = [], []
    for i in range(len(rec)):
        frames.append(rec.frame(i))
        times.append(rec.messages["t"][i])
        if i % 40 == 0:
            frames.append(junk[(i // 40) % len(junk)])
            times.append(rec.messages["t"][i] + 1e-3)
    write_pcap(d / "ethernet.pcap", np.array(times), frames)
    cooked(d / "ethernet.pcap", d / "sll.pcap", 1)
    cooked(d / "ethernet.pcap", d / "sll2.pcap", 2)
    mixed_pcapng(d / "ethernet.pcap", d / "mixed.pcapng")
    return d


@pytest.fixture(scope="module")
def entries(tmp_path_factory, trained_entries):
    path = tmp_path_factory.mktemp("entries") / "entries.json"
    trained_entries.save(path)
    return path


def same_messages(a: np.ndarray, b: np.ndarray) -> bool:
    return all(np.array_equal(a[k], b[k]) for k in MESSAGE_DTYPE.names)


@pytest.mark.parametrize("name", ["sll.pcap", "sll2.pcap", "mixed.pcapng"])
def test_a_cooked_capture_reads_as_its_ethernet_capture(captures, name):
    ethernet, other = read_pcap(captures / "ethernet.pcap"), read_pcap(captures / name)
    assert other.link is not None and set(other.link.tolist()) >= {113 if name == "sll.pcap" else 276}
    assert 0 < ethernet.messages["plant"].sum() < len(ethernet)         # junk in between
    assert same_messages(ethernet.messages, other.messages)
    # what a switch is sent: the Ethernet frame's ethertype and payload (the addresses are the cooked header's)
    assert [other.frame(i)[12:] for i in range(len(other))] == [ethernet.frame(i)[12:] for i in range(len(ethernet))]
    # in chunks too (the streaming replay's reader), chunks ending anywhere
    plant, t = [], []
    for chunk in PcapChunks(captures / name, chunk_bytes=1000):
        plant.append(chunk.plant)
        t.append(chunk.times())
    assert np.array_equal(np.concatenate(plant), ethernet.messages["plant"])
    assert np.array_equal(np.concatenate(t), ethernet.messages["t"])


@pytest.mark.parametrize("name", ["sll.pcap", "sll2.pcap", "mixed.pcapng"])
def test_replay_of_a_cooked_capture_changes_only_verdicts_and_checksums(captures, name, tmp_path, entries):
    for src in ("ethernet.pcap", name):
        assert main(["replay", str(captures / src), "-o", str(tmp_path / src), "--entries", str(entries)]) == 0
    ethernet, other = read_pcap(tmp_path / "ethernet.pcap"), read_pcap(tmp_path / name)
    assert np.count_nonzero(other.messages["verdict"]) > 100
    assert same_messages(ethernet.messages, other.messages)
    before, after = np.frombuffer((captures / name).read_bytes(), np.uint8), np.frombuffer(
        (tmp_path / name).read_bytes(), np.uint8)
    assert len(before) == len(after)
    plant = other.offset[other.messages["plant"]]
    patched = np.concatenate([plant + OFF_VERDICT, plant + OFF_VERDICT + 1, plant + OFF_UDP_CSUM,
                              plant + OFF_UDP_CSUM + 1])
    assert np.all(np.isin(np.flatnonzero(before != after), patched))
    if name.endswith(".pcap"):                                         # scapy recomputes the new checksums
        checked = 0
        for pkt in rdpcap(str(tmp_path / name)):
            if IP in pkt and UDP in pkt and pkt[UDP].dport == 50000 and len(pkt[UDP]) == 28 and pkt[UDP].chksum:
                ip = IP(bytes(pkt[IP]))
                given = ip[UDP].chksum
                del ip[UDP].chksum
                assert IP(bytes(ip))[UDP].chksum == given
                checked += 1
        assert checked > 150
