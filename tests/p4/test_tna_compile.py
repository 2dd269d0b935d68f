"""The Tofino (TNA) program compiles with bf-p4c, and the compiler's output says what
p4src/README.md says it does: 12 stages or fewer, the control-plane objects of the
v1model program (with the two documented TNA differences), the register sizes and widths.

One compile (about 15 s on a 2-core machine) shared by every test of this module.
Skipped when bf-p4c is not on PATH (the open-source Tofino backend, see p4src/README.md).
"""
from __future__ import annotations

import json
import re
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
TNA_MONITORS = 2
MAX_STAGES = 12          # Tofino 1, per pipe

pytestmark = pytest.mark.skipif(shutil.which("bf-p4c") is None,
                                reason="bf-p4c not on PATH (open-source Tofino backend; "
                                       "export PATH=/opt/p4/bin:$PATH, see p4src/README.md)")


@pytest.fixture(scope="module")
def build(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("tna")
    cmd = ["bf-p4c", "--target", "tofino", "--arch", "tna", "-g", "-I", str(ROOT / "p4src"),
           "-o", str(out), str(ROOT / "p4src/tna/civic.p4")]
    res = subprocess.run(cmd, check=False, capture_output=True, text=True, timeout=300)
    log = res.stdout + res.stderr
    assert res.returncode == 0, f"bf-p4c failed:\n{log[-4000:]}"
    assert not re.search(r"\berror\b", log, re.IGNORECASE), f"bf-p4c reported an error:\n{log[-4000:]}"
    return out


def resource_rows(build: Path) -> list[dict[str, str]]:
    """The per-stage rows of the first table of mau.resources.log (absolute counts)."""
    text = (build / "pipe/logs/mau.resources.log").read_text()
    lines = [ln for ln in text.splitlines() if ln.startswith("|")]
    lines = lines[next(i for i, ln in enumerate(lines) if "Stage Number" in ln):]
    header = [c.strip() for c in lines[0].strip("|").split("|")]
    rows = []
    for ln in lines[1:]:
        cells = [c.strip() for c in ln.strip("|").split("|")]
        if cells[0] == "Totals":
            break
        if cells[0].isdigit():
            rows.append(dict(zip(header, cells)))
    return rows


def bfrt_tables(build: Path) -> dict[str, dict]:
    return {t["name"]: t for t in json.loads((build / "bfrt.json").read_text())["tables"]}


def test_binary_is_written(build):
    assert (build / "pipe/tofino.bin").stat().st_size > 0
    assert (build / "bfrt.json").is_file() and (build / "pipe/context.json").is_file()


def test_fits_in_twelve_stages(build):
    rows = resource_rows(build)
    used = [int(r["Stage Number"]) for r in rows if int(r["Logical TableID"]) > 0]
    assert used and max(used) < MAX_STAGES, used
    # ingress (the long one) as the final table placement reports it
    summary = (build / "pipe/logs/table_summary.log").read_text()
    ingress = [int(n) for n in re.findall(r"Number of stages for ingress table allocation: (\d+)", summary)]
    assert ingress and ingress[-1] <= MAX_STAGES, ingress
    # metrics.json agrees that something was placed in TCAM and SRAM
    mau = json.loads((build / "pipe/logs/metrics.json").read_text())["mau"]
    assert mau["srams"] > 0 and mau["tcams"] > 0


def test_stateful_alus_per_stage(build):
    """At most 4 register actions (stateful ALUs) per stage; 11 registers in all."""
    rows = resource_rows(build)
    salus = [int(r["Meter ALU"]) for r in rows]
    assert max(salus) <= 4 and sum(salus) == 1 + 5 * TNA_MONITORS, salus


def test_control_plane_objects(build):
    tables = bfrt_tables(build)
    want = {"pipe.CivicIngress.forward": ["ingress_port"],
            "pipe.CivicIngress.monitored_port": ["dst_port"],
            "pipe.CivicIngress.plant_prefix": ["src_addr"]}
    for k in range(TNA_MONITORS):
        m = f"pipe.CivicIngress.mon{k}"
        want[f"{m}.config"] = []
        # TNA: precondition split in two (bf-p4c fits at most six 16-bit range keys in a table)
        want[f"{m}.precondition"] = ["l1", "l2", "l3", "l4", "$MATCH_PRIORITY"]
        want[f"{m}.precondition_cmd"] = ["p1", "v1", "v2", "$MATCH_PRIORITY"]
        # TNA: the 32-bit slope_key range as two 16-bit halves (range keys <= 4 nibbles)
        want[f"{m}.classify"] = ["slope_key_hi", "slope_key_lo", "level", "$MATCH_PRIORITY"]
    for name, keys in want.items():
        assert name in tables, name
        assert [k["name"] for k in tables[name]["key"]] == keys, name
    match_tables = {n for n, t in tables.items() if t["table_type"] == "MatchAction_Direct"}
    assert match_tables == set(want), "no @hidden step table may reach the control plane"
    for k in range(TNA_MONITORS):
        m = f"pipe.CivicIngress.mon{k}"
        for name in ("precondition", "precondition_cmd", "classify"):
            assert {key["match_type"] for key in tables[f"{m}.{name}"]["key"][:-1]} == {"Range"}
        actions = {a["name"]: [d["name"] for d in a.get("data", [])] for a in tables[f"{m}.config"]["action_specs"]}
        assert actions == {f"CivicIngress.mon{k}.set_config": ["enabled", "signal", "window", "ring_len", "lsq"]}
        actions = {a["name"] for a in tables[f"{m}.classify"]["action_specs"]}
        assert actions == {f"CivicIngress.mon{k}.set_class"}


def test_registers(build):
    tables = bfrt_tables(build)
    want = {"pipe.CivicIngress.last_seq": (256, 32)}
    for k in range(TNA_MONITORS):
        m = f"pipe.CivicIngress.mon{k}"
        want.update({f"{m}.ring": (32768, 32), f"{m}.ptr": (256, 8), f"{m}.run": (256, 8),
                     f"{m}.s0": (256, 32), f"{m}.s1": (256, 32)})
    registers = {n: t for n, t in tables.items() if t["table_type"] == "Register"}
    assert set(registers) == set(want)
    for name, (size, width) in want.items():
        t = registers[name]
        assert t["size"] == size, name
        assert t["data"][0]["singleton"]["type"]["width"] == width, name


def test_ring_index_puts_the_slot_in_the_high_bits(build):
    """Ring cell of (slot, ptr) = slot * 128 + ptr: the identity hash {slot, ptr[6:0]} puts its
    first element in the high bits (civic configure reads / clears cells at slot * 128 + i)."""
    bfa = (build / "pipe/civic.bfa").read_text()
    for k in range(TNA_MONITORS):
        m = re.search(rf"hash \d+:\s*\n\s*(\d+)\.\.(\d+): meta\.mon{k}\.ptr\(0\.\.6\)\s*\n"
                      rf"\s*(\d+)\.\.(\d+): meta\.slot", bfa)
        assert m, f"mon{k}: ring index hash layout not found in civic.bfa"
        p_lo, p_hi, s_lo, s_hi = map(int, m.groups())
        assert (p_hi - p_lo, s_lo - p_lo, s_hi - s_lo) == (6, 7, 7)
