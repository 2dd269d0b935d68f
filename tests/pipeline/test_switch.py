"""The software switch: plain per-message model == vectorized model; the pipeline's semantics."""
from __future__ import annotations

import numpy as np
import pytest

from civic.entries import Entries, parse_entries
from civic.pipeline import SwitchModel
from civic.pipeline.data_collection import RingState, window_sums
from civic.wire import MESSAGE_DTYPE, build_frames, monitor_verdict, read_pcap, write_pcap
from data import DIAGNOSE, TRAINING
from frames import interleave


def recordings():
    return sorted(TRAINING.glob("*.pcap")) + sorted(DIAGNOSE.glob("*/case.pcap"))


@pytest.mark.parametrize("mode", ["trained_entries", "paper_entries"])
def test_plain_and_vectorized_models_agree_on_every_recording(request, mode):
    entries = request.getfixturevalue(mode)
    for path in recordings():
        msgs = read_pcap(path).messages
        plain = SwitchModel(entries).run_plain(msgs)
        fast = SwitchModel(entries).run(msgs)
        assert np.array_equal(plain, fast), path.name


def test_plants_keep_their_own_history(trained_entries, tmp_path):
    paths = [TRAINING / "drain_v075_normal_r1.pcap", TRAINING / "drain_v075_error_r3.pcap",
             TRAINING / "fill_warning_r2.pcap"]
    mixed = read_pcap(interleave(paths, tmp_path)).messages
    verdict = SwitchModel(trained_entries).run(mixed)
    assert np.array_equal(verdict, SwitchModel(trained_entries).run_plain(mixed))
    for k, path in enumerate(paths):
        alone = SwitchModel(trained_entries).run(read_pcap(path).messages)
        mine = mixed["plant"] & (mixed["src"] == 0x0A000001 + k)
        assert np.array_equal(verdict[mine], alone)
    assert np.array_equal(verdict[~mixed["plant"]], mixed["verdict"][~mixed["plant"]])


def synthetic(n, seq0, l3_start=8000, rate=-40):
    l3 = np.clip(l3_start + rate * np.arange(n), 0, 65535)
    return {"seq": (seq0 + np.arange(n)) % 2**32, "l1": np.zeros(n, int), "l2": np.zeros(n, int),
            "l3": l3, "l4": np.zeros(n, int), "p1": np.zeros(n, int), "v1": np.zeros(n, int),
            "v2": np.full(n, 1000)}


def messages(fields, tmp_path):
    write_pcap(tmp_path / "s.pcap", np.arange(len(fields["seq"])) * 0.1, build_frames(fields))
    return read_pcap(tmp_path / "s.pcap").messages


def test_seq_wraparound_is_not_a_gap(trained_entries, tmp_path):
    msgs = messages(synthetic(60, 2**32 - 30), tmp_path)
    code = monitor_verdict(SwitchModel(trained_entries).run(msgs), 0)
    # window of 20: verdicts from the 20th message on, straight through the wrap
    assert np.all(code[:19] == 0) and np.all(code[19:] != 0)


def test_seq_gap_restarts_the_window(trained_entries, tmp_path):
    fields = synthetic(60, 1000)
    fields["seq"][30:] += 5          # five messages lost
    msgs = messages(fields, tmp_path)
    code = monitor_verdict(SwitchModel(trained_entries).run(msgs), 0)
    assert np.all(code[19:30] != 0) and np.all(code[30:49] == 0) and np.all(code[49:] != 0)


def test_failed_precondition_restarts_the_window(trained_entries, tmp_path):
    fields = synthetic(60, 5)
    fields["v2"][25] = 799           # V2 below 80.0 % for one message
    code = monitor_verdict(SwitchModel(trained_entries).run(messages(fields, tmp_path)), 0)
    assert code[25] == 0 and np.all(code[26:45] == 0) and code[45] != 0


def test_values_at_0xffff_neither_crash_nor_wrap(trained_entries, tmp_path):
    fields = synthetic(40, 9, l3_start=65535, rate=0)
    msgs = messages(fields, tmp_path)
    plain = SwitchModel(trained_entries).run_plain(msgs)
    assert np.array_equal(plain, SwitchModel(trained_entries).run(msgs))
    # a flat signal at the top of the range: no drain at all -> error for drain_t3
    assert np.all(monitor_verdict(plain, 0)[19:] == 3)


def test_lsq_slope_is_the_least_squares_slope(trained_entries):
    mon = trained_entries.monitors[0]
    rng = np.random.default_rng(1)
    x = rng.integers(2000, 9000, size=200)
    old, s0, s1 = window_sums(x, mon.ring_len)
    w = mon.window
    from civic.pipeline.slope import lsq
    raw = lsq(s0, s1, w)
    for i in range(w - 1, len(x)):
        ref = np.polyfit(np.arange(w), x[i - w + 1:i + 1], 1)[0] * 10  # mL/s
        assert raw[i] * mon.slope_scale == pytest.approx(ref, rel=1e-9, abs=1e-9)


def test_running_sums_equal_the_register_updates():
    x = np.random.default_rng(2).integers(0, 65536, size=500)
    for ring_len in (19, 20, 90, 128):
        old, s0, s1 = window_sums(x, ring_len)
        ring = RingState(1, ring_len)
        for i, v in enumerate(x):
            assert ring.push(0, int(v)) == old[i]
            assert (ring.s0[0], ring.s1[0]) == (s0[i], s1[i])
        assert s1.max() < 2**30 and s0.max() < 2**23


def test_unknown_plants_and_other_prefixes(trained_entries, tmp_path):
    fields = synthetic(40, 1)
    write_pcap(tmp_path / "u.pcap", np.arange(40) * 0.1, build_frames(fields, src_ip="10.0.1.1"))
    msgs = read_pcap(tmp_path / "u.pcap").messages
    assert not msgs["plant"].any()
    assert np.all(SwitchModel(trained_entries).run(msgs) == 0)
    moved = Entries(monitors=trained_entries.monitors, plant_prefix="10.0.1.0/24")
    msgs = read_pcap(tmp_path / "u.pcap", plant_prefix=moved.plant_prefix).messages
    assert msgs["plant"].all() and np.any(SwitchModel(moved).run(msgs) != 0)


@pytest.mark.parametrize("l2_minus_l3, cls", [(150, 1), (100, 1), (200, 1), (99, 2), (201, 2), (-50, 2), (0, 2)])
def test_compensation_subtracts_the_offset_of_the_aux_range(l2_minus_l3, cls):
    """Flat L3 gives slope 0, so the class table sees -offset: offset 19000 for aux in [100, 200],
    0 on a miss (and aux saturates at 0 when L2 < L3)."""
    raw = {"format": "civic-entries/2", "monitors": [{
        "name": "m", "signal": "l3", "window": 20, "estimator": "lsq",
        "compensation": {"signal": "l2", "minus": "l3", "offsets": [{"aux": [100, 200], "offset": 19000}]},
        "classes": [{"slope": [-2147483648, -1], "class": 1}, {"slope": [0, 2147483647], "class": 2}]}]}
    n = 30
    msgs = np.zeros(n, MESSAGE_DTYPE)
    msgs["plant"], msgs["src"], msgs["seq"] = True, 0x0A000001, np.arange(1, n + 1)
    msgs["l3"] = 5000
    msgs["l2"] = 5000 + l2_minus_l3
    model = SwitchModel(parse_entries(raw, "t"))
    code = monitor_verdict(model.run(msgs), 0)
    assert np.all(code[:19] == 0) and np.all(code[19:] == cls)
    assert np.array_equal(model.run_plain(msgs), model.run(msgs))
