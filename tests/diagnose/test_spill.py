"""Simulated 40 s fill tests: the finite overflow spill (a weir needing head above its crest),
and a second effect beside a closure."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from civic.diagnose.fit import diagnose
from civic.diagnose.mechanisms import Spill
from civic.plant.model import Link, PlantModel
from civic.plant.procedures import make_procedure, run_procedure
from civic.plant.simulate import Recording, simulate

ROOT = Path(__file__).resolve().parents[2]
PLANT = ROOT / "configs" / "plant.toml"


def _spill(c=3.5):
    return Spill("T1", {"c": c}, {"c": (0.03, 30.0)}, {"to": "T4", "rim_level": 5.0, "exponent": 1.0})


def _fill_record(model, seed):
    proc = make_procedure(model, "fill", 3.0)
    sim = run_procedure(proc, noise=True, seed=seed)
    sig = {k: np.asarray(sim[k]) for k in model.signal_names + model.input_names}
    return Recording(proc.t, sig, {}, path=f"fill-seed{seed}")


def test_spill_is_mass_exact_and_round_trips(tmp_path):
    nominal = PlantModel.from_toml(PLANT)
    m = _spill().apply(nominal)
    assert m.tank("T1").rim_volume() > 10.0                 # instant overflow moved above the crest
    lk = [x for x in m.links if x.name == "spill_T1"][0]
    assert (lk.law, lk.min_level, lk.exponent, lk.to) == ("orifice", 5.0, 1.0, "T4")
    m.to_toml(tmp_path / "spill.toml")
    assert PlantModel.from_toml(tmp_path / "spill.toml") == m
    proc = make_procedure(m, "fill", 3.0)
    sim = simulate(m, proc.t, proc.inputs, proc.x0)
    total = sim["volumes"].sum(axis=1) + sim["outside"]
    assert np.ptp(total) < 1e-9
    v1 = sim["volumes"][:, 0]
    # steady state above the rim: head = q_in / c
    assert v1[-1] == pytest.approx(10.0 + 2.0 * 0.30 / 3.5, abs=0.01)


def test_finite_spill_found_on_a_short_fill_test():
    nominal = PlantModel.from_toml(PLANT)
    rec = _fill_record(_spill(3.5).apply(nominal), seed=7)
    d = diagnose(nominal, rec)
    assert d.findings, d.verdict
    first = d.findings[0]["fit"].mechanisms[-1]
    assert isinstance(first, Spill) and first.component == "T1"
    assert first.values()["c"] == pytest.approx(3.5, rel=0.25)
    assert d.loc.at_rim.get("T1", 0) > 5.0


def test_instant_overflow_is_not_called_a_spill():
    nominal = PlantModel.from_toml(PLANT)
    rec = _fill_record(nominal, seed=8)
    d = diagnose(nominal, rec)
    assert not any(isinstance(f["fit"].mechanisms[-1], Spill) for f in d.findings)


def test_a_second_effect_on_a_short_fill_test_holds_on_both_block_orders():
    """A further finding on a short test must show in both block orders (`_holds_on_both_orders`):
    a T1 leak beside a pump a fifth weak acts over the whole fill, and does."""
    nominal = PlantModel.from_toml(PLANT)
    real = nominal.copy()
    real.set("pump.P1.gain", 0.8 * real.get("pump.P1.gain"))
    real.links.append(Link("leak", from_="T1", to="outside", coeff=0.01))
    d = diagnose(nominal, _fill_record(real, seed=1))
    found = [(f["mechanism"].name, f["mechanism"].component) for f in d.findings]
    assert found == [("coefficient", "P1"), ("leak", "T1")], d.verdict
    leak = d.findings[1]["fit"].mechanisms[-1].values()
    assert leak["to"] == "outside" and leak["c"] == pytest.approx(0.01, rel=0.3)
