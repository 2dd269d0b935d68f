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


def test_flow_law_exponent_shift_of_two_hundredths_is_a_finding():
    """0.01 off Torricelli bends the flow by 2.2 % over a 1:9 span of heads: not negligible
    (V2 n = 0.45 was fitted 0.473 and 0.482 when the calibration traded with it); 0.005 is."""
    m = PlantModel.from_toml(MODEL)
    law = FlowLaw("out1", {"exponent": 0.5}, {}, {"form": "exponent"})
    assert not law.negligible({"exponent": 0.482}, m) and not law.negligible({"exponent": 0.515}, m)
    assert law.negligible({"exponent": 0.495}, m) and law.negligible({"exponent": 0.505}, m)


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
    from civic.diagnose.problem import Calibration, Problem
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


def test_spill_below_the_rim_of_an_unmeasured_tank():
    """Free run: an unmeasured tank gets a finite spill to outside above a crest just below the rim
    of its split spill (read when it edits, after that spill), a candidate of its own next to the
    split spill in the joint fit."""
    from civic.diagnose.backward import free_rim_last, general_candidates
    from civic.diagnose.problem import Calibration, Problem
    from civic.diagnose.locate import Localisation
    from civic.diagnose.mechanisms import Overflow
    from civic.diagnose.mechanisms.overflow import SpillOut

    m = PlantModel.from_toml(MODEL)
    loc = Localisation("simulation", ["y_V"], tanks=["T1", "T2"], unmeasured=["T1"],
                       max_volume={"T1": 20.0, "T2": 10.0}, signals_present=["y_V"])
    (c,) = SpillOut.candidates(m, loc)
    assert c.component == "T1" and c.fixed["to"] == "outside" and c.name == "overflow" and c.late
    split = next(x for x in Overflow.candidates(m, loc) if "fraction" in x.params)
    prob = Problem.__new__(Problem)          # only the model edits (no engine needed)
    prob.model, prob.cal = m, Calibration.of(m)
    rim = 8.0 * 2.177                        # the split spill's rim: T1 at 8 dm
    built = prob.build([c, split], [np.array([0.02, 0.75]), np.array([rim, 0.6])], np.ones(len(prob.cal)))
    assert abs(c.onset_volume(built) - 0.75 * rim) < 1e-9     # crest at 6 dm, whatever the order
    # nothing below the crest, c*(h - crest) above it, all of it leaving the plant
    V = np.array([[5.0 * 2.177, 2.0], [7.0 * 2.177, 2.0]])
    ref = split.apply(m, [rim, 0.6])
    f0, f = (flows(x, V, np.zeros((2, 0)), np.zeros((2, 1))) for x in (ref, built))
    lost = f0.net[:, 0] - f.net[:, 0]
    assert abs(lost[0]) < 1e-12 and abs(lost[1] - 0.02 * 1.0) < 1e-12
    assert np.allclose(f.net[:, 1], f0.net[:, 1]) and abs(f.outside[1] - f0.outside[1] - 0.02) < 1e-12
    # without a rim on the tank, the crest is a fraction of the candidate's range top
    alone = c.apply(m, [0.02, 0.5])
    assert abs(c.onset_volume(alone) - 10.0) < 1e-9
    # measured plants (equation error) get none; in the joint fit it does not displace the split
    assert SpillOut.candidates(m, Localisation("equation", ["T1"], tanks=["T1"])) == []
    general = sorted(general_candidates(Overflow.candidates(m, loc) + [c]), key=free_rim_last)
    assert c in general and "fraction" in general[-1].params
    assert c.negligible({"c": 1e-5, "crest": 0.9}, m) and not c.negligible({"c": 0.02, "crest": 0.9}, m)


def test_backward_elimination_keeps_a_parameter_free_finding_on_a_tie():
    """A finding with free parameters goes when its removal raises the held-out RMSE by less than
    1 %; one without (a spill where the sensor clips) only when its removal lowers it by 5 %."""
    from civic.diagnose.backward import FIXED_ABLATION, MIN_ABLATION, _removable
    from civic.diagnose.mechanisms.overflow import AtClip

    m = PlantModel.from_toml(MODEL)
    clip = AtClip("T2", {}, {}, {"volume": 10.0, "to": "outside", "sensor": "y_V", "reading": 10.0}, model=m)
    law = FlowLaw("out2", {"exponent": 0.4}, {"exponent": (0.15, 2.0)}, {"form": "exponent"})
    tie = 1.0 + 0.5 * MIN_ABLATION
    assert _removable(law, tie) and not _removable(clip, tie)
    assert not _removable(clip, 1.0 - 0.5 * FIXED_ABLATION) and _removable(clip, 1.0 - 1.5 * FIXED_ABLATION)
    assert not _removable(law, 1.0 + 2.0 * MIN_ABLATION)


def test_elimination_starts_from_the_tied_optimum_where_most_mechanisms_act():
    """Joint-fit optima within BASIN_TIE of the best cost are a tie the data do not break: the
    one where more mechanisms act goes to the elimination (the held-out judgement decides them,
    not rounding); one clearly cheaper wins whatever acts in the others."""
    from civic.diagnose.backward import BASIN_TIE, _widest_of_tied
    from civic.diagnose.mechanisms import PumpHead
    from civic.diagnose.problem import FitResult

    m = PlantModel.from_toml(MODEL)

    class Prob:
        model = m

    law = FlowLaw("out2", {"exponent": 0.4}, {"exponent": (0.15, 2.0)}, {"form": "exponent"})

    def res(cost, head):
        return FitResult([law, PumpHead("P1", {"head_coeff": head}, {"head_coeff": (0.0, 0.2)})],
                         np.ones(3), {}, cost, 0.0, 0.0, 2, m)

    sparse, wide = res(1000.0, 0.0002), res(1000.0 * (1 + 0.5 * BASIN_TIE), 0.05)
    assert _widest_of_tied(Prob(), [sparse, wide]) is wide
    assert _widest_of_tied(Prob(), [wide, sparse]) is wide
    far = res(1000.0 * (1 + 2 * BASIN_TIE), 0.05)
    assert _widest_of_tied(Prob(), [sparse, far]) is sparse
    twin = res(1000.0 * (1 + 0.2 * BASIN_TIE), 0.0002)
    assert _widest_of_tied(Prob(), [twin, sparse]) is sparse     # same acting set: the cheaper


def test_a_sensor_map_already_bent_is_not_bent_again():
    """A model improved by a quadratic map (written by --write-model) diagnosed again: no power map
    is offered on top of that sensor's curvature (the model file cannot hold both)."""
    from civic.diagnose.locate import Localisation

    m = PlantModel.from_toml(MODEL.parent / "plant.toml")
    loc = Localisation("equation", ["T2"], tanks=["T1", "T2"], signals_present=["L1", "L2"],
                      signal_span={"L1": 5.0, "L2": 5.0}, signal_range={"L1": (4.0, 9.0), "L2": (3.5, 8.5)})
    assert [c.component for c in SensorCharacteristic.candidates(m, loc)] == ["L1", "L2"]
    m.find("sensor", "L2").curvature = 0.02
    assert [c.component for c in SensorCharacteristic.candidates(m, loc)] == ["L1"]
