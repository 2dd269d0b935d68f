"""Range tables: a binary search per key over the entries' edges == a P4 range table's match."""
from __future__ import annotations

import numpy as np

from civic.entries import parse_entries
from civic.pipeline import SwitchModel
from civic.pipeline.classification import RangeTable
from civic.pipeline.stream import StreamingSwitch
from civic.wire import SIGNALS, build_frames, read_pcap, write_pcap


def test_range_table_equals_a_linear_scan_of_disjoint_entries():
    """Binary search over the entries' edges gives the entry a P4 range table hits, -1 on a miss."""
    rng = np.random.default_rng(5)
    for _ in range(30):
        # disjoint boxes: cut each axis into cells, keep a random subset of the cell pairs
        xs = np.unique(np.concatenate(([0], rng.integers(1, 65535, 12), [65536])))
        ys = np.unique(np.concatenate(([0], rng.integers(1, 1000, 6), [1001])))
        boxes = [(xs[i], xs[i + 1] - 1 - rng.integers(0, 2), ys[j], ys[j + 1] - 1)
                 for i in range(len(xs) - 1) for j in range(len(ys) - 1) if rng.random() < 0.7]
        boxes = np.array([b for b in boxes if b[0] <= b[1]], np.int64)
        table = RangeTable(boxes[:, [0, 2]], boxes[:, [1, 3]])
        x, y = rng.integers(0, 65536, 3000), rng.integers(0, 1100, 3000)
        got = table.lookup(x, y)
        want = np.full(len(x), -1)
        for r, (xl, xh, yl, yh) in enumerate(boxes):
            want[(x >= xl) & (x <= xh) & (y >= yl) & (y <= yh)] = r
        assert np.array_equal(got, want)


def linear_scan(lo, hi, keys):
    """What a P4 range table returns: the highest-priority (earliest) entry holding the keys."""
    out = np.full(len(keys[0]), -1)
    for r in reversed(range(len(lo))):
        hit = np.all([(k >= lo[r, j]) & (k <= hi[r, j]) for j, k in enumerate(keys)], axis=0)
        out[hit] = r
    return out


def test_overlapping_entries_resolve_by_priority_and_misses_give_minus_one():
    rng = np.random.default_rng(7)
    for _ in range(200):
        n, k = int(rng.integers(0, 12)), int(rng.integers(1, 3))
        a, b = rng.integers(0, 300, (n, k)), rng.integers(0, 300, (n, k))
        lo, hi = np.minimum(a, b), np.maximum(a, b)
        table = RangeTable(lo.reshape(n, k), hi.reshape(n, k))
        keys = [rng.integers(-5, 310, 500) for _ in range(k)]
        assert np.array_equal(table.lookup(*keys), linear_scan(lo, hi, keys))


def test_the_streaming_kernel_looks_up_wide_keys_and_misses_like_the_model(tmp_path):
    """Class rows over the whole slope range and a level LUT edge at 0xFFFF: both lookups agree."""
    classes = [{"slope": [-(2**31), -5000], "level": [0, 30000], "class": 2},
               {"slope": [-4999, 4999], "level": [0, 65535], "class": 1},
               {"slope": [5000, 2**31 - 1], "level": [65535, 65535], "class": 3}]
    entries = parse_entries({"format": "civic-entries/3", "monitors": [
        {"name": "s", "signal": "l3", "window": 4, "estimator": "endpoint", "default_class": 2,
         "classes": classes}]}, "t")
    rng = np.random.default_rng(3)
    level = np.clip(np.cumsum(rng.integers(-9000, 9000, 3000)), 0, 65535)
    level[::97] = 65535
    frames = build_frames({**{s: np.zeros(3000, int) for s in SIGNALS}, "l3": level})
    path = tmp_path / "wide.pcap"
    write_pcap(path, np.arange(3000) * 0.1, frames)
    want = read_pcap(path)
    want.set_verdicts(SwitchModel(entries).run(want.messages))
    got = read_pcap(path)
    StreamingSwitch(entries).run_capture(got)
    assert got.data == want.data
    assert set(want.messages["verdict"]) == {0, 1, 2, 3}        # not yet, and every class
