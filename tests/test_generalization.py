"""Tables trained on the 7.5 L recordings, scored on simulated drain tests from other start levels
and other units of the plant type, through the commands a user runs."""
from __future__ import annotations

import json

import numpy as np
import pytest

from civic.cli import main
from civic.evalsets import spread_unit
from civic.plant.model import PlantModel
from data import ROOT, TRAINING

START_LEVELS = ("5.0", "5.5", "6.5", "9.5")


@pytest.fixture(scope="module")
def simulated(tmp_path_factory):
    """One drain test per class and start level, each on its own unit (coefficients ±3 %)."""
    folder = tmp_path_factory.mktemp("sim")
    rng = np.random.default_rng(41)
    datasheet = PlantModel.from_toml(ROOT / "configs/plant.toml")
    seed = 500
    for v0 in START_LEVELS:
        for cls in ("normal", "warning", "error"):
            seed += 1
            unit = folder / f"unit{seed}.toml"
            spread_unit(datasheet, rng, 0.03).to_toml(unit)
            assert main(["simulate", "drain", "--model", str(unit), "--v0", v0, "--fault", f"vm1={cls}",
                         "--seed", str(seed), "-o", str(folder / f"d{v0}_{cls}.pcap"),
                         "--labels", str(folder / "labels.csv")]) == 0
    return folder


def macro_f1(folder, flags, tmp):
    entries = tmp / ("e" + "".join(flags) + ".json")
    assert main(["train", str(TRAINING), "-o", str(entries), *flags]) == 0
    out = tmp / ("out" + "".join(flags))
    assert main(["replay", *map(str, sorted(folder.glob("*.pcap"))), "-o", str(out), "--entries", str(entries)]) == 0
    assert main(["evaluate", str(out), "--labels", str(folder / "labels.csv"), "--json", str(tmp / "s.json")]) == 0
    return json.loads((tmp / "s.json").read_text())["monitors"]["drain_t3"]


def test_default_training_holds_at_other_start_levels(simulated, tmp_path):
    s = macro_f1(simulated, [], tmp_path)
    assert s["macro_f1"] >= 0.99
    assert s["classes"]["error"]["recall"] == 1.0     # missing an error is the worst mistake
    assert s["undetected_runs"] == 0


def test_the_previous_default_misses_errors_from_low_start_levels(simulated, tmp_path):
    s = macro_f1(simulated, ["--no-calibrate"], tmp_path)
    assert s["classes"]["error"]["recall"] < 1.0


def test_paper_mode_does_not(simulated, tmp_path):
    s = macro_f1(simulated, ["--estimator", "endpoint", "--no-banded"], tmp_path)
    assert s["macro_f1"] < 0.85


def test_tables_from_the_model_alone_classify_the_real_recordings(capsys, tmp_path):
    assert main(["train", "--from-model", "-o", str(tmp_path / "m.json")]) == 0
    assert main(["replay", *map(str, sorted(TRAINING.glob("*.pcap"))), "-o", str(tmp_path / "out"),
                 "--entries", str(tmp_path / "m.json")]) == 0
    assert main(["evaluate", str(tmp_path / "out"), "--labels", str(TRAINING / "labels.csv"),
                 "--json", str(tmp_path / "s.json")]) == 0
    report = json.loads((tmp_path / "s.json").read_text())["monitors"]
    assert report["drain_t3"]["macro_f1"] >= 0.98 and report["fill_t1"]["macro_f1"] >= 0.98


def test_train_needs_exactly_one_source(capsys, tmp_path):
    assert main(["train", "-o", str(tmp_path / "x.json")]) == 2
    assert "TRAINING_DIR or --from-model" in capsys.readouterr().err
