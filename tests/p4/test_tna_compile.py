"""The Tofino (TNA) program compiles with bf-p4c, and the compiler's output says what
p4src/README.md says it does: 12 stages or fewer, the control-plane objects of the
v1model program (with the documented TNA differences), the register sizes and widths,
and the compensation (pipeline.md 3a) in no stage of its own: aux and compensate are
placed before the stage-4 step that adds compensate's bias.

Both compile-time profiles: the default p4src/tna/civic.p4 (test monitors drain_t3, fill_t1
as mon0, mon1) and p4src/tna/civic_balance.p4 (it defines CIVIC_PROFILE_BALANCE: balance
monitors balance_t3, balance_t1 as mon2, mon3; pipeline.md 3b). One compile per profile (about 10 s each on a 2-core machine), shared by
the tests of that profile. Skipped when bf-p4c is not on PATH (the open-source Tofino
backend, see p4src/README.md); the arithmetic transcriptions run without it.
"""
from __future__ import annotations

import json
import re
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
pytestmark = pytest.mark.tofino

TNA_MONITORS = 2
MAX_STAGES = 12          # Tofino 1, per pipe

needs_bf_p4c = pytest.mark.skipif(shutil.which("bf-p4c") is None,
                                  reason="bf-p4c not on PATH (open-source Tofino backend; "
                                         "export PATH=/opt/p4/bin:$PATH, see p4src/README.md)")


def compile_tna(out: Path, program: str) -> Path:
    if shutil.which("bf-p4c") is None:
        pytest.skip("bf-p4c not on PATH (open-source Tofino backend; "
                    "export PATH=/opt/p4/bin:$PATH, see p4src/README.md)")
    cmd = ["bf-p4c", "--target", "tofino", "--arch", "tna", "-g", "-I", str(ROOT / "p4src"),
           "-o", str(out), str(ROOT / "p4src/tna" / program)]
    res = subprocess.run(cmd, check=False, capture_output=True, text=True, timeout=300)
    log = res.stdout + res.stderr
    assert res.returncode == 0, f"bf-p4c failed:\n{log[-4000:]}"
    assert not re.search(r"\berror\b", log, re.IGNORECASE), f"bf-p4c reported an error:\n{log[-4000:]}"
    return out


@pytest.fixture(scope="module")
def build(tmp_path_factory) -> Path:
    """The default profile: drain_t3, fill_t1."""
    return compile_tna(tmp_path_factory.mktemp("tna"), "civic.p4")


@pytest.fixture(scope="module")
def build_balance(tmp_path_factory) -> Path:
    """The balance profile: balance_t3, balance_t1 (include/config.p4)."""
    return compile_tna(tmp_path_factory.mktemp("tna_balance"), "civic_balance.p4")


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


def bfa(build: Path) -> str:
    """The assembler source (pipe/civic.bfa, pipe/civic_balance.bfa)."""
    return next((build / "pipe").glob("*.bfa")).read_text()


def ingress_stages(build: Path) -> dict[str, int]:
    """First ingress stage of every table in civic.bfa, by P4 name (@hidden steps included)."""
    stages: dict[str, int] = {}
    stage = None
    for line in bfa(build).splitlines():
        if m := re.match(r"stage (\d+) (ingress|egress):", line):
            stage = int(m.group(1)) if m.group(2) == "ingress" else None
        elif stage is not None and (m := re.match(r"\s+p4: \{ name: ([\w.$]+)", line)):
            stages.setdefault(m.group(1), stage)
    return stages


@needs_bf_p4c
def test_binary_is_written(build):
    assert (build / "pipe/tofino.bin").stat().st_size > 0
    assert (build / "bfrt.json").is_file() and (build / "pipe/context.json").is_file()


@needs_bf_p4c
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


@needs_bf_p4c
def test_stateful_alus_per_stage(build):
    """At most 4 register actions (stateful ALUs) per stage; 13 registers in all (last_seq, and per
    slot ring, ptr, run, s0, s1, last_class)."""
    rows = resource_rows(build)
    salus = [int(r["Meter ALU"]) for r in rows]
    assert max(salus) <= 4 and sum(salus) == 1 + 6 * TNA_MONITORS, salus


@needs_bf_p4c
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
        want[f"{m}.compensate"] = ["aux", "$MATCH_PRIORITY"]
    for name, keys in want.items():
        assert name in tables, name
        assert [k["name"] for k in tables[name]["key"]] == keys, name
    match_tables = {n for n, t in tables.items() if t["table_type"] == "MatchAction_Direct"}
    assert match_tables == set(want), "no @hidden step table may reach the control plane"
    for k in range(TNA_MONITORS):
        m = f"pipe.CivicIngress.mon{k}"
        for name in ("precondition", "precondition_cmd", "classify", "compensate"):
            assert {key["match_type"] for key in tables[f"{m}.{name}"]["key"][:-1]} == {"Range"}
        actions = {a["name"]: [d["name"] for d in a.get("data", [])] for a in tables[f"{m}.config"]["action_specs"]}
        assert actions == {f"CivicIngress.mon{k}.set_config": ["enabled", "signal", "window", "ring_len", "lsq",
                                                               "aux_plus", "aux_minus"]}
        # TNA's set_offset takes the bias the control plane derives from the offset (monitor.p4)
        actions = {a["name"]: [d["name"] for d in a.get("data", [])] for a in tables[f"{m}.compensate"]["action_specs"]}
        assert actions == {f"CivicIngress.mon{k}.set_offset": ["bias"]}
        actions = {a["name"] for a in tables[f"{m}.classify"]["action_specs"]}
        # TNA: one action per class (each runs its own last_class RegisterAction), set_class on a miss
        assert actions == {f"CivicIngress.mon{k}.{a}" for a in ("set_normal", "set_warning", "set_error",
                                                                 "set_class")}


@needs_bf_p4c
def test_registers(build):
    tables = bfrt_tables(build)
    want = {"pipe.CivicIngress.last_seq": (256, 32)}
    for k in range(TNA_MONITORS):
        m = f"pipe.CivicIngress.mon{k}"
        want.update({f"{m}.ring": (32768, 32), f"{m}.ptr": (256, 8), f"{m}.run": (256, 8),
                     f"{m}.s0": (256, 32), f"{m}.s1": (256, 32), f"{m}.last_class": (256, 8)})
    registers = {n: t for n, t in tables.items() if t["table_type"] == "Register"}
    assert set(registers) == set(want)
    for name, (size, width) in want.items():
        t = registers[name]
        assert t["size"] == size, name
        assert t["data"][0]["singleton"]["type"]["width"] == width, name


@needs_bf_p4c
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


@needs_bf_p4c
def test_compensation_takes_no_stage(build):
    """config -> aux -> compensate end before the step that adds compensate's bias (stage 4:
    e = d + bias, lsq; slope_key = d + bias, endpoint), so classify stays where it was."""
    c = config_defines()
    stages = ingress_stages(build)
    for k in range(TNA_MONITORS):
        m = f"CivicIngress.mon{k}"
        add_bias = f"{m}.diff_b" if c[f"MON{k}_LSQ"][0] else f"{m}.key_endpoint"
        chain = [stages[f"{m}.{t}"] for t in ("config", "aux_diff", "compensate")] + [stages[add_bias]]
        assert chain == sorted(set(chain)), (k, chain)      # strictly increasing stages
        # the bias step waits for d = x - old only, not for compensate
        assert stages[add_bias] == stages[f"{m}.diff"] + 1, (k, stages[add_bias])
        # classify before the last ingress stage (which sets the verdict-change digest)
        assert stages[f"{m}.classify"] <= MAX_STAGES - 2, (k, stages[f"{m}.classify"])


@needs_bf_p4c
def test_aux_is_one_saturating_subtract(build):
    """aux = max(x[aux_plus] - x[aux_minus], 0): each of the 12 (plus, minus) actions of the
    @hidden aux_diff table is one saturating unsigned subtract (Tofino `ssubu`)."""
    bfa = (build / "pipe/civic.bfa").read_text()
    for k in range(TNA_MONITORS):
        acts = re.findall(rf"CivicIngress\.mon{k}\.aux_(l\d)_(l\d)\(\d+, \d+\):\n((?:[ \t]+- .*\n)+)", bfa)
        pairs = {(a, b) for a, b, _ in acts}
        assert pairs == {(f"l{i}", f"l{j}") for i in range(1, 5) for j in range(1, 5) if i != j}, k
        for a, b, body in acts:
            ops = [ln.split("-", 1)[1].split()[0] for ln in body.splitlines()
                   if ln.strip().startswith("- ") and ":" not in ln]
            assert ops == ["ssubu"], (k, a, b, body)


@needs_bf_p4c
def test_compensate_default_is_offset_zero(build):
    """compensate's default set_offset(bias) is the slot's key bias: MONk_S0_BIAS (lsq, B) or
    0x80000000 (endpoint), i.e. offset 0 (monitor.p4, p4src/README.md)."""
    c = config_defines()
    bfa = (build / "pipe/civic.bfa").read_text()
    for k in range(TNA_MONITORS):
        start = bfa.index(f"p4: {{ name: CivicIngress.mon{k}.compensate, size: {c['TNA_COMPENSATE_TABLE_SIZE'][0]} }}")
        end = bfa.index("p4: { name:", start + 1)
        m = re.search(r'default_action_parameters:\s*\n\s*bias: "(0x[0-9a-fA-F]+)"', bfa[start:end])
        assert m, f"mon{k}: compensate's default bias not found in civic.bfa"
        want = c[f"MON{k}_S0_BIAS"][0] if c[f"MON{k}_LSQ"][0] else 0x80000000
        assert int(m.group(1), 16) == want, k


# ---------------------------------------------------------------- the arithmetic as compiled
def config_defines() -> dict[str, tuple[int, ...]]:
    text = (ROOT / "p4src/tna/include/config.p4").read_text()
    return {m.group(1): tuple(int(v, 0) for v in m.group(2).split(","))
            for m in re.finditer(r"^#define[ \t]+(\w+)[ \t]+(-?[0-9xA-Fa-f, \t]+?)[ \t]*(?://.*)?$", text, re.MULTILINE)}


def s0_bias(window: int) -> int:
    """2^(31 - k), 2^k the largest power of two dividing W - 1."""
    k = ((window - 1) & -(window - 1)).bit_length() - 1
    return 1 << (31 - k)


def csd(c: int) -> tuple[int, ...]:
    """c as config.p4 MUL arguments (canonical signed digits, most significant first)."""
    digits, i = [], 0
    while c:
        if c & 1:
            d = 2 - (c & 3)
            digits.append((i, d))
            c -= d
        c >>= 1
        i += 1
    digits.sort(reverse=True)
    a = [sh for sh, _ in digits] + [0] * (4 - len(digits))
    return (*a, (1 << len(digits)) - 1, sum(1 << k for k, (_, d) in enumerate(digits) if d < 0))


def const_mul_steps(v: int, a0, a1, a2, a3, used, negs) -> int:
    """CIVIC_CONST_MUL / CIVIC_CONST_MUL_APPLY (const_mul.p4) step by step, bit<32>."""
    m32 = 0xFFFFFFFF
    if used == 1:
        return (v << a0) & m32
    t0, t1 = (v << a0) & m32, (v << a1) & m32
    t2 = (v << a2) & m32 if used & 4 else 0
    t3 = (v << a3) & m32 if used & 8 else 0
    if used == 3:
        return (t0 - t1) & m32 if negs & 2 else (t0 + t1) & m32
    t0 = (t0 - t1) & m32 if negs & 2 else (t0 + t1) & m32
    if used & 8:
        t2 = {4: t3 - t2, 8: t2 - t3}.get(negs & 12, t2 + t3) & m32
        return (t0 - t2) & m32 if negs & 12 == 12 else (t0 + t2) & m32
    return (t0 - t2) & m32 if negs & 4 else (t0 + t2) & m32


def test_configured_slots_are_consistent():
    c = config_defines()
    for k in range(c["TNA_MONITORS"][0]):
        w, r, lsq = c[f"MON{k}_WINDOW"][0], c[f"MON{k}_RING_LEN"][0], c[f"MON{k}_LSQ"][0]
        # the slot's key bias, also compensate's default bias (offset 0)
        assert c[f"MON{k}_S0_BIAS"][0] == (s0_bias(w) if lsq else 0x80000000), f"MON{k}_S0_BIAS"
        for v in (1, 0xFFFF, 0x7FFFFFFF, 0xFFFFFFFF):
            assert const_mul_steps(v, *c[f"MON{k}_R_MUL"]) == (v * r) & 0xFFFFFFFF
            assert const_mul_steps(v, *c[f"MON{k}_W1_MUL"]) == (v * (w - 1)) & 0xFFFFFFFF


@pytest.mark.parametrize("window,lsq", [(20, True), (90, True), (21, True), (2, True), (3, True),
                                        (97, True), (128, True), (20, False), (2, False), (127, False)])
def test_slope_key_steps_match_the_model(window, lsq):
    """monitor.p4's steps (TNA) against the software model: registers and slope_key, with
    compensate's bias for offset 0 and for offsets up to |2^30| (pipeline.md 3a):
    bias = B - offset / (W - 1) (lsq), 2^31 - offset (endpoint), mod 2^32."""
    from civic.pipeline import data_collection
    from civic.pipeline import slope as model_slope
    from civic.pipeline.classification import slope_key as model_key

    m32, bias = 0xFFFFFFFF, 0x80000000
    r = window if lsq else window - 1
    b = s0_bias(window) if lsq else bias
    step = window - 1 if lsq else 1             # lsq offsets are multiples of W - 1
    top = (1 << 30) // step * step
    offsets = (0, step, -step, 1520 * step, -1520 * step, top, -top)
    # the set_offset(bias) a TNA control plane writes for an offset; the default is b (offset 0)
    biases = {off: (b - off // step) & m32 if lsq else (bias - off) & m32 for off in offsets}
    assert biases[0] == b
    ring = data_collection.RingState(1, r)
    ring_t, ptr, s0, s1 = [0] * 128, 0, 0, 0
    rng = __import__("random").Random(window)
    for _ in range(3 * window + 5):
        x = rng.choice((0, 65535, rng.randrange(65536)))
        old_model = ring.push(0, x)
        p, ptr = ptr, 0 if ptr == r - 1 else ptr + 1          # ptr_advance
        old, ring_t[p] = ring_t[p], x                          # ring_swap
        assert old == old_model
        d = (x - old) & m32                                    # diff
        acc = const_mul_steps(old, *csd(r))                    # R * old
        s0_old, s0 = s0, (s0 + d) & m32                        # s0_add
        t = (s0_old - acc) & m32                               # s1_inc
        s1 = (s1 + t) & m32                                    # s1_add
        assert (s0, s1) == (int(ring.s0[0]), int(ring.s1[0]))
        if lsq:
            want = int(model_slope.lsq(ring.s0[0], ring.s1[0], window))
        else:
            want = int(model_slope.endpoint(x, old_model))
        for off, bias_off in biases.items():
            if lsq:
                e = (d + bias_off) & m32                       # diff_b
                s0n = (s0_old + e) & m32                       # s0_new_b
                prod = const_mul_steps(s0n, *csd(window - 1))  # (W - 1) * s0n
                key = (prod - ((s1 << 1) & m32)) & m32         # s1_twice, key_lsq_b
            else:
                key = (d + bias_off) & m32                     # key_endpoint
            assert key == ((want - off) & m32) ^ bias, off     # resid XOR 2^31
            assert key == int(model_key(want - off)), off


@needs_bf_p4c
def test_verdict_change_digest_and_counters(build):
    """pipeline.md section 7 on TNA: the ingress deparser's Digest, per-slot counters in egress."""
    bfrt = json.loads((build / "bfrt.json").read_text())
    learn = {f["name"]: [d["name"] for d in f["fields"]] for f in bfrt.get("learn_filters", [])}
    assert learn["pipe.CivicIngressDeparser.verdict_change"] == [
        "plant", "seq", "chg0", "chg1", "cls0", "cls1", "key0", "aux0", "level0", "key1", "aux1", "level1"]
    tables = bfrt_tables(build)
    for k in range(TNA_MONITORS):
        counter = tables[f"pipe.CivicEgress.notify.verdicts{k}"]
        assert counter["table_type"] == "Counter" and counter["size"] == 256 * 4


# ---------------------------------------------------------------- the balance profile
BALANCE_MONITORS = (2, 3)       # balance_t3, balance_t1: monitor indices (verdict bits 5..4, 7..6)


@needs_bf_p4c
def test_balance_binary_and_stages(build_balance):
    """civic_balance.p4 compiles in 12 stages or fewer, SALUs at most 4 per stage: last_seq,
    last_p1, last_v1, last_v2, and per slot ring, ptr, run, s0, slope, acc, accb, ringb, hold,
    last_class."""
    assert (build_balance / "pipe/tofino.bin").stat().st_size > 0
    summary = (build_balance / "pipe/logs/table_summary.log").read_text()
    ingress = [int(n) for n in re.findall(r"Number of stages for ingress table allocation: (\d+)", summary)]
    assert ingress and ingress[-1] <= MAX_STAGES, ingress
    rows = resource_rows(build_balance)
    used = [int(r["Stage Number"]) for r in rows if int(r["Logical TableID"]) > 0]
    assert used and max(used) < MAX_STAGES, used
    salus = [int(r["Meter ALU"]) for r in rows]
    assert max(salus) <= 4 and sum(salus) == 4 + 10 * len(BALANCE_MONITORS), salus


@needs_bf_p4c
def test_balance_control_plane_objects(build_balance):
    tables = bfrt_tables(build_balance)
    want = {"pipe.CivicIngress.forward": ["ingress_port"],
            "pipe.CivicIngress.monitored_port": ["dst_port"],
            "pipe.CivicIngress.plant_prefix": ["src_addr"]}
    for k in BALANCE_MONITORS:
        m = f"pipe.CivicIngress.mon{k}"
        want[f"{m}.config"] = []
        want[f"{m}.precondition"] = ["l1", "l2", "l3", "l4", "$MATCH_PRIORITY"]
        # the command steps join the commands: six 16-bit range keys, bf-p4c's most per table
        want[f"{m}.precondition_cmd"] = ["p1", "v1", "v2", "dp1", "dv1", "dv2", "$MATCH_PRIORITY"]
        want[f"{m}.flow0"] = ["head", "cmd", "$MATCH_PRIORITY"]
        want[f"{m}.flow1"] = ["head", "cmd", "$MATCH_PRIORITY"]
        want[f"{m}.classify"] = ["slope_key_hi", "slope_key_lo", "level", "$MATCH_PRIORITY"]
    for name, keys in want.items():
        assert name in tables, name
        assert [k["name"] for k in tables[name]["key"]] == keys, name
    match_tables = {n for n, t in tables.items() if t["table_type"] == "MatchAction_Direct"}
    assert match_tables == set(want), "no @hidden step table, and no compensate (a balance monitor has none)"
    for k in BALANCE_MONITORS:
        m = f"pipe.CivicIngress.mon{k}"

        def actions(t):
            return {a["name"]: [d["name"] for d in a.get("data", [])] for a in tables[f"{m}.{t}"]["action_specs"]}
        # v1model's set_config parameters (TNA uses `enabled` only)
        assert actions("config") == {f"CivicIngress.mon{k}.set_config": [
            "enabled", "signal", "window", "ring_len", "estimator", "balance", "hold_min", "aux_plus",
            "aux_minus", "f0_plus", "f0_minus", "f0_cmd", "f1_plus", "f1_minus", "f1_cmd"]}
        for t in ("flow0", "flow1"):
            assert actions(t) == {f"CivicIngress.mon{k}.set_{t}": ["flow", "band"]}
            assert {key["match_type"] for key in tables[f"{m}.{t}"]["key"][:-1]} == {"Range"}
    # the flow terms' sizes (include/config.p4): pipe23, V2 for balance_t3; P1, V1 for balance_t1
    c = config_defines()
    sizes = {"mon2.flow0": "TNA_FLOW_PIPE23_SIZE", "mon2.flow1": "TNA_FLOW_V2_SIZE",
             "mon3.flow0": "TNA_FLOW_P1_SIZE", "mon3.flow1": "TNA_FLOW_V1_SIZE"}
    for t, name in sizes.items():
        assert tables[f"pipe.CivicIngress.{t}"]["size"] == c[name][0], t
        # one action per class, each running its class's hold RegisterAction; set_class on a miss
        assert actions("classify") == {f"CivicIngress.mon{k}.set_none": [], f"CivicIngress.mon{k}.set_normal": [],
                                       f"CivicIngress.mon{k}.set_warning": [], f"CivicIngress.mon{k}.set_error": [],
                                       f"CivicIngress.mon{k}.set_class": ["cls"]}


@needs_bf_p4c
def test_balance_registers(build_balance):
    tables = bfrt_tables(build_balance)
    want = {"pipe.CivicIngress.last_seq": (256, [32]), "pipe.CivicIngress.last_p1": (256, [16]),
            "pipe.CivicIngress.last_v1": (256, [16]), "pipe.CivicIngress.last_v2": (256, [16])}
    for k in BALANCE_MONITORS:
        m = f"pipe.CivicIngress.mon{k}"
        want.update({f"{m}.ring": (32768, [32]), f"{m}.ptr": (256, [8]), f"{m}.run": (256, [8]),
                     f"{m}.s0": (256, [32]), f"{m}.slope": (256, [32]), f"{m}.acc": (256, [32]),
                     f"{m}.accb": (256, [32]), f"{m}.ringb": (32768, [32]),
                     f"{m}.hold": (256, [16, 16]), f"{m}.last_class": (256, [8])})
    registers = {n: t for n, t in tables.items() if t["table_type"] == "Register"}
    assert set(registers) == set(want)
    for name, (size, widths) in want.items():
        t = registers[name]
        assert t["size"] == size, name
        assert [d["singleton"]["type"]["width"] for d in t["data"]] == widths, name


@needs_bf_p4c
def test_balance_stage_plan(build_balance):
    """The chain of control/balance.p4: the flow term on message fields, then the one on a head
    difference, acc, z, ring, the slope steps, the slope register, classify with the hold in
    one stage, last_class, and the digest in the last stage."""
    stages = ingress_stages(build_balance)
    for k, early, late in ((2, "flow1", "flow0"), (3, "flow0", "flow1")):
        m = f"CivicIngress.mon{k}"
        chain = [stages[f"{m}.{t}"] for t in (early, late, "acc", "push_z", "ring", "diff", "s0", "add_s0",
                                               "slope", "classify", "last_class")]
        assert chain == sorted(set(chain)), (k, chain)       # strictly increasing stages
        # (W - 1) * (z + old) beside it: ring -> times_a -> times_b -> add_s0
        side = [stages[f"{m}.{t}"] for t in ("ring", "times_a", "times_b", "add_s0")]
        assert side == sorted(set(side)), (k, side)
        assert stages[f"{m}.{early}"] == 0 and stages[f"{m}.hold"] == stages[f"{m}.classify"], k
        assert stages[f"{m}.run"] < stages[f"{m}.classify"], k
        # band_w: the bands accumulated, the ring of accb, (accb - oldb) >> 7 before classify
        band = [stages[f"{m}.{t}"] for t in (late, "accb", "ringb", "band_sum", "band_scale", "classify")]
        assert band == sorted(set(band)), (k, band)
        assert stages[f"{m}.precondition_cmd"] < stages[f"{m}.run"], k
    assert max(stages.values()) == MAX_STAGES - 1


@needs_bf_p4c
def test_balance_stateful_alu_programs(build_balance):
    """The RegisterActions as compiled: the ring stores z and returns old + z; s0 adds z - old and
    returns s0 - old; the slope register subtracts ndelta and returns the new value; hold
    compares cand with the class, saturates hold, and writes the class only with hold >= H - 1
    (H - 1 from the PHV: set_config's hold_min)."""
    text = bfa(build_balance)

    def program(reg: str, action: str) -> list[str]:
        m = re.search(rf"{action}:\n((?:\s+- .*\n)+)", text[text.index(f"p4: {{ name: {reg},"):])
        assert m, (reg, action)
        return [ln.strip()[2:] for ln in m.group(1).splitlines()]
    for k in BALANCE_MONITORS:
        m = f"CivicIngress.mon{k}"
        assert program(f"{m}.ring", f"mon{k}_ring_swap") == ["add hi, lo, phv_lo", "alu_a lo, phv_lo", "output alu_hi"]
        assert program(f"{m}.s0", f"mon{k}_s0_add") == ["sub hi, lo, phv_lo", "add lo, lo, phv_hi", "output alu_hi"]
        assert program(f"{m}.slope", f"mon{k}_slope_add") == ["sub lo, lo, phv_lo", "output alu_lo"]
        for cls, name in ((1, "normal"), (2, "warning"), (3, "error")):
            prog = program(f"{m}.hold", f"mon{k}_hold_{name}")
            assert f"equ lo, hi, -{cls}" in prog and "saddu cmplo, lo, lo, 1" in prog, prog
            assert "geq.u hi, lo, -phv_lo" in prog and "output (cmplo & cmphi), mem_hi(0..7)" in prog, prog
        assert re.search(rf"stateful \S+{m}\.hold:\n(?:\s+.*\n)*?\s+exact group \d+: {{ \d+: meta\.mon{k}\.hold_m1 }}",
                         text), f"{m}.hold does not read hold_m1"


@needs_bf_p4c
def test_balance_digest_and_counters(build_balance):
    bfrt = json.loads((build_balance / "bfrt.json").read_text())
    learn = {f["name"]: [d["name"] for d in f["fields"]] for f in bfrt.get("learn_filters", [])}
    assert learn["pipe.CivicIngressDeparser.verdict_change"] == [
        "plant", "seq", "chg2", "chg3", "cls2", "cls3", "key2", "band2", "level2", "key3", "band3", "level3"]
    tables = bfrt_tables(build_balance)
    for k in BALANCE_MONITORS:
        counter = tables[f"pipe.CivicEgress.notify.verdicts{k}"]
        assert counter["table_type"] == "Counter" and counter["size"] == 256 * 4


def w1_steps(v: int, c: dict) -> tuple[int, int]:
    """(W - 1) * v as balance.p4's two steps (config.p4 BAL_W1_*), bit<32>: (t1, t2)."""
    m32 = 0xFFFFFFFF
    t1 = ((v << c["BAL_W1_A"][0]) + c["BAL_W1_S1"][0] * v) & m32
    x, y = {0: (t1, t1), 1: (t1, v), 2: (v, t1)}[c["BAL_W1_FORM"][0]]
    return t1, ((x << c["BAL_W1_B"][0]) + c["BAL_W1_S2"][0] * y) & m32


def test_balance_constants():
    """The two steps give (W - 1) * v, R = W (lsq), and W is the balance monitors' window of
    configs/monitors.toml (an entries file with another window needs a recompile)."""
    import tomllib
    c = config_defines()
    w = c["BAL_WINDOW"][0]
    assert c["BAL_RING_LEN"][0] == w and 2 <= w <= 128
    assert abs(c["BAL_W1_S1"][0]) == 1 and abs(c["BAL_W1_S2"][0]) == 1 and c["BAL_W1_FORM"][0] in (0, 1, 2)
    for v in (1, 2, 0xFFFF, 0x7FFFFFFF, 0xFFFFFFFF):
        assert w1_steps(v, c)[1] == (v * (w - 1)) & 0xFFFFFFFF, v
    monitors = tomllib.loads((ROOT / "configs/monitors.toml").read_text())["monitor"]
    windows = {m["name"]: m["window"] for m in monitors if m.get("kind") == "balance"}
    assert windows == {"balance_t3": w, "balance_t1": w}


@pytest.mark.parametrize("hold", [2, 20, 255])
def test_balance_steps_match_the_model(hold):
    """control/balance.p4's steps, transcribed (bit<32> modular), against the software model
    (civic.pipeline: accumulator, ring, lsq over z, hold) on a random stream with wrapping
    accumulators and every hold / class pattern."""
    from civic.pipeline import balance, classification, data_collection
    from civic.pipeline import slope as model_slope
    from civic.pipeline.classification import slope_key as model_key

    from civic.entries import BALANCE_SHIFT
    m32 = 0xFFFFFFFF
    c = config_defines()
    w = c["BAL_WINDOW"][0]
    rng = __import__("random").Random(hold)
    ring = data_collection.RingState(1, w)
    acc_model = 0
    cand_m, hold_m = 0, 0
    # TNA registers
    ring_t, ptr, acc, s0, slope_reg = [0] * 128, 0, 0, 0, 0x80000000
    ringb_t, accb = [0] * 128, 0
    bands = []
    cand, hold_t = 0, 0
    for n in range(5 * w + 7):
        x = rng.choice((0, 65535, rng.randrange(65536)))
        e = rng.choice((0, rng.randrange(-2**24, 2**24), 2**24, -2**24)) & m32
        band = rng.choice((0, 65535, rng.randrange(65536)))
        # pipeline.md 3b: band_w = the last R bands summed (the ring starts empty: zeros), >> 7, 16 bit
        bands.append(band)
        want_band_w = (sum(bands[-w:]) >> 7) & 0xFFFF
        # model
        acc_model = (acc_model + e) & m32
        z_model = int(balance.pushed(x, acc_model))
        ring.push(0, z_model)
        want = int(model_slope.lsq(ring.s0[0], ring.s1[0], w))
        # TNA (balance.p4)
        acc = (acc + e) & m32                                   # acc_add
        x16 = x << BALANCE_SHIFT                                # widen_x
        z = (x16 - acc) & m32                                   # push_z
        z2 = (z << 1) & m32                                     # twice_z
        p, ptr = ptr, 0 if ptr == w - 1 else ptr + 1            # ptr_advance
        accb = (accb + band) & m32                              # widen_band, accb_add
        oldb, ringb_t[p] = ringb_t[p], accb                     # ringb_swap
        band_w = (((accb - oldb) & m32) >> 7) & 0xFFFF          # band_sum, band_scale (bits 22..7)
        assert band_w == want_band_w, n
        a1, ring_t[p] = (ring_t[p] + z) & m32, z                # ring_swap: old + z
        old = (a1 - z) & m32                                    # get_old
        d = (z2 - a1) & m32                                     # diff
        ns0, s0 = (s0 - old) & m32, (s0 + d) & m32              # s0_add
        _, w1a = w1_steps(a1, c)                                # times_a, times_b
        ndelta = (((ns0 << 1) & m32) - w1a) & m32               # add_s0
        slope_reg = (slope_reg - ndelta) & m32                  # slope_add
        assert slope_reg == int(model_key(want)), n
        # hold: the class from the table (0..3), as classify's actions give it
        c_raw = rng.choice((0, 1, 1, 1, 2, 3)) if rng.random() < 0.2 else cand_m
        cand_m, hold_m = classification.next_hold(cand_m, hold_m, c_raw)
        written = int(classification.held(c_raw, hold_m, hold))
        out = c_raw if (cand == c_raw and hold_t >= hold - 1 and c_raw != 0) else 0
        hold_t = min(hold_t + 1, 0xFFFF) if cand == c_raw else 1
        cand = c_raw
        assert out == written, n


@needs_bf_p4c
def test_balance_verdict_word_bits(build_balance):
    """Egress writes the verdict word {cls1, cls0, 4 zero bits}: balance_t3 (bridged cls0) in bits
    5..4, balance_t1 (cls1) in bits 7..6, monitors 0 and 1 (bits 3..0) not evaluated."""
    text = bfa(build_balance)
    block = text[text.index("p4: { name: CivicEgress.verdict.write_verdict"):]
    m = re.search(r"(\d+)\.\.(\d+): 0\s*\n\s*(\d+)\.\.(\d+): meta\.bridge\.cls0\s*\n\s*(\d+)\.\.(\d+): meta\.bridge\.cls1",
                  block[:3000])
    assert m, "verdict word hash layout not found"
    z_lo, z_hi, c0_lo, c0_hi, c1_lo, c1_hi = (int(v) - int(m.group(1)) for v in m.groups())
    assert (z_lo, z_hi, c0_lo, c0_hi, c1_lo, c1_hi) == (0, 3, 4, 5, 6, 7)


@needs_bf_p4c
def test_balance_ring_indices_put_the_slot_in_the_high_bits(build_balance):
    """ring and ringb share the cell slot * 128 + ptr (pipeline.md 3b: same cell and pointer)."""
    text = bfa(build_balance)
    for k in BALANCE_MONITORS:
        found = re.findall(rf"hash \d+:\s*\n\s*(\d+)\.\.(\d+): meta\.mon{k}\.ptr\(0\.\.6\)\s*\n"
                           rf"\s*(\d+)\.\.(\d+): meta\.slot", text)
        assert len(found) >= 2, f"mon{k}: ring / ringb index hash layouts not found"
        for p_lo, p_hi, s_lo, s_hi in (map(int, f) for f in found):
            assert (p_hi - p_lo, s_lo - p_lo, s_hi - s_lo) == (6, 7, 7)
