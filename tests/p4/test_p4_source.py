"""Static checks of the P4 sources that can run without p4c.

They do not compile anything. They check that the files hang together
(every control file is included), that the control-plane names civic
configure relies on are spelled in the source, and that the constants in
p4src/shared/define.p4 agree with the Python side and docs/pipeline.md.
"""
from __future__ import annotations

import random
import re
from pathlib import Path

import pytest

from civic import wire
from civic.config import PRECONDITION_FIELDS
from civic.pipeline import data_collection
from civic.switch.desired import DISABLED, SIGNAL_CODES
from civic.switch.schema import (ACTION_SET_EGRESS, ACTION_SET_MONITORED, ACTION_SET_PLANT, FLOW_TABLES, MAX_PLANTS,
                                 MONITOR_REGISTERS, REGISTER_LAST_SEQ, SLOPE_BIAS, TABLE_FORWARD, TABLE_MONITORED_PORT,
                                 TABLE_PLANT_PREFIX, SwitchSchema, decode_value, mon)

ROOT = Path(__file__).resolve().parents[2]
P4SRC = ROOT / "p4src"
V1 = P4SRC / "v1model"
TNA = P4SRC / "tna"
MONITOR_SLOTS_V1 = 4


def strip_comments(text: str) -> str:
    text = re.sub(r"/\*.*?\*/", " ", text, flags=re.S)
    return re.sub(r"//[^\n]*", " ", text)


def defines() -> dict[str, int]:
    """Numeric #defines of define.p4 (a define naming an earlier one takes its value)."""
    out = {}
    for m in re.finditer(r"^#define\s+(\w+)\s+(0x[0-9A-Fa-f]+|\d+|[A-Z_]\w*)\s*(?://.*)?$",
                         (P4SRC / "shared/define.p4").read_text(), re.M):
        value = m.group(2)
        out[m.group(1)] = out[value] if value in out else int(value, 0)
    return out


def included(top: Path) -> list[Path]:
    """Every file reachable through #include "..." from `top` (angle includes are system headers)."""
    seen, todo = [], [top]
    while todo:
        f = todo.pop()
        if f in seen:
            continue
        assert f.is_file(), f"#include of a missing file: {f}"
        seen.append(f)
        for inc in re.findall(r'^\s*#include\s+"([^"]+)"', f.read_text(), re.M):
            todo.append((f.parent / inc).resolve())
    return seen


def source(top: Path) -> str:
    return "\n".join(strip_comments(f.read_text()) for f in included(top))


@pytest.mark.parametrize("arch", [V1, TNA], ids=["v1model", "tna"])
def test_every_control_file_is_included(arch):
    files = set(included(arch / "civic.p4"))
    controls = sorted((arch / "include/control").glob("*.p4"))
    assert controls, f"no control files under {arch}/include/control"
    for f in controls + [arch / "include/parser.p4", P4SRC / "shared/define.p4", P4SRC / "shared/headers.p4"]:
        assert f.resolve() in files, f"{f.relative_to(ROOT)} is not #included by {arch.name}/civic.p4"


@pytest.mark.parametrize("arch", [V1, TNA], ids=["v1model", "tna"])
def test_braces_and_parens_balance(arch):
    for f in included(arch / "civic.p4"):
        text = strip_comments(f.read_text())
        for a, b in ("{}", "()", "[]"):
            assert text.count(a) == text.count(b), f"unbalanced {a}{b} in {f.relative_to(ROOT)}"


def control_bodies(src: str) -> dict[str, str]:
    """control name -> body text (between the braces after the parameter lists)."""
    out = {}
    for m in re.finditer(r"\bcontrol\s+(\w+)\s*\(", src):
        i = src.index("{", m.end())
        depth, j = 0, i
        while True:
            depth += {"{": 1, "}": -1}.get(src[j], 0)
            j += 1
            if depth == 0:
                break
        out[m.group(1)] = src[i + 1:j - 1]
    return out


def top_level_decls(body: str) -> str:
    """The part of a control body outside nested braces (its declarations), apply block excluded."""
    out, depth = [], 0
    for ch in body:
        if ch == "{":
            depth += 1
        if depth == 0:
            out.append(ch)
        if ch == "}":
            depth -= 1
    text = "".join(out)
    return text[:text.rindex("apply")] if "apply" in text else text


CP_OBJECT = re.compile(r"(?:@name\(\s*\"([^\"]+)\"\s*\)\s*)?"
                       r"(?:table\s+(\w+)|action\s+(\w+)\s*\(|[Rr]egister<[^;=]*?>\s*\([^;]*?\)\s*(\w+)\s*;)")
INSTANCE = re.compile(r"(?:@name\(\s*\"([^\"]+)\"\s*\)\s*)?\b([A-Z]\w*)\s*\(([^;{}]*)\)\s+(\w+)\s*;")


def derived_names(src: str, top: str = "CivicIngress") -> dict[str, str]:
    """P4Info names p4c derives for the tables, actions and registers reachable from `top`.

    The rules of p4c 1.2.x (frontends/p4/inlining.cpp ComputeNewNames, hierarchicalNames.cpp,
    IDeclaration::controlPlaneName): an object of an inlined control instance is prefixed with
    the instance's external name (its @name, else its declared name), recursively; a name
    starting with '.' is absolute and stays as it is; the top-level control's name is prefixed
    last; the P4Info drops a leading dot. Returns name -> kind ("table", "action", "register").
    """
    bodies = control_bodies(src)
    out: dict[str, str] = {}

    def walk(ctl: str, prefix: str) -> None:
        decls = top_level_decls(bodies[ctl])
        for m in CP_OBJECT.finditer(decls):
            if decls[:m.start()].rstrip().endswith("@hidden"):
                continue                  # @hidden: no control-plane name
            anno, table, action, register = m.groups()
            local = table or action or register
            kind = "table" if table else "action" if action else "register"
            name = anno or local
            full = name[1:] if name.startswith(".") else f"{prefix}.{name}"
            assert full not in out, f"two objects named {full}"
            out[full] = kind
        for m in INSTANCE.finditer(decls):
            anno, typ, _, inst = m.groups()
            if typ in bodies:
                walk(typ, f"{prefix}.{anno or inst}")

    walk(top, top)
    return out


@pytest.mark.parametrize("arch", [V1, TNA], ids=["v1model", "tna"])
def test_no_duplicate_name_annotations(arch):
    """p4c rejects two objects of one control with the same @name when it writes a P4Info
    (frontends/p4/duplicateHierarchicalNameCheck.cpp: "conflicting control plane name"), and an
    absolute @name in a control instantiated more than once names two objects the same."""
    src = source(arch / "civic.p4")
    bodies = control_bodies(src)
    uses: dict[str, int] = {}
    for body in bodies.values():
        for m in INSTANCE.finditer(top_level_decls(body)):
            uses[m.group(2)] = uses.get(m.group(2), 0) + 1
    for ctl, body in bodies.items():
        decls = top_level_decls(body)
        names = re.findall(r'@name\(\s*"([^"]+)"\s*\)\s*(?!\s*(?:bit|int)\b)', decls)
        key_names = re.findall(r':\s*\w+\s+@name\("([^"]+)"\)', decls)
        names = [n for n in names if n not in key_names]
        assert len(names) == len(set(names)), f"{ctl}: duplicate @name {sorted(names)}"
        if uses.get(ctl, 0) > 1:
            assert not any(n.startswith(".") for n in names), f"{ctl} is instantiated twice but has absolute @names"


def test_v1model_control_plane_names():
    """The names of civic/switch/schema.py, as p4c will derive them (see p4src/README.md)."""
    src = source(V1 / "civic.p4")
    assert re.search(r"control\s+CivicIngress\s*\(", src)
    # register<T>(size), read(out T, in bit<32>) is the V1MODEL_VERSION 20180101 API
    top = (V1 / "civic.p4").read_text()
    assert re.search(r"#define\s+V1MODEL_VERSION\s+20180101\s*\n#include\s+<v1model.p4>", top)
    assert re.search(r"V1Switch\s*\([^;]*CivicIngress\s*\(\)", src, re.S)
    # monitor slot k is one instance `Monitor() monK;` of CivicIngress
    for k in range(MONITOR_SLOTS_V1):
        assert re.search(rf"\bMonitor\s*\(\s*\)\s+mon{k}\s*;", src), f"mon{k}"
    names = derived_names(src)
    want = {TABLE_FORWARD: "table", TABLE_MONITORED_PORT: "table",
            TABLE_PLANT_PREFIX: "table", ACTION_SET_EGRESS: "action",
            ACTION_SET_MONITORED: "action", ACTION_SET_PLANT: "action",
            REGISTER_LAST_SEQ: "register", "CivicIngress.drop": "action",
            "CivicIngress.last_p1": "register", "CivicIngress.last_v1": "register",
            "CivicIngress.last_v2": "register"}
    for k in range(MONITOR_SLOTS_V1):
        for t in ("config", "precondition", "compensate", "classify") + FLOW_TABLES:
            want[mon(k, t)] = "table"
        for a in ("set_config", "qualify", "disqualify", "set_offset", "set_class", "set_flow0", "set_flow1"):
            want[mon(k, a)] = "action"
        for r in MONITOR_REGISTERS:
            want[mon(k, r)] = "register"
    assert names == want


def test_derived_names_match_fixture_p4info():
    """Every table, action and register of the P4Info fixture is one the program has."""
    fixture = ROOT / "tests/fixtures/civic.p4info.txtpb"
    if not fixture.exists():
        pytest.skip("no P4Info fixture")
    schema = SwitchSchema.from_text(fixture.read_text())
    names = derived_names(source(V1 / "civic.p4"))
    for kind, have in (("table", schema.tables), ("action", schema.actions), ("register", schema.registers)):
        for n in (obj.name for obj in have):
            if n != "NoAction":
                assert names.get(n) == kind, f"fixture {kind} {n} is not in the program"


def test_tna_derived_names():
    src = source(TNA / "civic.p4")
    names = derived_names(src)
    v1 = derived_names(source(V1 / "civic.p4"))
    n = tna_config()["TNA_MONITORS"]
    # bf-p4c takes at most six 16-bit range keys per table: TNA splits the precondition in two
    # (l1..l4 and p1, v1, v2; p4src/README.md), the only names TNA adds
    split = {f"CivicIngress.mon{k}.{name}": kind for k in range(n)
             for name, kind in (("precondition_cmd", "table"), ("qualify_cmd", "action"), ("disqualify_cmd", "action"),
                                # one classify action per class: each runs its own last_class RegisterAction
                                ("set_normal", "action"), ("set_warning", "action"), ("set_error", "action"))}
    # the balance monitors' objects (command steps, flow terms, accumulator, hold) are v1model's
    # alone: the TNA default profile runs the two test monitors (p4src/README.md)
    balance = re.compile(r"CivicIngress\.(last_[pv]\d|mon\d\.(flow\d|set_flow\d|acc|accb|ringb|cand|hold))$")
    assert names == {k: v for k, v in v1.items()
                     if not re.match(rf"CivicIngress\.mon([{n}-9])\.", k) and not balance.match(k)} | split


def test_v1model_key_and_parameter_names():
    src = source(V1 / "civic.p4")
    for key, kind in [("ingress_port", "exact"), ("dst_port", "exact"), ("src_addr", "lpm"),
                      ("slope_key", "range"), ("level", "range"), ("aux", "range"), ("head", "range"),
                      ("cmd", "range")] + [(s, "range") for s in PRECONDITION_FIELDS]:
        assert re.search(rf':\s*{kind}\s+@name\("{key}"\)', src), key
    params = [(int(w), n) for w, n in re.findall(r"bit<(\d+)>\s+(\w+)",
                                                 re.search(r"action\s+set_config\s*\(([^)]*)\)", src).group(1))]
    assert [n for _, n in params] == list(DISABLED)
    assert params[:9] == [(1, "enabled"), (2, "signal"), (8, "window"), (8, "ring_len"), (2, "estimator"),
                          (1, "balance"), (8, "hold_min"), (2, "aux_plus"), (2, "aux_minus")]
    assert all(w == 3 for w, _ in params[9:])            # operand codes l1..l4, p1, v1, v2, zero
    assert re.search(r"action\s+set_flow0\s*\(\s*bit<32>\s+flow\s*,\s*bit<16>\s+band\s*\)", src)
    assert re.search(r"action\s+set_offset\s*\(\s*bit<32>\s+offset\s*\)", src)
    assert re.search(r"action\s+set_class\s*\(\s*bit<2>\s+cls\s*\)", src)
    assert re.search(r"action\s+set_egress\s*\(\s*bit<9>\s+port\s*\)", src)
    assert "mark_to_drop(standard_metadata)" in src


def test_register_sizes_and_widths():
    d = defines()
    src = source(V1 / "civic.p4")
    widths = {"ring": 32, "ptr": 8, "run": 8, "s0": 32, "s1": 32, "last_seq": 32, "acc": 32, "cand": 2,
              "hold": 8, "last_p1": 16, "accb": 32, "ringb": 32}
    for reg, w in widths.items():
        m = re.search(rf"register<bit<(\d+)>>\((\w+)\)\s+{reg}\s*;", src)
        assert m, reg
        assert int(m.group(1)) == w, reg
        size = d[m.group(2)]
        assert size == (d["MAX_PLANTS"] * d["MAX_WINDOW"] if reg in ("ring", "ringb") else d["MAX_PLANTS"]), reg


def test_constants_match_python_and_docs():
    d = defines()
    assert d["ETHERTYPE_IPV4"] == 0x0800
    assert d["PLANT_PAYLOAD_LEN"] == wire.PAYLOAD_LEN
    assert d["UDP_LEN_PLANT"] == wire.UDP_LEN
    assert d["DEFAULT_UDP_PORT"] == wire.DEFAULT_UDP_PORT
    assert d["MAX_PLANTS"] == MAX_PLANTS
    assert d["SLOPE_BIAS"] == SLOPE_BIAS
    assert d["RUN_MAX"] == data_collection.RUN_MAX
    assert d["VERDICT_MONITORS"] == wire.MAX_MONITORS
    assert 2 * d["MAX_MONITORS"] <= 16 and d["MAX_MONITORS"] == MONITOR_SLOTS_V1
    assert {s: d[f"SIGNAL_{s.upper()}"] for s in SIGNAL_CODES} == SIGNAL_CODES
    assert {n: d[f"CLASS_{n.upper()}"] for n in wire.CLASS_CODES} == wire.CLASS_CODES
    assert d["CLASS_NOT_EVALUATED"] == 0 and d["CLASS_DEFAULT"] == wire.CLASS_CODES["error"]
    assert d["RING_CELLS"] == d["MAX_PLANTS"] * d["MAX_WINDOW"]
    assert d["MAX_WINDOW"] == 1 << d["MAX_WINDOW_LOG2"]
    doc = (ROOT / "docs/pipeline.md").read_text()
    w_lo, w_hi = map(int, re.search(r"`(\d+)\s*<=\s*W\s*<=\s*(\d+)`", doc).groups())
    assert d["MAX_WINDOW"] == w_hi and w_lo >= 2
    assert "0x80000000" in doc and "255" in doc


def test_table_sizes_match_fixture_p4info():
    """The P4Info fixture of tests/switch/ uses the sizes the program declares."""
    fixture = ROOT / "tests/fixtures/civic.p4info.txtpb"
    if not fixture.exists():
        pytest.skip("no P4Info fixture")
    schema = SwitchSchema.from_text(fixture.read_text())
    d = defines()
    want = {TABLE_FORWARD: d["FORWARD_TABLE_SIZE"],
            TABLE_MONITORED_PORT: d["MONITORED_PORT_TABLE_SIZE"],
            TABLE_PLANT_PREFIX: d["PLANT_PREFIX_TABLE_SIZE"]}
    for k in range(schema.monitor_slots()):
        want[mon(k, "precondition")] = d["PRECONDITION_TABLE_SIZE"]
        want[mon(k, "classify")] = d["CLASSIFY_TABLE_SIZE"]
        want[mon(k, "config")] = 1
    for name, size in want.items():
        assert schema.table(name).size == size, name
    assert schema.monitor_slots() == MONITOR_SLOTS_V1


def header_fields(name: str) -> list[tuple[str, int]]:
    text = strip_comments((P4SRC / "shared/headers.p4").read_text())
    body = re.search(rf"header\s+{name}\s*\{{(.*?)\}}", text, re.S).group(1)
    types = {"mac_addr_t": 48, "ipv4_addr_t": 32}
    out = []
    for typ, field in re.findall(r"(bit<\d+>|\w+_t)\s+(\w+)\s*;", body):
        out.append((field, int(typ[4:-1]) if typ.startswith("bit<") else types[typ]))
    return out


def test_header_layouts():
    assert sum(w for _, w in header_fields("ethernet_t")) == 8 * wire.ETH_LEN
    assert sum(w for _, w in header_fields("ipv4_t")) == 8 * wire.IPV4_LEN
    assert sum(w for _, w in header_fields("udp_t")) == 64
    plant = header_fields("plant_msg_t")
    assert sum(w for _, w in plant) == 8 * wire.PAYLOAD_LEN
    # same fields, same order, same widths as the wire format's decoded message
    wire_fields = [(n, wire.MESSAGE_DTYPE[n].itemsize * 8) for n in ("seq",) + wire.SIGNALS + ("verdict",)]
    assert plant == wire_fields
    # the verdict word sits where civic.wire patches it
    assert 8 * (wire.OFF_VERDICT - wire.OFF_PAYLOAD) == sum(w for n, w in plant[:-1])


def p4_checksum(hc: int, m_old: int, m_new: int) -> int:
    """verdict.p4's statements transcribed: bit<32> sum, two folds, complement, 0 -> 0xFFFF."""
    if hc == 0:
        return 0
    s = ((~hc) & 0xFFFF) + ((~m_old) & 0xFFFF) + m_new
    s &= 0xFFFFFFFF
    s = (s & 0xFFFF) + (s >> 16)
    s = (s & 0xFFFF) + (s >> 16)
    out = (~s) & 0xFFFF
    return 0xFFFF if out == 0 else out


def test_checksum_arithmetic_as_written_matches_the_model():
    rng = random.Random(7)
    cases = [(0, 0, 0), (0xFFFF, 0, 0), (0xFFFF, 0xFFFF, 0xFFFF), (1, 0, 0xFFFF), (0x1234, 0, 0)]
    cases += [(rng.randrange(1 << 16), rng.randrange(1 << 16), rng.randrange(1 << 8)) for _ in range(20000)]
    for hc, mo, mn in cases:
        assert p4_checksum(hc, mo, mn) == int(wire.incremental_checksum(hc, mo, mn)), (hc, mo, mn)


def tna_config() -> dict:
    """#defines of the TNA config: ints, and MONk_*_MUL as tuples (a0, a1, a2, a3, use, neg)."""
    out = {}
    text = (TNA / "include/config.p4").read_text()
    for m in re.finditer(r"^#define\s+(\w+)\s+([^/\n]+?)\s*(?://.*)?$", text, re.M):
        parts = [int(v, 0) for v in m.group(2).split(",")] if re.fullmatch(r"[\dxA-Fa-f,\s]+", m.group(2)) else None
        if parts:
            out[m.group(1)] = parts[0] if len(parts) == 1 else tuple(parts)
    return out


def const_mul(v: int, a0, a1, a2, a3, use, neg) -> int:
    """const_mul.p4 transcribed (bit<32> modular)."""
    m = 0xFFFFFFFF
    t = [(v << a) & m if use >> i & 1 else 0 for i, a in enumerate((a0, a1, a2, a3))]
    u = (t[0] - t[1]) & m if neg & 2 else (t[0] + t[1]) & m
    if neg & 12 == 0:
        return (u + t[2] + t[3]) & m
    if neg & 12 == 12:
        return (u - (t[2] + t[3])) & m
    if neg & 4:
        return (u + (t[3] - t[2])) & m
    return (u + (t[2] - t[3])) & m


def mul_constant(a0, a1, a2, a3, use, neg) -> int:
    assert not neg & 1, "term 0 must be positive"
    return sum((-1 if neg >> i & 1 else 1) << a for i, a in enumerate((a0, a1, a2, a3)) if use >> i & 1)


def test_tna_monitor_constants_are_consistent():
    """Window, ring length and estimator of each TNA monitor slot are compile-time constants."""
    c = tna_config()
    n = c["TNA_MONITORS"]
    assert 1 <= n <= 8
    for k in range(n):
        w, r, lsq = c[f"MON{k}_WINDOW"], c[f"MON{k}_RING_LEN"], c[f"MON{k}_LSQ"]
        assert 2 <= w <= defines()["MAX_WINDOW"]
        assert r == (w if lsq else w - 1), f"MON{k}_RING_LEN must be W (lsq) or W - 1 (endpoint)"
        assert mul_constant(*c[f"MON{k}_R_MUL"]) == r, f"MON{k}_R_MUL is not R"
        assert mul_constant(*c[f"MON{k}_W1_MUL"]) == w - 1, f"MON{k}_W1_MUL is not W - 1"
        for v in (0, 1, 65535, 0x7FFFFFFF, 0xFFFFFFFF, 123456789):
            assert const_mul(v, *c[f"MON{k}_R_MUL"]) == (v * r) & 0xFFFFFFFF
            assert const_mul(v, *c[f"MON{k}_W1_MUL"]) == (v * (w - 1)) & 0xFFFFFFFF


def csd_terms(c: int) -> tuple:
    """Canonical signed digit form of 1 <= c <= 128 as config.p4 MUL arguments (most significant term first)."""
    digits, i = [], 0
    while c:
        if c & 1:
            d = 2 - (c & 3)          # +1 or -1
            digits.append((i, d))
            c -= d
        c >>= 1
        i += 1
    digits.sort(reverse=True)
    assert len(digits) <= 4 and digits[0][1] == 1
    a = [sh for sh, _ in digits] + [0] * (4 - len(digits))
    neg = sum(1 << k for k, (_, d) in enumerate(digits) if d < 0)
    return (*a, (1 << len(digits)) - 1, neg)


def test_every_window_has_a_four_term_decomposition():
    for c in range(1, 129):
        assert mul_constant(*csd_terms(c)) == c
        assert all(const_mul(v, *csd_terms(c)) == (v * c) & 0xFFFFFFFF for v in (1, 0xFFFF, 0xFFFFFFFF))


def p4_checksum_tna(hc: int, m_old: int, m_new: int) -> int:
    """tna verdict.p4 transcribed: 16-bit ones' complement additions with end-around carry."""
    if hc == 0:
        return 0
    n_hc, n_m = ~hc & 0xFFFF, ~m_old & 0xFFFF
    u = (n_hc + n_m) & 0xFFFF
    if u < n_hc:
        u = (u + 1) & 0xFFFF
    v = (u + m_new) & 0xFFFF
    if v < u:
        v = (v + 1) & 0xFFFF
    return 0xFFFF if v == 0xFFFF else ~v & 0xFFFF


def test_tna_checksum_arithmetic_matches_the_model():
    rng = random.Random(11)
    cases = [(0xFFFF, 0xFFFF, 0), (0xFFFF, 0xFFFF, 0xFFFF), (1, 1, 0), (0x8000, 0x8000, 0x8000)]
    cases += [(a, b, c) for a in (1, 0xFFFE, 0xFFFF) for b in (0, 1, 0xFFFF) for c in (0, 1, 0xFF, 0xFFFF)]
    cases += [(rng.randrange(1 << 16), rng.randrange(1 << 16), rng.randrange(1 << 16)) for _ in range(20000)]
    for hc, mo, mn in cases:
        assert p4_checksum_tna(hc, mo, mn) == int(wire.incremental_checksum(hc, mo, mn)), (hc, mo, mn)


@pytest.mark.parametrize("window,lsq", [(20, True), (90, True), (21, True), (2, True), (128, True),
                                        (20, False), (2, False), (127, False)])
@pytest.mark.parametrize("offset_steps", [0, 1234, -77])
def test_tna_slope_key_arithmetic_matches_the_model(window, lsq, offset_steps):
    """monitor.p4 + slope.p4 (TNA) transcribed, against the software model's registers and slope;
    the compensation's offset carried in the bias set_offset(bias) gives (pipeline.md 3a)."""
    from civic.pipeline import slope as model_slope

    m32, bias = 0xFFFFFFFF, 0x80000000
    r = window if lsq else window - 1
    r_mul, w1_mul = csd_terms(r), csd_terms(window - 1)
    assert mul_constant(*r_mul) == r and mul_constant(*w1_mul) == window - 1
    # config.p4: B = 2^(31 - k), 2^k the largest power of two dividing W - 1, so (W - 1) * B = 2^31
    w1 = window - 1
    big_b = 1 << (31 - ((w1 & -w1).bit_length() - 1)) if lsq else bias
    offset = offset_steps * w1 if lsq else offset_steps          # lsq offsets are multiples of W - 1
    bias_param = (big_b - offset_steps) & m32 if lsq else (bias - offset) & m32   # set_offset(bias)

    rng = random.Random(window)
    ring = data_collection.RingState(1, r)
    ring_t, ptr, s0, s1 = [0] * 128, 0, 0, 0
    for _ in range(3 * window + 5):
        x = rng.choice((0, 65535, rng.randrange(65536)))
        old_model = ring.push(0, x)
        # TNA registers and PHV arithmetic
        p = ptr
        ptr = 0 if p == r - 1 else p + 1
        old = ring_t[p]
        ring_t[p] = x
        assert old == old_model
        d = (x - old) & m32
        t = (s0 - const_mul(old, *r_mul)) & m32
        s0_before, s0 = s0, (s0 + d) & m32
        s1 = (s1 + t) & m32
        assert (s0, s1) == (int(ring.s0[0]), int(ring.s1[0]))
        if lsq:
            e = (d + bias_param) & m32                               # diff_b
            s0n = (s0_before + e) & m32                              # s0_new_b
            prod = const_mul(s0n, *w1_mul)
            key = (prod - (s1 << 1)) & m32                           # s1_twice, key_lsq_b
            want = int(model_slope.lsq(ring.s0[0], ring.s1[0], window))
        else:
            key = (d + bias_param) & m32                             # key_endpoint
            want = int(model_slope.endpoint(x, old_model))
        assert key == ((want - offset) & m32) ^ bias


def test_tna_names():
    src = source(TNA / "civic.p4")
    for full in (TABLE_FORWARD, TABLE_MONITORED_PORT, TABLE_PLANT_PREFIX,
                 ACTION_SET_EGRESS, ACTION_SET_MONITORED, ACTION_SET_PLANT,
                 REGISTER_LAST_SEQ, "CivicIngress.drop"):
        assert f'@name(".{full}")' in src, full
    for k in range(tna_config()["TNA_MONITORS"]):
        assert re.search(rf"\bMonitor\s*\([^;]*\)\s+mon{k}\s*;", src), k
    for reg in ("ring", "ptr", "run", "s0", "s1", "last_class"):       # no balance monitors on TNA's default
        assert re.search(rf"Register<bit<\d+>,\s*bit<\d+>>\([A-Z_]+(,\s*0)?\)\s+{reg}\s*;", src), reg
    for obj in ("table config", "action set_config", "table precondition", "action qualify",
                "table classify", "action set_class"):
        assert re.search(rf"\b{obj}\b", src), obj


# ---------------------------------------------------------------- the P4Info fixture, table by table
V1_FIELD_ROOTS = {"hdr": "headers_t", "msg": "plant_msg_t", "m": "monitor_md_t", "meta": "local_metadata_t"}
V1MODEL_STANDARD_METADATA = {"ingress_port": 9, "egress_spec": 9, "egress_port": 9}   # p4include/v1model.p4
TYPEDEF_WIDTHS = {"mac_addr_t": 48, "ipv4_addr_t": 32}


def p4_types(src: str) -> dict[str, dict[str, str]]:
    """struct / header name -> {field: type} of the program."""
    out = {}
    for m in re.finditer(r"\b(?:struct|header)\s+(\w+)\s*\{([^}]*)\}", src):
        out[m.group(1)] = dict((f, t) for t, f in re.findall(r"(bit<\d+>|\w+)\s+(\w+)\s*;", m.group(2)))
    out["__params__"] = {f: t for sig in re.findall(r"\bcontrol\s+\w+\s*\(([^)]*)\)", src)
                         for t, f in re.findall(r"\bin\s+(bit<\d+>)\s+(\w+)", sig)}
    return out


def key_width(expr: str, types: dict) -> int:
    parts = expr.split(".")
    if len(parts) == 1:                        # a control's parameter, e.g. Monitor's `in bit<16> dp1`
        return int(types["__params__"][expr][4:-1])
    if parts[0] == "standard_metadata":
        return V1MODEL_STANDARD_METADATA[parts[1]]
    typ = V1_FIELD_ROOTS[parts[0]]
    for p in parts[1:]:
        typ = types[typ][p]
    return int(typ[4:-1]) if typ.startswith("bit<") else TYPEDEF_WIDTHS[typ]


def derived_tables(src: str, top: str = "CivicIngress") -> dict[str, dict]:
    """P4Info name -> {keys: [(name, kind, width)], actions: [(P4Info name, defaultonly)], default, args}
    of every table reachable from `top`, with action names resolved as derived_names does."""
    bodies = control_bodies(src)
    types = p4_types(src)
    out: dict[str, dict] = {}

    def full(anno, local, prefix):
        name = anno or local
        return name[1:] if name.startswith(".") else f"{prefix}.{name}"

    def walk(ctl: str, prefix: str) -> None:
        body = bodies[ctl]
        actions = {m.group(2): full(m.group(1), m.group(2), prefix)
                   for m in re.finditer(r'(?:@name\(\s*"([^"]+)"\s*\)\s*)?action\s+(\w+)\s*\(', body)}
        actions["NoAction"] = "NoAction"
        for m in re.finditer(r'(?:@name\(\s*"([^"]+)"\s*\)\s*)?table\s+(\w+)\s*\{', body):
            i, depth = m.end(), 1
            while depth:
                depth += {"{": 1, "}": -1}.get(body[i], 0)
                i += 1
            tbody = body[m.end():i - 1]
            key = re.search(r"\bkey\s*=\s*\{([^}]*)\}", tbody)
            keys = [(n, kind.upper(), key_width(e, types)) for e, kind, n in
                    re.findall(r'([\w.]+)\s*:\s*(\w+)\s+@name\("([^"]+)"\)', key.group(1) if key else "")]
            acts = re.search(r"\bactions\s*=\s*\{([^}]*)\}", tbody).group(1)
            refs = [(actions[a], bool(d)) for d, a in re.findall(r"(@defaultonly\s+)?(\w+)\s*(?:\(\s*\))?\s*;", acts)]
            dflt = re.search(r"\bdefault_action\s*=\s*(\w+)\s*\(([^)]*)\)", tbody)
            assert not re.search(r"\bconst\s+default_action", tbody), "const default actions: see the fixture"
            args = [int(a, 0) if re.fullmatch(r"\d+|0x[0-9a-fA-F]+", a.strip()) else defines()[a.strip()]
                    for a in dflt.group(2).split(",") if a.strip()]
            out[full(m.group(1), m.group(2), prefix)] = {"keys": keys, "actions": refs,
                                                         "default": actions[dflt.group(1)], "args": args}
        for m in INSTANCE.finditer(top_level_decls(body)):
            anno, typ, _, inst = m.groups()
            if typ in bodies:
                walk(typ, f"{prefix}.{anno or inst}")

    walk(top, top)
    return out


def test_fixture_p4info_tables_match_the_program():
    """Keys (name, match kind, width), action refs and their @defaultonly scope, and initial default
    actions of the fixture are what p4c derives from the v1model program; aliases are unique and
    ids carry the P4Runtime type prefix (p4info/p4ids.h: action 0x01, table 0x02, register 0x16)."""
    from finsy.proto import p4i as p4info_pb2

    schema = SwitchSchema.from_text((ROOT / "tests/fixtures/civic.p4info.txtpb").read_text())
    info = schema.p4info
    tables = derived_tables(source(V1 / "civic.p4"))
    assert set(tables) == {t.name for t in schema.tables}
    for t in info.tables:
        want = tables[t.preamble.name]
        assert [(f.name, p4info_pb2.MatchField.MatchType.Name(f.match_type), f.bitwidth)
                for f in t.match_fields] == want["keys"], t.preamble.name
        assert [f.id for f in t.match_fields] == list(range(1, len(t.match_fields) + 1))
        refs = [(schema.actions[r.id].name, r.scope == p4info_pb2.ActionRef.DEFAULT_ONLY) for r in t.action_refs]
        assert refs == want["actions"], t.preamble.name
        for r in t.action_refs:
            assert (r.scope == p4info_pb2.ActionRef.DEFAULT_ONLY) == ("@defaultonly" in r.annotations)
        assert not t.const_default_action_id, t.preamble.name
        init = t.initial_default_action
        assert schema.actions[init.action_id].name == want["default"], t.preamble.name
        assert [decode_value(a.value) for a in init.arguments] == want["args"], t.preamble.name
    used = {a for t in tables.values() for a, _ in t["actions"]}
    assert {a.name for a in schema.actions} == used, "P4Info lists exactly the actions some table references"
    objs = [(0x02, t.preamble) for t in info.tables] + [(0x01, a.preamble) for a in info.actions] + \
        [(0x16, r.preamble) for r in info.registers]
    for prefix, pre in objs:
        assert pre.id >> 24 == prefix, pre.name
        assert pre.name == pre.alias or pre.name.endswith("." + pre.alias), pre.name
    aliases = [pre.alias for _, pre in objs]
    assert len(aliases) == len(set(aliases)), "p4c gives every object a unique alias"
    assert len({pre.id for _, pre in objs}) == len(objs)


def p4info_summary(schema: SwitchSchema) -> dict:
    """Everything of a P4Info that civic configure and the fixture depend on, ids left out."""
    from finsy.proto import p4i as p4info_pb2

    aname = {a.id: a.name for a in schema.actions}
    out = {}
    for t in schema.p4info.tables:
        out[("table", t.preamble.name)] = (
            [(f.name, p4info_pb2.MatchField.MatchType.Name(f.match_type), f.bitwidth) for f in t.match_fields],
            sorted((aname[r.id], p4info_pb2.ActionRef.Scope.Name(r.scope)) for r in t.action_refs),
            int(t.size), aname.get(t.const_default_action_id),
            aname.get(t.initial_default_action.action_id) if t.HasField("initial_default_action") else None)
    for a in schema.p4info.actions:
        out[("action", a.preamble.name)] = [(p.name, p.bitwidth) for p in a.params]
    for r in schema.p4info.registers:
        out[("register", r.preamble.name)] = (r.type_spec.bitstring.bit.bitwidth, int(r.size))
    return out


@pytest.mark.bmv2
def test_built_p4info_matches_fixture(request):
    """The P4Info p4c-bm2-ss writes must say what the fixture says (ids aside).
    CIVIC_P4INFO=path checks another build instead of compiling."""
    import os

    if os.environ.get("CIVIC_P4INFO"):
        built = Path(os.environ["CIVIC_P4INFO"])
    else:
        built = request.getfixturevalue("v1model_build") / "civic.p4info.txtpb"
    have = p4info_summary(SwitchSchema.from_text(built.read_text(), str(built)))
    want = p4info_summary(SwitchSchema.from_text((ROOT / "tests/fixtures/civic.p4info.txtpb").read_text()))
    assert sorted(have) == sorted(want)
    for k in want:
        assert have[k] == want[k], k
