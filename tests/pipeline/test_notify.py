"""Verdict changes and counts (docs/pipeline.md section 7): plain == vectorized, and both equal what
one computes from the verdicts alone."""
from __future__ import annotations

import numpy as np
import pytest

from civic.pipeline import SwitchModel
from civic.wire import monitor_verdict, read_pcap
from data import DIAGNOSE, TRAINING
from frames import changing_fleet


def captures(tmp_path):
    return (sorted(TRAINING.glob("*.pcap"))[::4] + sorted(DIAGNOSE.glob("*/case.pcap"))
            + [changing_fleet(tmp_path / "fleet.pcap", plants=9)])


def from_verdicts(msgs, verdicts, monitors):
    """(index, plant, monitor, prev, cls) of every change, by walking the verdicts plant by plant."""
    last, out = {}, []
    for i in np.flatnonzero(msgs["plant"]):
        for m in range(monitors):
            c = int(monitor_verdict(verdicts[i:i + 1], m)[0])
            key = (int(msgs["src"][i]), m)
            if c and c != last.get(key, 0):
                out.append((int(i), key[0], m, last.get(key, 0), c))
                last[key] = c
    return out


def test_changes_and_counts_plain_equal_vectorized_equal_the_verdicts(trained_entries, tmp_path):
    n = len(trained_entries.monitors)
    for path in captures(tmp_path):
        msgs = read_pcap(path).messages
        plain = SwitchModel(trained_entries)
        verdicts = plain.run_plain(msgs)
        vec = SwitchModel(trained_entries)
        changes = vec.verdict_changes(msgs)
        assert changes == plain.changes, path.name
        assert [(c.index, c.plant, c.monitor, c.prev, c.cls) for c in changes] == from_verdicts(msgs, verdicts, n)
        counts = vec.verdict_counts(msgs)
        assert np.array_equal(counts, plain.counts)
        for m in range(n):
            code = monitor_verdict(verdicts, m)
            for cls in (1, 2, 3):
                assert counts[m, :, cls].sum() == np.sum(msgs["plant"] & (code == cls))
        assert np.all(counts[:, :, 0] == 0)


def test_a_changing_fleet_changes_twice_per_plant(trained_entries, tmp_path):
    msgs = read_pcap(changing_fleet(tmp_path / "f.pcap", plants=6)).messages
    changes = [c for c in SwitchModel(trained_entries).verdict_changes(msgs) if c.monitor == 0]  # drain_t3
    assert len(changes) == 18
    firsts = [c for c in changes if c.prev == 0]
    assert len(firsts) == 6 and len({c.plant for c in firsts}) == 6
    for c in changes:                                 # digest data: the message's seq, slope, level
        assert c.seq == msgs["seq"][c.index] and c.level == msgs["l3"][c.index]


@pytest.mark.parametrize("codes, want", [
    ([0, 1, 1, 0, 2, 2, 1], [(1, 0, 1), (4, 1, 2), (6, 2, 1)]),
    ([0, 0, 0], []),
    ([3, 0, 3, 3], [(0, 0, 3)]),
])
def test_messages_without_a_verdict_change_nothing(codes, want):
    from civic.pipeline.notify import changes
    changed, prev = changes(np.zeros(len(codes), int), np.array(codes))
    got = [(int(i), int(prev[i]), codes[i]) for i in np.flatnonzero(changed)]
    assert got == want
