"""`civic configure` against a real simple_switch_grpc (BMv2) in a network namespace.

Pipeline push, install, a no-op re-run, a changed entries file (insert, modify,
delete), a write the switch rejects (the previous entries stay), and the one-line
errors for an unreachable switch and a pipeline that is not CIVIC's. The
request-building details are unit-tested against a recording servicer in
tests/switch/.
"""
from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from needs import BMV2

pytestmark = BMV2

ROOT = Path(__file__).resolve().parents[2]


def civic(*argv) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "civic", *map(str, argv)], capture_output=True, text=True,
                          cwd=ROOT, env={**os.environ, "COLUMNS": "200"})


def counts(out: str) -> tuple[int, ...]:
    """(added, modified, deleted, unchanged) from civic configure's table."""
    rows = [tuple(map(int, m)) for m in re.findall(r"│\s*(\d+)\s*│\s*(\d+)\s*│\s*(\d+)\s*│\s*(\d+)\s*│", out)]
    assert len(rows) == 1, out
    return rows[0]


def one_line_error(res: subprocess.CompletedProcess, *words) -> None:
    assert res.returncode == 2, res.stdout + res.stderr
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in res.stderr, res.stderr
    for w in words:
        assert w in lines[0], lines[0]


@pytest.fixture
def switch():
    """A bare BMv2 (no pipeline, nobody connected); `civic configure` is its controller."""
    from civic.switch.bmv2 import BMv2Switch
    with BMv2Switch(None, controller=False) as sw:
        yield sw


@pytest.fixture(scope="module")
def entry_files(tmp_path_factory, trained_entries):
    d = tmp_path_factory.mktemp("configure")
    trained_entries.save(d / "e1.json")
    doc = json.loads((d / "e1.json").read_text())
    # e2: one class changed (modify), another monitor's last row gone (delete), a new UDP port (insert + delete)
    doc["monitors"][0]["classes"][0]["class"] = 1 + doc["monitors"][0]["classes"][0]["class"] % 3
    doc["monitors"][1]["classes"].pop()
    doc["udp_port"] = 50005
    (d / "e2.json").write_text(json.dumps(doc))
    # e3: e1 with five of monitor 0's rows split in two along the level (five more entries)
    doc = json.loads((d / "e1.json").read_text())
    rows, split = doc["monitors"][0]["classes"], 0
    for r in list(rows):
        lo, hi = r["level"]
        if hi > lo and split < 5:
            rows.append({**r, "level": [(lo + hi) // 2 + 1, hi]})
            r["level"] = [lo, (lo + hi) // 2]
            split += 1
    assert split == 5
    (d / "e3.json").write_text(json.dumps(doc))
    return d


def test_install_converge_change_and_read(switch, v1model_build, entry_files):
    e1, e2 = entry_files / "e1.json", entry_files / "e2.json"
    n1 = len(json.loads(e1.read_text())["monitors"][0]["classes"])

    res = civic("configure", "--switch", switch.address, "--entries", e1, "--pipeline", v1model_build)
    assert res.returncode == 0, res.stderr
    assert "pipeline installed" in res.stdout
    added, modified, deleted, unchanged = counts(res.stdout)
    assert added > n1 and deleted == 0                     # defaults that differ from the initial ones: modified
    total = added + modified + unchanged

    res = civic("configure", "--switch", switch.address, "--entries", e1, "--pipeline", v1model_build)
    assert res.returncode == 0, res.stderr
    assert counts(res.stdout) == (0, 0, 0, total) and "nothing written" in res.stdout
    assert "pipeline installed" not in res.stdout

    res = civic("configure", "--switch", switch.address, "--entries", e2)        # pipeline already there
    assert res.returncode == 0, res.stderr
    assert counts(res.stdout) == (1, 1, 2, total - 3)
    assert "verified by read-back" in res.stdout

    res = civic("configure", "--switch", switch.address, "--read")
    assert res.returncode == 0, res.stderr
    assert "50005" in res.stdout and "monitored_port" in res.stdout
    assert res.stdout.count("mon0.classify") == n1 + 1              # the entries and the default action

    res = civic("configure", "--switch", switch.address, "--entries", e1)
    assert res.returncode == 0 and counts(res.stdout) == (2, 1, 1, total - 3)


def test_rejected_write_leaves_previous_entries(switch, v1model_build, entry_files, tmp_path):
    """A switch that holds fewer classify entries than the P4Info says rejects the overflow; nothing half-done."""
    e1, e3 = entry_files / "e1.json", entry_files / "e3.json"
    n1 = len(json.loads(e1.read_text())["monitors"][0]["classes"])
    small = tmp_path / "small"
    shutil.copytree(v1model_build, small)
    cfg = json.loads((small / "civic.json").read_text())
    tables = [t for p in cfg["pipelines"] for t in p["tables"] if t["name"].endswith("mon0.classify")]
    assert len(tables) == 1
    tables[0]["max_size"] = n1 + 2
    (small / "civic.json").write_text(json.dumps(cfg))

    res = civic("configure", "--switch", switch.address, "--entries", e1, "--pipeline", small)
    assert res.returncode == 0, res.stderr
    total = sum(counts(res.stdout)) - counts(res.stdout)[2]
    res = civic("configure", "--switch", switch.address, "--entries", e3, "--pipeline", small)
    one_line_error(res, "rejected", "rolled back")
    res = civic("configure", "--switch", switch.address, "--entries", e1, "--pipeline", small)
    assert res.returncode == 0 and counts(res.stdout) == (0, 0, 0, total)


def test_unreachable_and_foreign_pipeline_are_one_line_errors(switch, v1model_build, entry_files, tmp_path):
    e1 = entry_files / "e1.json"
    one_line_error(civic("configure", "--switch", "127.0.0.1:1", "--entries", e1, "--timeout", "1"),
                   "cannot reach switch 127.0.0.1:1")
    one_line_error(civic("configure", "--switch", switch.address, "--entries", e1), "no pipeline installed")

    from civic.switch.bmv2 import compile_v1model
    fwd = tmp_path / "fwd"
    compile_v1model(ROOT / "bench" / "p4" / "forward.p4", fwd)
    one_line_error(civic("configure", "--switch", switch.address, "--entries", e1, "--pipeline", fwd),
                   "P4Info has no table")
    # the switch runs another program: configure without --pipeline says it is not CIVIC's
    from civic.switch.connection import SwitchConnection
    from civic.switch.pipeline import load_pipeline
    pipe = load_pipeline(fwd)
    with SwitchConnection(switch.address) as conn:
        conn.set_pipeline(pipe.get_pipeline_config())
    one_line_error(civic("configure", "--switch", switch.address, "--entries", e1), "P4Info has no table")
    # a P4Info that does not belong to the BMv2 JSON: BMv2's PI takes the pair without a check,
    # the first Read of a CIVIC table then fails (one line, still)
    mixed = tmp_path / "mixed"
    mixed.mkdir()
    shutil.copy(fwd / "civic.json", mixed / "civic.json")
    shutil.copy(v1model_build / "civic.p4info.txtpb", mixed / "civic.p4info.txtpb")
    one_line_error(civic("configure", "--switch", switch.address, "--entries", e1, "--pipeline", mixed),
                   f"switch {switch.address}")
