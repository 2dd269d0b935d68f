"""civic.diagnose.nominal: coefficients fitted on the normal regime (below the clip) only."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from civic.diagnose.nominal import fit_nominal, normal_segments
from civic.plant.model import PlantModel
from civic.plant.simulate import Recording, simulate

ROOT = Path(__file__).resolve().parents[2]
MODEL = ROOT / "configs" / "cascaded-tanks.toml"


def _record(model, u):
    t = np.arange(len(u)) * model.dt
    sim = simulate(model, t, {"u_V": u}, {"T1": 2.0, "T2": 2.0})
    return Recording(t, {"u_V": u, "y_V": np.asarray(sim["y_V"])}, {})


def test_normal_segments_split_at_the_clip():
    m = PlantModel.from_toml(MODEL)
    n = 300
    y = np.full(n, 3.0)
    y[100:150] = 9.9                 # near the 10 V clip: excluded
    y[280:] = 9.95                   # too short a tail after the last normal stretch
    rec = Recording(np.arange(n) * m.dt, {"u_V": np.zeros(n), "y_V": y}, {})
    assert normal_segments(m, rec, below=0.85, min_len=40) == [(0, 100), (150, 280)]


def test_fit_nominal_recovers_a_coefficient_from_the_normal_regime():
    truth = PlantModel.from_toml(MODEL)
    truth.set("link.out2.coeff", 0.06)
    rng = np.random.default_rng(3)
    u = np.repeat(rng.uniform(2.0, 6.0, 12), 25)
    rec = _record(truth, u)
    start = PlantModel.from_toml(MODEL)
    fitted, info = fit_nominal(start, rec, ["link.out2.coeff"])
    assert info["segments_s"]
    assert info["values"]["link.out2.coeff"] == pytest.approx(0.06, rel=0.02)
    assert fitted.get("link.out2.coeff") == pytest.approx(0.06, rel=0.02)
    assert info["rmse"] < 1e-3
