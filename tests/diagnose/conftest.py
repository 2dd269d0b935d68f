"""Shared fixtures: concealed-effect recordings made with the closed-loop plant simulator.

Each case runs the plant (with the fault and a few % of calibration spread) under the
MPC designed on the *nominal* model, as the real plant is run: the controller hides
the fault from the levels. Cases are generated once per session.
"""
from __future__ import annotations

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PLANT = ROOT / "configs" / "plant.toml"
DURATION = 600.0
# case -> the bundled case whose operation it runs
BUNDLED_OPERATION = {"flowlaw_V2_pinned": "example_none", "saturation_L1_held_at_clip": "example_none",
                     "leak_T1_from300_in_fill_test": "example_leak_t3"}


def real_plant(nominal):
    """The 'real' plant: datasheet coefficients off by a few % (calibration, not a fault)."""
    m = nominal.copy()
    m.set("pump.P1.gain", 0.30 * 1.03)
    m.set("link.pipe23.coeff", 0.12 * 0.98)
    m.set("link.V2.coeff", 0.30 * 1.02)
    return m


SWEEP_SEED1 = (1.0335, 1.0257, 1.0378, 1.0080)   # the sweep's seed-1 draw
SWEEP_SEED2 = (1.0354, 1.0028, 1.0252, 0.9963)   # ... and seed-2's
SWEEP_SEED3 = (0.9874, 1.0255, 0.9983, 0.9782)   # ... seed-3's
SWEEP_SEED5 = (0.9628, 1.0263, 1.0060, 1.0108)   # ... seed-5's
SWEEP_SEED7 = (0.9959, 0.9825, 0.9891, 1.0399)   # ... and seed-7's


def draw_calibration(m, nominal, factors):
    """One draw of the bench sweep's calibration spread (bench/diagnose_sweep.py's sweep_plant): factors on
    P1's gain and the V1, pipe23 and V2 coefficients."""
    for path, f in zip(("pump.P1.gain", "link.V1.coeff", "link.pipe23.coeff", "link.V2.coeff"), factors):
        m.set(path, float(nominal.get(path)) * f)


def make_fault(nominal, name):
    from civic.plant.model import Link, Overflow

    m = real_plant(nominal)
    if name == "leak_T1":
        m.links.append(Link("leak", from_="T1", to="T4", coeff=0.012, law="orifice"))
    elif name == "leak_T2":
        m.links.append(Link("leak", from_="T2", to="T4", coeff=0.010, law="orifice"))
    elif name == "leak_T1_from300_in_fill_test":
        # the random sweep's seed-507 plant: a small T1 leak opening at 300 s, as the bundled
        # operation's fill test drains T1 with the pump off (from 298.6 s)
        draw_calibration(m, nominal, (1.0037, 0.975, 1.016, 0.9654))
        m.links.append(Link("leak", from_="T1", to="T4", coeff=0.00711, since=300.0))
    elif name == "leak_T3_from300":
        m.links.append(Link("leak", from_="T3", to="T4", coeff=0.012, since=300.0))
    elif name == "leak_T1_small_out":
        m.links.append(Link("leak", from_="T1", to="outside", coeff=0.002, law="orifice"))
    elif name == "spill_T2":
        # a small finite spill into the reservoir: 0.07 L/s per L above an 8.5 L rim
        m.links.append(Link("spill", from_="T2", to="T4", coeff=0.07 * 2.0, law="orifice", exponent=1.0,
                            min_level=8.5 / 2.0))
    elif name == "leak_T2_out_draining":
        # large enough to drain the reservoir T4 to the pump's 1 L minimum in the last minutes
        m.links.append(Link("leak", from_="T2", to="outside", coeff=0.02, law="orifice"))
    elif name == "leak_T3_out":
        m.links.append(Link("leak", from_="T3", to="outside", coeff=0.010, law="orifice"))
    elif name == "offset_L2":
        m.find("sensor", "L2").offset = 0.4
    elif name == "offset_L4":
        m.find("sensor", "L4").offset = 0.5
    elif name == "deadtime_P1":
        m.find("pump", "P1").dead_time = 2.0
    elif name == "deadtime_V2":
        m.find("valve", "V2").dead_time = 2.0
    elif name == "head_P1":
        m.find("pump", "P1").head_coeff = 0.04
    elif name == "overflow_T1":
        m.tank("T1").overflow = Overflow(to="T4", volume=9.0)
    elif name == "overflow_T1_from_above":
        # the random sweep's seed-501 plant: a T1 rim at 8.95 L, below seed 501's first setpoint
        # (9.29 L), so the record starts with T1 above its rim, and the loop holds it there for 80 s
        draw_calibration(m, nominal, (0.9761, 1.0149, 0.9945, 1.0052))
        m.tank("T1").overflow = Overflow(to="T4", volume=8.95)
    elif name == "valve_V1":
        m.find("valve", "V1").characteristic = 1.5
    elif name == "saturation_L1":
        m.find("sensor", "L1").max = 9.0
    # real-rig physics (issue #20)
    elif name == "flowlaw_pipe23":
        m.find("link", "pipe23").exponent = 0.6
    elif name == "flowlaw_V2":
        m.find("link", "V2").exponent = 0.7
    elif name == "flowlaw_pipe23_subtle":
        # the sweep's seed-5 plant (bench/diagnose_sweep.py's sweep_plant): with seed 5 no balance is flagged
        draw_calibration(m, nominal, SWEEP_SEED5)
        m.find("link", "pipe23").exponent = 0.55
    elif name == "saturation_L1_training_only":
        # the sweep's seed-13 plant: under seed 13's setpoints T1 passes 9 L once, in a training block
        draw_calibration(m, nominal, (0.9848, 0.9711, 0.9644, 0.9781))
        m.find("sensor", "L1").max = 9.0
    elif name == "flowlaw_V2_pinned":
        # a milder exponent on a coefficient 1.4 % low: calibrated, V2's coefficient pins at -5 %
        link = m.find("link", "V2")
        link.exponent, link.coeff = 0.45, 0.30 * 0.986
    elif name == "sensorchar_L2":
        s = m.find("sensor", "L2")
        s.exponent, s.gain = 1.1, 5.0 ** -0.1       # calibrated at 5 L, bent elsewhere
    elif name == "sensorchar_L1":
        # the same bend on L1: the loop holds the reading, so T1 fills to its 10 L rim and sits
        # there reading 10.77 (above the 10.0 the model gives the rim; seed 11: 60 s at the rim)
        s = m.find("sensor", "L1")
        s.exponent, s.gain = 1.1, 5.0 ** -0.1
    elif name == "sensorchar_L4":
        # the reservoir's sensor bent the other way, calibrated at 5 L: at its 13-22 L it reads
        # 2-5 L low, an offset beyond a quarter of its swing
        s = m.find("sensor", "L4")
        s.exponent, s.gain = 0.85, 5.0 ** 0.15
    elif name == "sensorchar_L3_seed1":
        # the sweep's seed-1 plant (bench/diagnose_sweep.py's sweep_plant), L3 bent by 0.85 (calibrated at 5 L)
        draw_calibration(m, nominal, SWEEP_SEED1)
        s = m.find("sensor", "L3")
        s.exponent, s.gain = 0.85, 5.0 ** 0.15
    elif name == "flowlaw_V2_seed1":
        # the sweep's seed-1 plant, V2's drain with exponent 0.45: calibrated, V2's coefficient
        # trades with the exponent, fitted 0.48
        draw_calibration(m, nominal, SWEEP_SEED1)
        m.find("link", "V2").exponent = 0.45
    elif name == "saturation_L1_held_at_clip":
        # the sweep's seed-4 plant, L1 clipping at 9 L; the bundled clean case's last setpoint
        # (9.3 L from 526.5 s) holds T1 at and above the clip to the end
        draw_calibration(m, nominal, (0.9818, 0.982, 0.9991, 0.9979))
        m.find("sensor", "L1").max = 9.0
    elif name == "head_P1_absorbed":
        # the sweep's seed-94 plant, a pump head of 0.02 per dm: at T1's 2.5-4.7 dm it takes 5-9 %
        # of the flow, which the calibration's pump gain takes whole at the -5 % edge
        draw_calibration(m, nominal, (1.0273, 0.9817, 1.0126, 0.9975))
        m.find("pump", "P1").head_coeff = 0.02
    elif name == "offset_L1_small":
        # the sweep's seed-2 plant, L1 reading 0.1 L high from the start
        draw_calibration(m, nominal, SWEEP_SEED2)
        m.find("sensor", "L1").offset = 0.1
    elif name == "P1_low_at_edge":
        # the seed-94 plant with P1's gain 5.5 % below the datasheet: the calibration's -5 % edge
        # takes all but 0.5 % of it (at 5.3 % the calibration settled at -4.95 % once the balances
        # were weighted for errors in the variables)
        draw_calibration(m, nominal, (0.945, 0.9817, 1.0126, 0.9975))
    elif name == "closure_V2_from300+leak_T1":
        # the sweep's seed-2 plant, VM1 closed 55 % from 300 s and a T1 leak into the reservoir
        draw_calibration(m, nominal, SWEEP_SEED2)
        x = m.find("link", "V2")
        x.closure, x.onset = 0.55, 300.0
        m.links.append(Link("leak", from_="T1", to="T4", coeff=0.010, law="orifice"))
    elif name.startswith("shift_L3+flowlaw_pipe23"):
        # the sweep's seed-3 (or -2, -5, -7) plant, L3's reading 0.15 L up from 302.3 s and pipe23's
        # flow ~ dh**0.6
        draw_calibration(m, nominal, {"seed2": SWEEP_SEED2, "seed5": SWEEP_SEED5, "seed7": SWEEP_SEED7}
                         .get(name[-5:], SWEEP_SEED3))
        s = m.find("sensor", "L3")
        s.shift, s.since = 0.15, 302.3
        m.find("link", "pipe23").exponent = 0.6
    elif name == "leak_T1+deadtime_V2":
        # two concealed effects at once
        m.links.append(Link("leak", from_="T1", to="T4", coeff=0.010, law="orifice"))
        m.find("valve", "V2").dead_time = 2.0
    elif name.startswith("shift_"):
        # a sensor knocked 302.3 s in (between two of the equation error's 5 s windows): L3's
        # reading 0.15 L up, or the reservoir's 0.5 L (only the inventory sees that one); L2's
        # late, in the last block, which the interleaved split holds out; L3's 22 s before the end
        s = m.find("sensor", name.split("_")[1])
        s.shift = 0.5 if s.name == "L4" else 0.15
        s.since = {"late": 547.3, "end": 577.7}.get(name.split("_")[-1], 302.3)
    elif name.startswith("drift_"):
        # a sensor that starts drifting 200 s in by 0.3 L over the rest of the record: L1's
        # reading down (the loop then fills T1), L3's up
        s = m.find("sensor", name.split("_")[1])
        s.drift, s.since = (-0.00075 if s.name == "L1" else 0.00075), 200.0
    elif name == "closure_V2_for_a_while":
        # VM1 closed 55 % from 200 s and opened again at 400 s
        x = m.find("link", "V2")
        x.closure, x.onset, x.until = 0.55, 200.0, 400.0
    elif name == "leak_T3_repaired":
        # a T3 leak into the reservoir from the start, repaired at 300 s
        m.links.append(Link("leak", from_="T3", to="T4", coeff=0.012, until=300.0))
    elif name == "glitch_L3":
        # L3's reading 0.2 L high from 200 s, right again from 400 s (a glitch over)
        s = m.find("sensor", "L3")
        s.shift, s.since, s.until = 0.2, 200.0, 400.0
    elif name == "righted_L1":
        # L1's reading 0.3 L high from the start, set right at 300 s
        s = m.find("sensor", "L1")
        s.shift, s.until = 0.3, 300.0
    elif name == "deadzone_P1":
        m.find("pump", "P1").input_offset = 0.05
    elif name == "split_T1":
        m.tank("T1").overflow = Overflow(to="T4", volume=9.0, fraction=0.5, rest="outside")
    elif name != "clean":
        raise KeyError(name)
    return m


@pytest.fixture(scope="session")
def nominal():
    from civic.plant.model import PlantModel

    return PlantModel.from_toml(PLANT)


@pytest.fixture(scope="session")
def sweep_draw(nominal):
    """factors -> a copy of the nominal plant with that draw of the sweep's calibration spread."""
    def make(factors):
        m = nominal.copy()
        draw_calibration(m, nominal, factors)
        return m

    return make


@pytest.fixture(scope="session")
def closed_loop_case(nominal):
    """name -> Recording of a 10 min closed-loop run (cached)."""
    from civic.plant.control import run_closed_loop
    from civic.plant.simulate import Recording

    cache = {}

    def get(name, seed=11, extra_water=0.0, controller="mpc"):
        """extra_water: the circuit holds this much more than the model's stated 40 L; controller:
        "mpc" or "pi" (the PI loops)."""
        key = (name, seed, extra_water, controller)
        if key not in cache:
            import numpy as np

            from civic.plant.control import make_schedule, schedule_from_truth

            plant = make_fault(nominal, name)
            if name in BUNDLED_OPERATION or name.startswith("spill"):
                # a bundled case's operation (spills: its setpoints take T2 past 8.5 L)
                case = BUNDLED_OPERATION.get(name, "example_leak_t3")
                schedule = schedule_from_truth(ROOT / "traces" / "diagnose" / case / "truth.json")[0]
            else:
                schedule = make_schedule(DURATION, np.random.default_rng(seed + 100)) if extra_water else None
            x0 = None
            if extra_water:
                sp = schedule[0][2]
                x0 = {"T1": sp[0], "T2": sp[1], "T3": sp[2], "T4": 40.0 + extra_water - sum(sp)}
            res = run_closed_loop(plant, DURATION, controller=controller, seed=seed, noise=True,
                                  controller_model=nominal, schedule=schedule, x0=x0)
            cache[key] = Recording(res.t, res.signals, res.fields, f"closed-loop {name}")
        return cache[key]

    return get
