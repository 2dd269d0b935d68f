"""civic simulate --plants: many plants in one capture, scored per plant."""
from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from civic.cli import main
from civic.wire import read_pcap
from data import TRAINING


def test_fleet_capture_interleaves_plants_and_scores_per_plant(tmp_path, capsys):
    pcap, labels = tmp_path / "fleet.pcap", tmp_path / "labels.csv"
    assert main(["simulate", "drain", "--plants", "12", "--seed", "5", "--src-ip", "10.0.0.20",
                 "-o", str(pcap), "--labels", str(labels)]) == 0
    msgs = read_pcap(pcap).messages
    src = msgs["src"] - (10 << 24) - 20
    assert sorted(np.unique(src)) == list(range(12))
    assert np.all(np.diff(msgs["t"]) >= 0)
    assert np.all(src[:12] == np.arange(12))                     # one message of every plant per period
    for k in range(12):                                           # each plant counts on from its own seq
        assert np.all(np.diff(msgs["seq"][src == k].astype(np.int64)) % 2**32 == 1)
    rows = list(csv.DictReader(labels.open()))
    assert [r["src_ip"] for r in rows] == [f"10.0.0.{20 + k}" for k in range(12)]
    assert [r["class"] for r in rows[:3]] == ["normal", "warning", "error"]

    entries = tmp_path / "entries.json"
    assert main(["train", str(TRAINING), "-o", str(entries)]) == 0
    assert main(["replay", str(pcap), "-o", str(tmp_path / "out.pcap"), "--entries", str(entries)]) == 0
    assert main(["evaluate", str(tmp_path / "out.pcap"), "--labels", str(labels), "--json",
                 str(tmp_path / "scores.json")]) == 0
    capsys.readouterr()
    drain = json.loads((tmp_path / "scores.json").read_text())["monitors"]["drain_t3"]
    assert all(sum(row) >= 4 * 100 for row in drain["confusion"])  # 4 plants of each class, scored
    assert drain["macro_f1"] > 0.9


@pytest.mark.parametrize("argv, words", [
    (["drain", "--plants", "300"], "at most 255"),
    (["drain", "--plants", "10", "--src-ip", "10.0.0.250"], "at most 6"),
    (["drain", "--plants", "0"], "--plants"),
    (["closed-loop", "--plants", "2", "--v0", "5"], "takes no --v0"),
])
def test_bad_fleet_arguments_are_one_line_errors(tmp_path, capsys, argv, words):
    code = main(["simulate", *argv, "-o", str(tmp_path / "x.pcap")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and words in err[0], err
