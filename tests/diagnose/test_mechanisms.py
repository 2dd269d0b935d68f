"""The catalogue's real-rig families edit a model into the physics they name (tests/diagnose)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from civic.diagnose.mechanisms import CATALOGUE, FlowLaw, PumpDeadZone, SensorCharacteristic
from civic.diagnose.mechanisms.base import Mechanism
from civic.plant.model import PlantModel
from civic.plant.simulate import flows, simulate

MODEL = Path(__file__).resolve().parents[2] / "configs" / "cascaded-tanks.toml"


def test_every_family_is_a_mechanism_with_its_own_name():
    assert all(issubclass(f, Mechanism) for f in CATALOGUE)
    names = {f.name for f in CATALOGUE}
    assert {"flow_law", "sensor_characteristic", "pump_dead_zone", "overflow", "leak"} <= names


def test_flow_law_forms_change_the_outflow():
    m = PlantModel.from_toml(MODEL)
    V = np.array([[4.0 * 2.177, 3.0]])           # T1 at 4 dm, T2 at 3 dm
    q0 = flows(m, V, np.zeros((1, 0)), np.zeros((1, 1))).links[0, 0]
    assert q0 == np.float64(0.0684 * 2.0)
    ex = FlowLaw("out1", {"exponent": 0.8}, {}, {"form": "exponent"}).apply(m)
    q = flows(ex, V, np.zeros((1, 0)), np.zeros((1, 1))).links[0, 0]
    assert abs(q - 0.0684 * 4.0 ** 0.8) < 1e-12
    lin = FlowLaw("out1", {"linear": 0.01}, {}, {"form": "linear"}).apply(m)
    f = flows(lin, V, np.zeros((1, 0)), np.zeros((1, 1)))
    assert abs(f.net[0, 1] - (0.0684 * 2.0 + 0.01 * 4.0 - 0.0497 * np.sqrt(3.0))) < 1e-12


def test_pump_dead_zone_and_sensor_characteristic():
    m = PlantModel.from_toml(MODEL)
    dz = PumpDeadZone("P1", {"threshold": 1.0}, {}, {"umax": 10.0}).apply(m)
    q = flows(dz, np.array([[1.0, 1.0], [1.0, 1.0]]), np.zeros((2, 0)), np.array([[0.8], [3.0]])).pumps[:, 0]
    assert q[0] == 0.0 and abs(q[1] - 0.0405 * 2.0) < 1e-12
    sc = SensorCharacteristic("y_V", {"exponent": 1.3, "offset": 0.5, "gain": 0.7}, {},
                              {"base": 0.0, "base_gain": 1.0}).apply(m)
    t = np.arange(3) * m.dt
    y = simulate(sc, t, {"u_V": np.zeros(3)}, {"T1": 0.0, "T2": 4.0})["y_V"][0]
    assert abs(y - (0.7 * 4.0 ** 1.3 + 0.5)) < 1e-12


def test_spill_at_the_clip_follows_a_fitted_sensor_map():
    """A measured tank whose sensor sits at its clip spills where that sensor clips, also when
    a sensor map fitted with it moves that level (the rim is read after the map's edit,
    whatever the order of the candidates)."""
    from civic.diagnose.fit import Calibration, Problem
    from civic.diagnose.mechanisms.overflow import AtClip

    m = PlantModel.from_toml(MODEL)
    spill = AtClip("T2", {}, {}, {"volume": 10.0, "to": "outside", "sensor": "y_V", "reading": 10.0}, model=m)
    sensor = SensorCharacteristic("y_V", {"exponent": 1.6, "offset": 1.8, "gain": 0.5},
                                  {"exponent": (0.5, 2.0), "offset": (-2.0, 2.0), "gain": (0.2, 3.0)},
                                  {"base": 0.0, "base_gain": 1.0})
    prob = Problem.__new__(Problem)          # only the model edits (no engine needed)
    prob.model, prob.cal = m, Calibration.of(m)
    built = prob.build([spill, sensor], [spill.x0, sensor.x0], np.ones(len(prob.cal)))
    s = built.find("sensor", "y_V")
    rim = built.tank("T2").overflow.volume
    assert abs(float(s.read(rim / built.tank("T2").area)) - 10.0) < 1e-9
    assert abs(rim - 10.0) > 0.5                # the nominal map's 10 L would no longer be the clip
    # under the nominal map the rim is the clip volume of the nominal sensor
    alone = prob.build([spill], [spill.x0], np.ones(len(prob.cal)))
    assert abs(alone.tank("T2").overflow.volume - 10.0) < 1e-9
    assert spill.n_params == 1 and "reading" not in spill.values() and spill.label == "overflow(T2->outside)"
