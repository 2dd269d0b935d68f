"""Training: leave-one-run-out quality, table well-formedness, generalization across levels."""
from __future__ import annotations

import numpy as np
import pytest

from civic.config import load_monitors
from civic.entries import SLOPE_MAX, SLOPE_MIN, load_entries
from civic.evaluate import score
from civic.pipeline.classification import classify
from civic.train import leave_one_run_out


@pytest.mark.parametrize("monitor", ["drain_t3", "fill_t1"])
def test_default_mode_reaches_macro_f1_099_leave_one_run_out(training_runs, monitor):
    mon = next(m for m in load_monitors().monitors if m.name == monitor)
    s = score(*leave_one_run_out(training_runs["lsq"], mon, "lsq", True))
    assert s["macro_f1"] >= 0.99


def test_paper_mode_confuses_drain_classes_and_bands_fix_it(training_runs):
    mon = load_monitors().monitors[0]
    paper = score(*leave_one_run_out(training_runs["endpoint"], mon, "endpoint", False))
    banded = score(*leave_one_run_out(training_runs["endpoint"], mon, "endpoint", True))
    assert paper["macro_f1"] < 0.9 < banded["macro_f1"]


def test_every_key_matches_exactly_one_entry(trained_entries, paper_entries):
    rng = np.random.default_rng(3)
    for entries in (trained_entries, paper_entries):
        for mon in entries.monitors:
            t = mon.classes
            slope = np.concatenate([rng.integers(SLOPE_MIN, SLOPE_MAX, 2000), t[:, 0], t[:, 1], [SLOPE_MIN, SLOPE_MAX]])
            level = rng.integers(0, 65536, len(slope))
            hits = sum(((slope >= lo) & (slope <= hi) & (level >= llo) & (level <= lhi)).astype(int)
                       for lo, hi, llo, lhi, _ in t)
            assert np.all(hits == 1)


def test_entries_round_trip(trained_entries, tmp_path):
    trained_entries.save(tmp_path / "e.json")
    back = load_entries(tmp_path / "e.json")
    for a, b in zip(trained_entries.monitors, back.monitors):
        assert np.array_equal(a.classes, b.classes) and a.window == b.window and a.estimator == b.estimator


def test_drain_boundaries_follow_the_level(trained_entries):
    """At a lower level a slower outflow is still normal (Torricelli), so the table must say so.
    The class table sees the outflow: the slope minus the compensated inflow from T2."""
    mon = trained_entries.monitors[0]
    assert mon.compensate == ("l2", "l3") and len(mon.offsets)
    normal_high = -0.30 * np.sqrt(5.5 / 2) * 1000 / mon.slope_scale   # datasheet outflow at 5.5 L, raw
    normal_low = -0.30 * np.sqrt(3.2 / 2) * 1000 / mon.slope_scale    # ... at 3.2 L
    got = classify(np.array([normal_high, normal_low]).astype(int), np.array([5500, 3200]), mon.classes, 3)
    assert got.tolist() == [1, 1]
    # the same slow outflow high up is a clogged drain
    assert classify(np.array([int(normal_low)]), np.array([6500]), mon.classes, 3)[0] >= 2
