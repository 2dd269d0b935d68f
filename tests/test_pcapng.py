"""pcapng captures: the same messages as their classic pcap, replayed back into pcapng, bad files."""
from __future__ import annotations

import struct

import numpy as np
import pytest
from scapy.utils import PcapNgWriter, rdpcap

from civic.cli import main
from civic.errors import CivicError
from civic.pcap_chunks import PcapChunks, PcapWriter
from civic.pcapng import PcapNgBlocks
from civic.wire import SIGNALS, read_pcap
from data import TRAINING
from frames import block, interface, junk_frames, option, packet, plant, section

RECORDING = TRAINING / "fill_warning_r3.pcap"
FIELDS = ("plant", "src", "dport", "udp_csum", "seq", *SIGNALS, "verdict")


@pytest.fixture(scope="module")
def as_pcapng(tmp_path_factory):
    """The bundled recording with a few non-plant frames, written as pcapng by scapy (not by us)."""
    path = tmp_path_factory.mktemp("ng") / "capture.pcapng"
    packets = rdpcap(str(RECORDING))
    writer = PcapNgWriter(str(path))
    for pkt in packets:
        writer.write(pkt)
    writer.close()
    return path


def test_a_pcapng_reads_as_its_classic_pcap(as_pcapng):
    ng, classic = read_pcap(as_pcapng), read_pcap(RECORDING)
    assert as_pcapng.read_bytes()[:4] == b"\x0a\x0d\x0d\x0a"
    assert len(ng) == len(classic) > 100
    for name in FIELDS:
        assert np.array_equal(ng.messages[name], classic.messages[name]), name
    assert np.max(np.abs(ng.messages["t"] - classic.messages["t"])) < 1e-6
    assert all(ng.frame(i) == classic.frame(i) for i in range(len(ng)))
    assert ng.to_bytes() == as_pcapng.read_bytes()


def test_sections_interfaces_and_time_resolutions(tmp_path):
    """A big-endian section (nanoseconds, 100 s offset) with blocks that are no packets, then a
    little-endian one with two interfaces (microseconds, 2^-20 s): every time to its own unit."""
    frames = [bytes(plant(seq=1, l1=100)), bytes(plant(seq=2, l1=200)), junk_frames()[0], bytes(plant(seq=3, l1=300))]
    data = (section(">") + interface(">", options=option(">", 9, b"\x09") + option(">", 14, struct.pack(">q", 100))
                                     + option(">", 0, b""))
            + block(">", 4, b"\0" * 4)                       # a name resolution block
            + packet(">", 0, 1_500_000_000_123_456_789, frames[0])
            + block(">", 0x40000BAD, b"custom")
            + section("<") + interface("<") + interface("<", options=option("<", 9, b"\x94"))
            + packet("<", 1, (1_600_000_000 << 20) + (1 << 19), frames[1])
            + packet("<", 0, 1_700_000_000_250_000, frames[2])
            + packet("<", 1, 1_700_000_001 << 20, frames[3]))
    path = tmp_path / "mixed.pcapng"
    path.write_bytes(data)
    cap = read_pcap(path)
    assert cap.messages["t"].tolist() == [1_500_000_100.123456789, 1_600_000_000.5, 1_700_000_000.25,
                                         1_700_000_001.0]
    assert cap.messages["plant"].tolist() == [True, True, False, True]
    assert cap.messages["l1"][cap.messages["plant"]].tolist() == [100, 200, 300]
    assert [cap.frame(i) for i in range(4)] == frames


def test_chunks_walk_the_blocks_as_the_whole_file(as_pcapng):
    whole = read_pcap(as_pcapng)
    chunks = PcapChunks(as_pcapng, chunk_bytes=1000)
    parts = list(chunks)
    assert len(parts) > 5
    assert np.array_equal(np.concatenate([c.times() for c in parts]), whole.messages["t"])
    assert np.array_equal(np.concatenate([c.plant for c in parts]), whole.messages["plant"])
    assert chunks.header + b"".join(bytes(c.records()) for c in parts) == as_pcapng.read_bytes()


def test_every_chunk_boundary_walks_as_the_whole_file():
    """Two sections (little-, then big-endian), the walk cut at every byte: a chunk may end anywhere,
    inside a section header's first 16 bytes too (its byte order is read from there)."""
    frame = bytes(plant())
    data = (section("<") + interface("<") + packet("<", 0, 10, frame)
            + section(">") + interface(">") + packet(">", 0, 20, frame))
    whole = PcapNgBlocks("two.pcapng").walk(memoryview(data))
    assert whole[2].tolist() == [1e-5, 2e-5]
    for n in range(1, len(data)):
        walker, pending, base, offsets, times = PcapNgBlocks("two.pcapng"), b"", 0, [], []
        for i in range(0, len(data), n):
            buf = pending + data[i:i + n]
            offset, _, t, _, end = walker.walk(memoryview(buf), i + n >= len(data), base)
            offsets.append(offset + base)
            times.append(t)
            pending, base = buf[end:], base + end
        assert np.array_equal(np.concatenate(offsets), whole[0]), n
        assert np.array_equal(np.concatenate(times), whole[2]), n


def test_replay_writes_pcapng_back_with_the_verdicts_of_its_pcap(as_pcapng, tmp_path):
    entries = tmp_path / "entries.json"
    assert main(["train", str(TRAINING), "-o", str(entries)]) == 0
    for src, dst in ((as_pcapng, tmp_path / "out.pcapng"), (RECORDING, tmp_path / "out.pcap")):
        assert main(["replay", str(src), "-o", str(dst), "--entries", str(entries)]) == 0
    ng, classic = read_pcap(tmp_path / "out.pcapng"), read_pcap(tmp_path / "out.pcap")
    assert (tmp_path / "out.pcapng").read_bytes()[:4] == b"\x0a\x0d\x0d\x0a"
    assert np.any(classic.messages["verdict"] != 0)
    for name in FIELDS:
        assert np.array_equal(ng.messages[name], classic.messages[name]), name
    # scapy reads our output: the blocks stayed well formed
    assert len(rdpcap(str(tmp_path / "out.pcapng"))) == len(ng)


def test_what_civic_writes_as_pcap_it_writes_as_pcapng_where_asked(tmp_path):
    """simulate -o and the writers under it: the same frames and times, read back by us and by scapy;
    frames of one size (one array of blocks) and of several sizes (block by block), lengths on the wire."""
    for out in ("sim.pcap", "sim.pcapng"):
        assert main(["simulate", "drain", "--plants", "3", "--seed", "7", "-o", str(tmp_path / out)]) == 0
    classic, ng = read_pcap(tmp_path / "sim.pcap"), read_pcap(tmp_path / "sim.pcapng")
    assert (tmp_path / "sim.pcapng").read_bytes()[:4] == b"\x0a\x0d\x0d\x0a" and len(ng) > 500
    for name in ("t", *FIELDS):
        assert np.array_equal(ng.messages[name], classic.messages[name]), name
    frames = [bytes(plant(seq=i)) for i in range(3)] + junk_frames()
    t = 1767225600.0 + np.arange(len(frames)) * 0.25 + 1e-6
    writer = PcapWriter(tmp_path / "live.pcapng")                 # civic monitor --write OUT.pcapng
    writer.write(t[:4], frames[:4], [len(f) + 100 for f in frames[:4]])
    writer.write(t[4:], frames[4:])
    writer.close()
    read = rdpcap(str(tmp_path / "live.pcapng"))
    assert [bytes(p) for p in read] == frames
    assert [round(float(p.time), 6) for p in read] == [round(x, 6) for x in t]
    assert [p.wirelen for p in read[:4]] == [len(f) + 100 for f in frames[:4]]
    assert [read_pcap(tmp_path / "live.pcapng").frame(i) for i in range(len(frames))] == frames


def test_replay_refuses_an_output_named_for_the_other_format(as_pcapng, tmp_path, capsys, trained_entries):
    entries = tmp_path / "entries.json"
    trained_entries.save(entries)
    for src, dst in ((as_pcapng, "out.pcap"), (RECORDING, "out.pcapng")):
        assert main(["replay", str(src), "-o", str(tmp_path / dst), "--entries", str(entries)]) == 2
        err = capsys.readouterr().err.strip()
        assert "\n" not in err and "keeps" in err and not (tmp_path / dst).exists()


FRAME = bytes(plant())


@pytest.mark.parametrize("tail, message", [
    (None, "truncated pcapng"),
    (struct.pack("<III", 6, 10, 0), "corrupt pcapng"),                       # a block 10 bytes long
    (struct.pack("<IIII", 6, 16, 0, 16), "corrupt pcapng"),                  # a packet block with no room
    (packet("<", 5, 0, FRAME), "corrupt pcapng"),                            # on no interface 5
    (section("<") + interface("<", link=101) + packet("<", 0, 0, FRAME), "neither Ethernet"),
    (block("<", 3, struct.pack("<I", len(FRAME)) + FRAME), "Simple Packet"),  # no capture time
    (block("<", 0x0A0D0D0A, struct.pack("<IHHq", 0, 1, 0, -1)), "byte-order magic"),
    (section("<") + interface("<", options=option("<", 9, b"\x14")) + packet("<", 0, 0, FRAME), "time resolution"),
])
def test_bad_pcapngs_give_one_clear_error(as_pcapng, tmp_path, capsys, tail, message):
    good = as_pcapng.read_bytes()
    path = tmp_path / "bad.pcapng"
    path.write_bytes(good[:-7] if tail is None else good + tail)
    with pytest.raises(CivicError, match=message):
        read_pcap(path)
    with pytest.raises(CivicError, match=message):
        for _ in PcapChunks(path, chunk_bytes=512):
            pass
    assert main(["diagnose", str(path), "-q"]) != 0
    err = capsys.readouterr().err.strip()
    assert message in err and "\n" not in err
