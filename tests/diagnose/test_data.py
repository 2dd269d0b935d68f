"""Recordings as diagnosis reads them: sensor fault codes, frozen readings and impossible commands left out."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from civic.cli import main
from civic.diagnose import data
from civic.plant.model import PlantModel
from frames import with_readings

ROOT = Path(__file__).resolve().parents[2]
CASES = ROOT / "traces" / "diagnose"
CASE = CASES / "example_leak_t3" / "case.pcap"      # with_readings' default


@pytest.mark.parametrize("field, value, t0, said", [
    ("l2", 0xFFFF, 300.0, "L2 read 65.535 (beyond its tank)"),         # a sensor's fault code
    ("p1", 0xFFFF, 200.0, "p1 read 65.535 (beyond its range)"),        # a command no pump takes
    ("v2", 2000, 300.0, "v2 read 2 (beyond its range)"),
])
def test_a_fault_code_is_left_out_and_the_leak_still_found(tmp_path, capsys, field, value, t0, said):
    """20 s of a fault code. Before: L2's were explained by an L2 offset and the leak was lost
    (at 200 s, by a sensor map); p1's and v2's were taken as commands held at 100 %, and a P1
    closure from 200 s, a V2 closure from 300 s, came with the leak. Now they are left out, said
    in a warning and in the report."""
    path = tmp_path / "fault.pcap"
    with_readings(path, field, value, t0, t0 + 20.0)
    assert main(["diagnose", str(path), "--json", str(tmp_path / "r.json"), "-q"]) == 0
    rep = json.loads((tmp_path / "r.json").read_text())
    assert [(f["mechanism"], f["component"], f["parameters"]["to"]) for f in rep["findings"]] == [("leak", "T3", "T4")]
    assert rep["findings"][0]["parameters"]["c"] == pytest.approx(0.012, rel=0.05)
    [u] = rep["unreadable"]
    assert u["signal"] == said.split()[0] and 195 <= u["samples"] <= 200
    assert t0 - 0.5 <= u["from_s"] <= t0 + 0.5 and t0 + 19.5 <= u["to_s"] <= t0 + 20.0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and said in err[0] and f"{t0:g}" in err[0]


def test_a_sensor_fault_code_on_a_clean_run_raises_no_alarm_and_keeps_the_replay(tmp_path):
    """A sensor's fault code leaves the inputs known: the open-loop replay still runs (a lost
    message would stop it)."""
    path = tmp_path / "fault.pcap"
    with_readings(path, "l3", 0xFFFF, 200.0, 220.0, CASES / "example_none" / "case.pcap")
    assert main(["diagnose", str(path), "--json", str(tmp_path / "r.json"), "-q"]) == 0
    rep = json.loads((tmp_path / "r.json").read_text())
    assert rep["mismatch"] is False and rep["findings"] == []
    assert [u["signal"] for u in rep["unreadable"]] == ["L3"]
    assert max(rep["fit"]["replay_check"]["rms_over_noise"].values()) < rep["fit"]["replay_check"]["bar"]


def test_readings_beyond_any_tank_are_unreadable_and_the_rest_kept(tmp_path):
    model = PlantModel.from_toml(ROOT / "configs" / "plant.toml")
    path = tmp_path / "beyond.pcap"
    with_readings(path, "l1", 20000, 100.0, 101.0)            # 20 L in a 10 L tank: not a fault code, still impossible
    rec = data.load(path, model)
    assert [u["signal"] for u in rec.unreadable] == ["L1"] and rec.unreadable[0]["values"] == [20.0]
    assert len(rec.t) == 6000 and rec.gaps.sum() == rec.unreadable[0]["samples"] == 10 and not rec.lost.any()
    assert np.max(rec.signals["L1"]) < 11.0                      # interpolated from its neighbours
    clean = data.load(CASE, model)                               # a tank at its rim is readable
    assert clean.unreadable == [] and not clean.gaps.any()
    with_readings(path, "p1", 1200, 100.0, 101.0)               # 120 %: no command; 100.1 % would be one
    rec = data.load(path, model)
    assert [u["signal"] for u in rec.unreadable] == ["p1"] and rec.lost.sum() == 10
    assert np.all(rec.signals["p1"] <= 1.0)


def test_a_frozen_reading_is_left_out_and_the_leak_still_found(tmp_path, capsys):
    """L2 frozen for 120 s at its reading of 300 s (the fill test's drain-down, the record's
    lowest L2). Before: a T2 leak, an L2 offset from 370 s and a pipe23 closure were named and
    T3's leak was lost. Now the frozen samples are left out and said, and the leak is found
    alone."""
    path = tmp_path / "frozen.pcap"
    with_readings(path, "l2", None, 300.0, 420.0)
    assert main(["diagnose", str(path), "--json", str(tmp_path / "r.json"), "-q"]) == 0
    rep = json.loads((tmp_path / "r.json").read_text())
    assert [(f["mechanism"], f["component"], f["parameters"]["to"]) for f in rep["findings"]] == [("leak", "T3", "T4")]
    assert rep["findings"][0]["parameters"]["c"] == pytest.approx(0.012, rel=0.05)
    [u] = rep["unreadable"]
    assert u["signal"] == "L2" and u["beyond"] is None and 1195 <= u["samples"] <= 1200
    assert 299.5 <= u["from_s"] <= 300.5 and 419.5 <= u["to_s"] <= 420.0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "L2 frozen at" in err[0] and "300" in err[0] and "left out" in err[0]


def test_a_brief_frozen_reading_on_a_clean_run_raises_no_alarm(tmp_path):
    path = tmp_path / "frozen.pcap"
    with_readings(path, "l4", None, 100.0, 102.0, CASES / "example_none" / "case.pcap")
    assert main(["diagnose", str(path), "--json", str(tmp_path / "r.json"), "-q"]) == 0
    rep = json.loads((tmp_path / "r.json").read_text())
    assert rep["mismatch"] is False and rep["findings"] == []
    assert [(u["signal"], u["samples"]) for u in rep["unreadable"]] == [("L4", 20)]


def test_no_bundled_recording_reads_as_frozen():
    """The rigs' own noise: exact repeats of 2-4 samples at most, no sample left out."""
    model = PlantModel.from_toml(ROOT / "configs" / "plant.toml")
    paths = sorted((ROOT / "traces").glob("*/*.pcap")) + sorted(CASES.glob("*/case.pcap"))
    assert len(paths) > 30
    for path in paths:
        assert data.load(path, model).unreadable == [], path.name
    ct = PlantModel.from_toml(ROOT / "configs" / "cascaded-tanks.toml")
    assert data.load(ROOT / "traces" / "cascaded-tanks" / "estimation.csv", ct).unreadable == []   # no resolution


def test_a_recording_mostly_unreadable_is_one_line_error(tmp_path, capsys):
    path = tmp_path / "dead.pcap"
    with_readings(path, "l3", 0xFFFF, 0.0, 400.0)
    assert main(["diagnose", str(path), "-q"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "more than half of the samples" in err and "L3" in err
    with_readings(path, "l3", None, 0.0, 400.0)
    assert main(["diagnose", str(path), "-q"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "frozen at one reading in more than half of the samples" in err and "L3" in err
