"""Recordings as diagnosis reads them: sensor fault codes left out as lost messages."""
from __future__ import annotations

import copy
import json
from pathlib import Path

import numpy as np
import pytest

from civic.cli import main
from civic.diagnose import data
from civic.errors import CivicError
from civic.plant.model import PlantModel
from civic.wire import OFF_PAYLOAD, OFF_UDP_CSUM, SIGNALS, read_pcap

ROOT = Path(__file__).resolve().parents[2]
CASE = ROOT / "traces" / "diagnose" / "example_leak_t3" / "case.pcap"


def with_readings(dst: Path, signal: str, value: int, t_from: float, t_to: float) -> None:
    """The bundled leak case with `signal` reading `value` (wire units) from t_from to t_to s
    (UDP checksums set to 0: no checksum, valid for IPv4)."""
    cap = copy.deepcopy(read_pcap(CASE))
    t = cap.messages["t"] - cap.messages["t"][0]
    buf = np.frombuffer(cap.data, np.uint8)
    at = cap.offset[(t >= t_from) & (t < t_to)]
    field = OFF_PAYLOAD + 4 + 2 * SIGNALS.index(signal)
    buf[at + field], buf[at + field + 1] = value >> 8, value & 0xFF
    buf[at + OFF_UDP_CSUM] = buf[at + OFF_UDP_CSUM + 1] = 0
    cap.write(dst)


def test_a_sensor_fault_code_is_left_out_and_the_leak_still_found(tmp_path, capsys):
    """L2 reads 0xFFFF for 20 s: before, the diagnosis fitted a sensor map to those readings
    and lost the leak; now they are lost messages, said in a warning and in the report."""
    path = tmp_path / "fault.pcap"
    with_readings(path, "l2", 0xFFFF, 200.0, 220.0)
    assert main(["diagnose", str(path), "--json", str(tmp_path / "r.json"), "-q"]) == 0
    rep = json.loads((tmp_path / "r.json").read_text())
    assert [(f["mechanism"], f["component"], f["parameters"]["to"]) for f in rep["findings"]] == [("leak", "T3", "T4")]
    assert rep["findings"][0]["parameters"]["c"] == pytest.approx(0.012, rel=0.05)
    [u] = rep["unreadable"]
    assert u["signal"] == "L2" and u["values"] == [65.535] and 195 <= u["samples"] <= 200
    assert 199.5 <= u["from_s"] <= 200.5 and 219.5 <= u["to_s"] <= 220.0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "sensor L2 read 65.535" in err[0] and "left out as lost messages" in err[0]


def test_readings_beyond_any_tank_are_unreadable_and_the_rest_kept(tmp_path):
    model = PlantModel.from_toml(ROOT / "configs" / "plant.toml")
    path = tmp_path / "beyond.pcap"
    with_readings(path, "l1", 20000, 100.0, 101.0)            # 20 L in a 10 L tank: not a fault code, still impossible
    rec = data.load(path, model)
    assert [u["signal"] for u in rec.unreadable] == ["L1"] and rec.unreadable[0]["values"] == [20.0]
    assert len(rec.t) == 6000 and rec.gaps.sum() == rec.unreadable[0]["samples"] == 10
    assert np.max(rec.signals["L1"]) < 11.0
    clean = data.load(CASE, model)                               # a tank at its rim is readable
    assert clean.unreadable == [] and not clean.gaps.any()


def test_a_recording_mostly_unreadable_is_one_line_error(tmp_path, capsys):
    path = tmp_path / "dead.pcap"
    with_readings(path, "l3", 0xFFFF, 0.0, 400.0)
    assert main(["diagnose", str(path), "-q"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "more than half of the samples" in err and "L3" in err
