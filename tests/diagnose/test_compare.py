"""The mass-balance equation error mirrors the simulator: with the true model it is noise only.

civic.diagnose.compare evaluates the model's flows on measured states (vectorised);
civic.plant.simulate integrates them. For every mechanism of the catalogue, a recording
simulated from a model must leave zero-mean residuals when compared with that model,
and clearly non-zero ones when compared with the nominal model.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.ndimage import binary_closing, uniform_filter1d

from civic.diagnose.compare import INVENTORY, EquationError, SimulationError, closed_gaps, holdout_mask
from civic.diagnose.locate import localise
from civic.plant.model import Link, Overflow, PlantModel
from civic.plant.simulate import Recording, simulate

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def nominal():
    return PlantModel.from_toml(ROOT / "configs" / "plant.toml")


def _inputs(n, seed):
    rng = np.random.default_rng(seed)
    hold = 80
    p = np.repeat(rng.uniform(0.2, 0.9, n // hold + 1), hold)[:n]
    v1 = np.repeat(rng.uniform(0.2, 1.0, n // hold + 1), hold)[:n]
    v2 = np.repeat(rng.uniform(0.05, 0.6, n // hold + 1), hold)[:n]
    return {"p1": p, "v1": v1, "v2": v2}


def _variant(nominal, name):
    m = nominal.copy()
    if name == "leak":
        m.links.append(Link("leak", from_="T2", to="T4", coeff=0.02, law="orifice"))
    elif name == "leak_out":
        m.links.append(Link("leak", from_="T3", to="outside", coeff=0.02, law="orifice"))
    elif name == "dead_time":
        m.find("pump", "P1").dead_time = 1.37          # fractional number of samples
    elif name == "head":
        m.find("pump", "P1").head_coeff = 0.05
    elif name == "valve":
        m.find("valve", "V2").characteristic = 1.7
        m.find("valve", "V1").dead_time = 0.25
    elif name == "overflow":
        m.tank("T1").overflow = Overflow(to="T4", volume=8.0)
    elif name == "overflow_split":
        m.tank("T1").overflow = Overflow(to="T2", volume=8.0, fraction=0.6, rest="T4")
    elif name == "offset":
        m.find("sensor", "L3").offset = 0.3
    return m


@pytest.mark.parametrize("name", ["nominal", "leak", "leak_out", "dead_time", "head", "valve", "overflow", "overflow_split",
                                  "offset"])
def test_equation_error_matches_simulator(nominal, name):
    true = _variant(nominal, name)
    n = 3000
    t = np.arange(n) * true.dt
    sim = simulate(true, t, _inputs(n, 3), {"T1": 7.0, "T2": 6.0, "T3": 5.0, "T4": 22.0}, noise=True, seed=4)
    rec = Recording(t, {k: sim[k] for k in true.signal_names + true.input_names}, {}, name)
    ee = EquationError(true, rec)
    assert ee.columns == ["T1", "T2", "T3", "T4", INVENTORY]
    R = ee.residuals(true)
    # the true model accounts for every litre: the measured total stays at 40 L less what left
    assert abs(np.mean(R[:, 4])) < 0.01, np.mean(R[:, 4])
    R = R[:, :4]
    sd = np.array([0.02, 0.02, 0.02, 0.05]) * np.sqrt(2 / ee.smooth) * 1.5
    z = R.mean(axis=0) / (sd / np.sqrt(len(R)))
    assert np.all(np.abs(z) < 5), z
    if name != "nominal":
        Rn = ee.residuals(nominal)[:, :4]
        assert np.max(np.abs(Rn.mean(axis=0) / (sd / np.sqrt(len(R))))) > 8 or \
            np.max(np.sqrt(np.mean(Rn ** 2, axis=0)) / sd) > 2


def test_holdout_blocks_alternate():
    mask = holdout_mask(60)
    assert mask.sum() == 30 and mask[:10].all() and not mask[10:20].any()


@pytest.mark.parametrize("width", [3, 7])
def test_closed_gaps_is_the_morphological_closing(width):
    """The run-boundary version equals scipy's closing with the record ends padded by their
    own value: short gaps filled, a gap at either end kept."""
    rng = np.random.default_rng(width)
    pad = width // 2
    for _ in range(500):
        runs = rng.integers(1, 2 * width, 12)
        mask = np.repeat(np.arange(12) % 2 == rng.integers(2), runs)
        want = binary_closing(np.pad(mask, pad, mode="edge"), structure=np.ones(width, bool))[pad:-pad]
        np.testing.assert_array_equal(closed_gaps(mask, width), want)
    assert not closed_gaps(np.array([0, 0, 1, 1, 0, 1, 1, 0], bool), 3)[[0, 1, 7]].any()
    assert closed_gaps(np.array([1, 0, 0, 1], bool), 3).all()


def test_multiple_shooting_restarts_from_measurement(nominal):
    n = 1200
    t = np.arange(n) * nominal.dt
    sim = simulate(nominal, t, _inputs(n, 7), {"T1": 7.0, "T2": 6.0, "T3": 5.0, "T4": 22.0}, noise=True, seed=1)
    rec = Recording(t, {k: sim[k] for k in nominal.signal_names + nominal.input_names}, {}, "x")
    short = SimulationError(nominal, rec, horizon_s=20.0).rmse(nominal)
    sigma = {s.name: s.noise_sigma for s in nominal.sensors}
    assert all(v < 1.5 * sigma[k] for k, v in short.items()), short   # noise (twice: restarts)


@pytest.mark.parametrize("n", [1000, 3000, 6000])        # 100 s, 300 s, 600 s at the rim
def test_spill_is_modelled_on_every_noisy_sample_at_the_rim(nominal, n):
    """A tank held at its rim by a strong inflow reads the rim +- noise, with a sensor twice as
    noisy as the datasheet's (a fixed 0.03 L band missed one sample in twenty). The rim the
    diagnosis gives it is the one the localisation reads off the plateau; with that rim every
    sample of the stay must spill in the equation error (a dip read as 'below the rim' keeps the
    inflow in the tank), however long the stay: a rim at the plateau's top climbed with the stay
    and left the balance 13 sigmas off after 300 s."""
    true = nominal.copy()
    true.tank("T1").overflow = Overflow(to="T4", volume=8.0)
    true.find("sensor", "L1").noise_sigma *= 2.0
    t = np.arange(n) * true.dt
    u = {"p1": np.full(n, 0.9), "v1": np.full(n, 0.3), "v2": np.full(n, 0.4)}
    sim = simulate(true, t, u, {"T1": 7.95, "T2": 6.0, "T3": 5.0, "T4": 20.0}, noise=True, seed=5)
    rec = Recording(t, {k: sim[k] for k in true.signal_names + true.input_names}, {}, "rim")
    ee = EquationError(nominal, rec)
    R = ee.residuals(nominal)
    loc = localise(nominal, rec, ee, R, np.std(R, axis=0))
    smoothed = uniform_filter1d(np.asarray(sim["L1"], float), ee.smooth)
    assert np.mean(smoothed[100:] < 8.0 - 0.03) > 0.03     # the noise reaches below a 0.03 L band
    sd = 0.04 * np.sqrt(2 / ee.smooth) * 1.5
    assert abs(loc.plateaus["T1"] - 8.0) < sd                # the rim read where the readings sit
    seen = nominal.copy()
    seen.tank("T1").overflow = Overflow(to="T4", volume=loc.plateaus["T1"])
    R = EquationError(seen, rec).residuals(seen)[:, :2]
    z = R.mean(axis=0) / (sd / np.sqrt(len(R)))
    assert np.all(np.abs(z) < 5), z


def test_a_record_that_starts_above_the_rim_spills_the_excess_at_once(nominal):
    """A closed loop started at a setpoint above a tank's rim: its first reading is above the
    rim, the next ones at it (the datasheet spills the excess at once). The equation error of
    the true model must spill it too: kept in the tank, the first window's balance was 0.23 L off
    on T1 and on T4, and a T1 leak until 80 s outranked the overflow that held T1 at its rim."""
    true = nominal.copy()
    true.tank("T1").overflow = Overflow(to="T4", volume=8.0)
    n = 600
    t = np.arange(n) * true.dt
    u = {"p1": np.full(n, 0.9), "v1": np.full(n, 0.3), "v2": np.full(n, 0.4)}
    sim = simulate(true, t, u, {"T1": 8.4, "T2": 6.0, "T3": 5.0, "T4": 20.6}, noise=True, seed=5)
    rec = Recording(t, {k: sim[k] for k in true.signal_names + true.input_names}, {}, "above")
    assert sim["L1"][0] > 8.3 and np.all(np.abs(sim["L1"][5:] - 8.0) < 0.1)
    R = EquationError(true, rec).residuals(true)
    sd = 0.05 * np.sqrt(2 / 5) * 1.5              # the noisier sensor's (L4) smoothed difference
    assert np.all(np.abs(R[:2, :4]) < 3 * sd), R[:2]
    assert abs(R[:, 4].mean()) < 0.01               # and every litre stays accounted for


def test_level_error_spread_is_large_where_a_links_head_is_near_zero(nominal):
    """V1 open, T1 and T2 level for the first half of the record and 2 L apart for the second:
    a one-noise shift of a reading moves V1's Torricelli flow, and T1's balance, many times
    further where the head is near zero (the flow's slope in the head is infinite there) than
    where the levels stand apart; T3's balance, whose links see 4 L heads, hardly moves. The
    noise itself (what the windows' robust spread measures) is the same in both halves."""
    n = 3000
    rng = np.random.default_rng(7)
    t = np.arange(n) * nominal.dt
    level = {"L1": np.where(t < t[n // 2], 6.0, 8.0), "L2": np.full(n, 6.0), "L3": np.full(n, 2.0),
             "L4": np.full(n, 20.0)}
    signals = {k: v + rng.normal(0.0, 0.05 if k == "L4" else 0.02, n) for k, v in level.items()}
    signals.update(p1=np.full(n, 0.5), v1=np.ones(n), v2=np.full(n, 0.3))
    ee = EquationError(nominal, Recording(t, signals, {}, "level heads"))
    spread = ee.level_error_spread(nominal)
    level_half = ee.row_times[:, 1] <= t[n // 2]
    t1, t3 = ee.columns.index("T1"), ee.columns.index("T3")
    near, apart = np.median(spread[level_half, t1]), np.median(spread[~level_half, t1])
    assert near > 5 * apart, (near, apart)
    assert np.median(spread[:, t3]) < apart
    assert np.all(spread[:, ee.columns.index(INVENTORY)] == 0.0)
    # the readings are left as they were
    assert np.allclose(ee.ys["L1"], uniform_filter1d(signals["L1"], ee.smooth, mode="nearest"))
