"""Real data: the Cascaded Tanks benchmark (estimation record) against configs/cascaded-tanks.toml.

Only the lower tank is measured, so the diagnosis runs on the open-loop simulation
error (blocked 2-fold CV). The improved model must load and run in `civic simulate`.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from civic.cli import main

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "traces" / "cascaded-tanks" / "estimation.csv"
MODEL = ROOT / "configs" / "cascaded-tanks.toml"


def _other_inputs(path: Path, model_path: Path) -> None:
    """A different experiment: a multisine input simulated with the improved model, 4 s samples."""
    from civic.plant.model import PlantModel
    from civic.plant.simulate import simulate

    m = PlantModel.from_toml(model_path)
    n = 600
    t = np.arange(n) * m.dt
    rng = np.random.default_rng(3)
    u = 3.0 + sum(0.6 * np.sin(2 * np.pi * f * t + rng.uniform(0, 6.3)) for f in (1 / 900, 1 / 410, 1 / 170))
    sim = simulate(m, t, {"u_V": u}, {"T1": 10.0, "T2": 5.0}, noise=True, seed=1)
    np.savetxt(path, np.column_stack([t, u, sim["y_V"]]), delimiter=",", header="t_s,u_V,y_V",
               comments="", fmt="%.6g")


def test_cascaded_tanks_round_trip(tmp_path, capsys):
    rep_path, improved = tmp_path / "ct.json", tmp_path / "improved.toml"
    rc = main(["diagnose", str(DATA), "--model", str(MODEL), "--json", str(rep_path),
               "--write-model", str(improved), "-q"])
    assert rc == 0
    rep = json.loads(rep_path.read_text())
    assert rep["mismatch"] is True
    names = [(f["mechanism"], f["component"]) for f in rep["findings"]]
    assert ("overflow", "T1") in names and any(m == "flow_law" for m, _ in names)
    spill = next(f for f in rep["findings"] if (f["mechanism"], f["component"]) == ("overflow", "T1")
                 and "fraction" in f["parameters"])
    assert 0.0 < spill["parameters"]["fraction"] < 1.0      # part into T2, the rest out
    # T1 also loses water to outside a little below that rim (third pass of issue #20): without
    # it the record fitted to 0.149 V and its blocked CV held out 0.178 V
    below = [f for f in rep["findings"] if (f["mechanism"], f["component"]) == ("overflow", "T1")
             and "crest" in f["parameters"]]
    assert len(below) == 1 and 0.5 <= below[0]["parameters"]["crest"] < 1.0
    assert below[0]["parameters"]["to"] == "outside"
    before, after = rep["fit"]["before"]["rmse"]["y_V"], rep["fit"]["after"]["rmse"]["y_V"]
    assert after <= 0.145 < before
    assert rep["fit"]["ablation"]["heldout_rmse"] < 0.17
    # held-out evidence: every kept finding's removal raises the blocked-CV free-run RMSE,
    # and the findings come ordered by that contribution
    abl = rep["fit"]["ablation"]
    without = [r["heldout_rmse"] for r in abl["without"]]
    assert all(w > abl["heldout_rmse"] for w in without) and without == sorted(without, reverse=True)
    assert [r["finding"].split("(")[0] for r in abl["without"]] == [f["mechanism"] for f in rep["findings"]]
    assert rep["fit"]["integrator"]["max_deviation_sigma"] < 1.0
    # the sensor map's gain is the rig's unit of volume (one sensor, every coefficient free): no
    # standard error for it, the bend and the offset keep theirs
    shape = next(f for f in rep["findings"] if f["mechanism"] == "sensor_characteristic")
    unc = shape["uncertainty"]
    assert set(unc["not_identifiable"]) == {"gain"} and "gain" not in unc["stderr"]
    assert {"exponent", "offset"} <= set(unc["stderr"])
    # the lower tank spills where its sensor clips, under the sensor map fitted with it
    from civic.plant.model import PlantModel
    imp = PlantModel.from_toml(improved)
    if ("overflow", "T2") in names:
        s, t2 = imp.find("sensor", "y_V"), imp.tank("T2")
        assert abs(float(s.read(t2.overflow.volume / t2.area)) - s.max) < 1e-6
    capsys.readouterr()
    rc = main(["simulate", "--model", str(improved), "--inputs", str(DATA), "--init-samples", "50"])
    line = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("y_V")][0]
    assert rc == 0 and float(line.split()[1]) <= 0.145
    # the improved model runs in the simulator on another experiment
    other = tmp_path / "other.csv"
    _other_inputs(other, improved)
    capsys.readouterr()
    rc = main(["simulate", "--model", str(improved), "--inputs", str(other), "--init-samples", "50"])
    out = capsys.readouterr().out
    assert rc == 0, out
    line = [ln for ln in out.splitlines() if ln.startswith("y_V")][0]
    assert float(line.split()[1]) < 0.5    # same model that made the data: noise + initial state only


def test_the_unit_of_volume_is_free_where_one_sensor_sees_the_rig():
    """Cascaded Tanks (one sensor, no stated water, no fixed rim): every volume scaled by s, the
    flows by s and the sensor's gain by s**-exponent replay the same readings, so the map's gain
    cannot be told from the coefficients. The four-tank plant (four sensors, a stated fill)
    holds its unit."""
    from civic.diagnose import data
    from civic.diagnose.fit import volume_unit_free
    from civic.plant.model import Overflow, PlantModel
    from civic.plant.simulate import simulate

    nominal = PlantModel.from_toml(MODEL)
    rec = data.load(DATA, nominal)
    assert volume_unit_free(nominal, rec)
    plant = PlantModel.from_toml(ROOT / "configs" / "plant.toml")
    assert not volume_unit_free(plant, data.load(ROOT / "traces" / "diagnose" / "example_none" / "case.pcap", plant))

    def rig(s):
        m = nominal.copy()
        sensor = m.find("sensor", "y_V")
        sensor.exponent, sensor.offset, sensor.gain = 1.8, 1.7, 0.25 * s ** -1.8
        m.tank("T1").overflow = Overflow(to="T2", volume=9.0 * s, fraction=0.7, rest="outside")
        m.set("pump.P1.gain", float(nominal.get("pump.P1.gain")) * s)
        m.set("link.out1.coeff", float(nominal.get("link.out1.coeff")) * s ** 0.5)
        out2 = m.find("link", "out2")
        out2.exponent, out2.coeff = 0.4, out2.coeff * s ** 0.6
        return m

    u = np.asarray(rec.signals["u_V"])
    t = np.arange(len(u)) * nominal.dt
    y = [simulate(rig(s), t, {"u_V": u}, {"T1": 6.0 * s, "T2": 4.3 * s})["y_V"] for s in (1.0, 0.5, 2.0)]
    assert np.ptp(y[0]) > 3.0 and max(np.max(np.abs(y[0] - other)) for other in y[1:]) < 1e-6


def test_split_overflow_fraction_is_fitted():
    """The upper tank (unmeasured) spills half into the measured lower tank, half outside:
    the catalogue's split overflow names it and recovers the rim and the fraction."""
    from civic.plant.simulate import regularise
    from civic.diagnose.fit import diagnose
    from civic.plant.model import Overflow, PlantModel
    from civic.plant.simulate import Recording, simulate

    nominal = PlantModel.from_toml(MODEL)
    d = np.loadtxt(DATA, delimiter=",", skiprows=1)
    u = np.tile(d[:300, 1], 2)          # the record's first high-input burst, twice (one per CV half)
    t = np.arange(len(u)) * nominal.dt
    true = nominal.copy()
    true.tank("T1").overflow = Overflow(to="T2", volume=9.0, fraction=0.5, rest="outside")
    sim = simulate(true, t, {"u_V": u}, {"T1": 8.0, "T2": 5.2}, noise=True, seed=3)
    rec = regularise(Recording(t, {"u_V": u, "y_V": sim["y_V"]}, {}, "split"), nominal.dt)
    diag = diagnose(nominal, rec, n_init=50)
    top = diag.findings[0]
    assert top["mechanism"].label == "overflow(T1->T2|outside)"
    p = diag.final_all.mechanisms[0].values()
    # the joint refit frees the nominal coefficients: the rim trades against T1's scale (not
    # checked), the share that falls into T2 does not
    assert abs(p["fraction"] - 0.5) < 0.1, p


def _cut_record(offset: int):
    """The nominal model and the estimation record cut `offset` samples after its middle: both
    parts, each timed from its own start."""
    from civic.diagnose import data
    from civic.plant.model import PlantModel

    model = PlantModel.from_toml(MODEL)
    rec = data.load(DATA, model)
    cut = len(rec.t) // 2 + offset
    return model, rec.part(slice(0, cut), "part"), rec.part(slice(cut, None), "part")


def test_half_record_keeps_the_spill_no_fold_can_judge():
    """The second half of the record: T2 reaches its sensor's clip once, in the last block, so no
    fold of the blocked CV sees its spill act both in training and held out; the spill stays
    (the pooled error had dropped it, and the model then stored water above the sensor's range
    on the first half's long overflow: 0.36 V there). Its improved model transfers to the first
    half (`--init-samples 50` protocol) within 0.25 V; the validation record is not used."""
    from civic.diagnose.fit import diagnose
    from civic.diagnose.report import build_report, simulation_rmse

    model, first, second = _cut_record(0)
    d = diagnose(model, second, n_init=50)
    rep = build_report(d, second, 50, 50)
    judged = {r["finding"]: r["judged_by_folds"] for r in rep["fit"]["ablation"]["without"]}
    assert judged.get("overflow(T2->outside)") == []
    spill = next(f for f in rep["findings"] if (f["mechanism"], f["component"]) == ("overflow", "T2"))
    assert "kept unjudged" in spill["evidence"] and spill["intervals"]
    # the fold that holds out the last block was trained below 9.4 V: it judges nothing
    assert judged["sensor_characteristic(y_V)"] == [1, 2]
    assert simulation_rmse(d.model_improved, first, 50, 50)[0]["y_V"] < 0.25


def test_a_fold_that_extrapolates_judges_no_finding():
    """The last 544 samples: the fold that holds out their last block was trained below 7.4 V and
    missed the held-out clip at 10 V by 0.9 V RMS with every finding in, less without T1's spill,
    whose removal the pooled error then chose; the model without the spill missed the other
    part's long overflow by 0.55 V. Judged by the folds whose held-out readings stay within their
    training's, the spill stays and the model transfers."""
    from civic.diagnose.fit import diagnose
    from civic.diagnose.report import build_report, simulation_rmse

    model, head, tail = _cut_record(-32)
    d = diagnose(model, tail, n_init=50)
    rep = build_report(d, tail, 50, 50)
    judged = {r["finding"]: r["judged_by_folds"] for r in rep["fit"]["ablation"]["without"]}
    assert "overflow(T1->T2|outside)" in judged
    assert all(j == [] or 0 not in j for j in judged.values()), judged
    assert simulation_rmse(d.model_improved, head, 50, 50)[0]["y_V"] < 0.25


def test_joint_fit_leaves_the_nominal_calibrations_basin():
    """The first 448 samples: the nominal model's calibration there (pump gain 0.5x, out1's
    coefficient 1.8x, making up for the spills it lacks) is a basin every start of the joint fit
    ended in, at 10x the cost, and the improved model fitted its own part at 0.56 V (nominal
    0.61 V). Started from the datasheet's calibration too, the fit reaches the basin of every
    other cut of the record and transfers to the rest of it."""
    from civic.diagnose.fit import diagnose
    from civic.diagnose.report import simulation_rmse

    model, head, rest = _cut_record(-64)
    d = diagnose(model, head, n_init=50)
    assert simulation_rmse(d.model_improved, head, 50, 50)[0]["y_V"] < 0.2
    assert simulation_rmse(d.model_improved, rest, 50, 50)[0]["y_V"] < 0.3
