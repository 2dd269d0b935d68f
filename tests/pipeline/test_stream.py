"""The streaming switch (compiled kernel, registers carried between chunks) == the vectorized
model, byte for byte and event for event, whatever the chunking; pcaps read in chunks."""
from __future__ import annotations

import numpy as np
import pytest

from civic.errors import CivicError
from civic.pcap_chunks import PcapChunks
from civic.pipeline import SwitchModel
from civic.pipeline.stream import StreamingSwitch, changes
from civic.wire import SIGNALS, build_frames, read_pcap, write_pcap
from data import DIAGNOSE, ROOT, TRAINING
from frames import interleave


def recordings():
    return (sorted(TRAINING.glob("*.pcap")) + sorted(DIAGNOSE.glob("*/case.pcap"))
            + sorted((ROOT / "traces" / "continuous").glob("*.pcap")))


def vectorized(entries, path):
    """The reference: the vectorized model's output bytes and its verdict changes."""
    cap = read_pcap(path)
    verdicts, found = SwitchModel(entries).run_with_changes(cap.messages)
    cap.set_verdicts(verdicts)
    return bytes(cap.data), found


def streamed(entries, path, cuts):
    """The capture through one StreamingSwitch in chunks ending at `cuts`."""
    cap = read_pcap(path)
    switch = StreamingSwitch(entries)
    buf = np.frombuffer(cap.data, np.uint8)
    found = []
    for a, b in zip(np.r_[0, cuts], np.r_[cuts, len(cap)]):
        rows = switch.process(buf, cap.offset[a:b], cap.messages["plant"][a:b])
        found += changes(rows, cap.messages["src"][a:b], cap.messages["seq"][a:b], a)
    return bytes(cap.data), found, switch


def random_cuts(rng, n):
    return np.sort(rng.choice(np.arange(1, n), size=min(n - 1, int(rng.integers(1, 40))), replace=False))


def test_streaming_equals_vectorized_on_every_recording_under_random_chunkings(trained_entries):
    rng = np.random.default_rng(21)
    for path in recordings():
        want, want_changes = vectorized(trained_entries, path)
        n = len(read_pcap(path))
        for cuts in (np.zeros(0, int), random_cuts(rng, n)):
            got, got_changes, _ = streamed(trained_entries, path, cuts)
            assert got == want, path.name
            assert got_changes == want_changes, path.name


def test_edge_captures_and_one_message_chunks(trained_entries, tmp_path):
    """Junk frames (passed untouched), several plants, seq gaps and wraparound, values at 0xFFFF."""
    mixed = interleave([TRAINING / "drain_v075_error_r3.pcap", TRAINING / "fill_warning_r1.pcap"], tmp_path)
    n = 400
    fields = {s: np.full(n, 0xFFFF if s.startswith("l") else 1000) for s in SIGNALS}
    fields["seq"] = (np.arange(n, dtype=np.int64) + 0xFFFFFF00) & 0xFFFFFFFF
    fields["seq"][200:] += 5                                   # a gap
    edge = tmp_path / "edge.pcap"
    write_pcap(edge, np.arange(n) * 0.1, build_frames(fields, src_ip="10.0.0.77"))
    for path in (mixed, edge):
        want, want_changes = vectorized(trained_entries, path)
        got, got_changes, _ = streamed(trained_entries, path, np.arange(1, len(read_pcap(path))))
        assert got == want and got_changes == want_changes, path.name
    src = read_pcap(mixed)
    out = read_pcap(mixed)
    StreamingSwitch(trained_entries).run_capture(out)
    junk = ~src.messages["plant"]
    assert junk.sum() >= 10
    assert all(src.frame(i) == out.frame(i) for i in np.flatnonzero(junk))


def fleet_capture(tmp_path, plants=64):
    """64 plants at once, each replaying a bundled recording, messages interleaved by time."""
    paths = sorted(TRAINING.glob("*.pcap"))
    frames, times = [], []
    for k in range(plants):
        msgs = read_pcap(paths[k % len(paths)]).messages
        frames.append(build_frames({s: msgs[s] for s in SIGNALS}, src_ip=f"10.0.0.{k + 1}", seq0=7 * k))
        times.append(msgs["t"] - msgs["t"][0] + 0.0013 * k)
    t = np.concatenate(times)
    order = np.argsort(t, kind="stable")
    path = tmp_path / "fleet.pcap"
    write_pcap(path, t[order], np.concatenate(frames)[order])
    return path


def test_a_64_plant_fleet_streams_like_one_pass_and_counts_like_the_switch(trained_entries, tmp_path):
    path = fleet_capture(tmp_path)
    want, want_changes = vectorized(trained_entries, path)
    n = len(read_pcap(path))
    for size in (1000, 4096):
        got, got_changes, switch = streamed(trained_entries, path, np.arange(size, n, size))
        assert got == want and got_changes == want_changes
    cap = read_pcap(path)
    counts = SwitchModel(trained_entries).verdict_counts(cap.messages)
    assert np.array_equal(switch.counts, counts)
    assert len({c.plant for c in want_changes}) == 64


@pytest.mark.parametrize("chunk_bytes", [1, 77, 1000, 1 << 16])
def test_chunks_hold_every_record_once(tmp_path, chunk_bytes):
    path = interleave([TRAINING / "drain_v075_normal_r1.pcap"], tmp_path)    # frames of several sizes
    whole = read_pcap(path)
    chunks = PcapChunks(path, chunk_bytes=chunk_bytes)
    parts = list(chunks)
    assert chunks.header + b"".join(bytes(c.records()) for c in parts) == bytes(whole.data)
    assert np.array_equal(np.concatenate([c.plant for c in parts]), whole.messages["plant"])
    assert np.array_equal(np.concatenate([c.times() for c in parts]), whole.messages["t"])


def test_a_truncated_pcap_is_the_same_one_line_error_chunked_or_whole(tmp_path):
    src = (TRAINING / "drain_v075_normal_r1.pcap").read_bytes()
    cut = tmp_path / "cut.pcap"
    cut.write_bytes(src[:-30])
    with pytest.raises(CivicError) as whole:
        read_pcap(cut)
    with pytest.raises(CivicError) as chunked:
        list(PcapChunks(cut, chunk_bytes=5000))
    assert str(whole.value) == str(chunked.value)
    assert "truncated pcap" in str(chunked.value) and "\n" not in str(chunked.value)
