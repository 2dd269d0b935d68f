"""Calibration to recordings, the compensate table, and the envelope's simulated tests."""
from __future__ import annotations

import numpy as np
import pytest

from civic.config import load_monitors
from civic.entries import LEVEL_MAX
from civic.envelope import Envelope, Recorded, compensation_table, load_recorded
from civic.errors import CivicError
from civic.evalsets import unit_tests
from civic.plant.model import PlantModel
from civic.train import read_labels
from data import ROOT, TRAINING

DATASHEET = PlantModel.from_toml(ROOT / "configs/plant.toml")


def as_recorded(tests, monitor):
    return [Recorded(f"sim{i}", monitor, t.cls, {k: t.msgs[k].astype(np.int64) for k in
                                                  ("l1", "l2", "l3", "l4", "p1", "v1", "v2")}, t.msgs["t"])
            for i, t in enumerate(tests)]


def test_calibration_recovers_a_known_units_coefficients():
    unit = DATASHEET.copy()
    unit.set("link.V2.coeff", 0.30 * 1.04)
    unit.set("link.pipe23.coeff", 0.12 * 0.95)
    unit.set("pump.P1.gain", 0.30 * 0.97)
    recorded = as_recorded(unit_tests(unit, "drain", 7.5, 2, 0.0, seed=5), "drain_t3") + \
        as_recorded(unit_tests(unit, "fill", None, 1, 0.0, seed=6), "fill_t1")
    env = Envelope(DATASHEET).fit(recorded)
    got = {**env.calibrated_["drain"], **env.calibrated_["fill"]}
    for path in ("link.V2.coeff", "link.pipe23.coeff", "pump.P1.gain"):
        assert got[path] == pytest.approx(unit.get(path), rel=0.01), path
    assert env.model_.get("link.V2.coeff") == got["link.V2.coeff"]
    assert DATASHEET.get("link.V2.coeff") == 0.30          # the datasheet model is left alone


def test_the_bundled_unit_lies_within_the_plant_types_spread():
    config = load_monitors()
    recorded = load_recorded(TRAINING, read_labels(TRAINING / "labels.csv"), config.udp_port, config.plant_prefix)
    env = Envelope(DATASHEET).fit(recorded)
    for values in env.calibrated_.values():
        for path, v in values.items():
            assert v == pytest.approx(DATASHEET.get(path), rel=0.05), path
            lo, hi = env.unit_range(path)
            assert lo <= DATASHEET.get(path) * 0.97 and v * 1.03 <= hi


def test_compensation_table_follows_the_link_law_within_tolerance():
    scale, step = 0.1 * 6 / (20 * 399) * 10 / 10 * 10, 19   # lsq, W = 20: mL/s per raw unit
    rows = compensation_table(DATASHEET, "l2", "l3", scale, step, tolerance=2.0)
    assert rows[0, 0] == 0 and rows[-1, 1] == LEVEL_MAX
    assert np.all(rows[1:, 0] == rows[:-1, 1] + 1)            # disjoint and gap-free
    assert np.all(rows[:, 2] % step == 0)
    assert len(rows) <= 256
    aux = np.arange(0, 10_001)
    law = 0.12 * np.sqrt(aux / 1000 / 2.0) * 1000               # mL/s, datasheet C_23, A = 2 dm²
    row = np.searchsorted(rows[:, 1], aux)
    err = np.abs(rows[row, 2] * scale - law)
    assert err.max() <= 2.0 + step * scale


def test_compensation_needs_a_link_between_the_tanks():
    with pytest.raises(CivicError, match="no link between T1"):
        compensation_table(DATASHEET, "l1", "l3", 0.01, 1)
