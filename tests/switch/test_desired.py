"""The table entries an entries file asks for: encoding (finsy) and validation before any write."""
from __future__ import annotations

import copy

import pytest

from civic.config import PRECONDITION_FIELDS
from civic.entries import parse_entries
from civic.errors import CivicError
from civic.switch.converge import configure
from civic.switch.desired import PRIORITY_BASE, desired_state
from civic.switch.schema import mon

from switch.p4rt_servicer import ENTRIES, entries_file, field, load_info, params, schema


def test_entries_to_protos_encoding():
    sch = schema()
    want = desired_state(parse_entries(copy.deepcopy(ENTRIES), "t"), sch)
    by_table: dict = {}
    for te in want.entries:
        by_table.setdefault(sch.tables[te.table_id].name, []).append(te)

    fwd = by_table["CivicIngress.forward"]
    assert [(field(te, sch, "ingress_port").exact.value, params(te)) for te in fwd] == \
        [(b"\x01", [(1, b"\x02")]), (b"\x02", [(1, b"\x01")])]        # default 1<->2, canonical bytes
    assert all(te.priority == 0 for te in fwd)
    (mp,) = by_table["CivicIngress.monitored_port"]
    assert field(mp, sch, "dst_port").exact.value == b"\xc3\x50"        # 50000
    (pp,) = by_table["CivicIngress.plant_prefix"]
    lpm = field(pp, sch, "src_addr").lpm
    assert (lpm.value, lpm.prefix_len, pp.priority) == (b"\x0a\x00\x00\x00", 24, 0)

    (pre,) = by_table["CivicIngress.mon0.precondition"]
    assert pre.priority == PRIORITY_BASE
    assert len(pre.match) == 2                                  # l3 and v2; l1, l2, l4, p1, v1 don't-care
    l3, v2 = field(pre, sch, "l3").range, field(pre, sch, "v2").range
    assert (l3.low, l3.high, v2.low, v2.high) == (b"\x0b\xb9", b"\xff\xff", b"\x03\x20", b"\xff\xff")
    cls = by_table["CivicIngress.mon0.classify"]
    assert [te.priority for te in cls] == [PRIORITY_BASE, PRIORITY_BASE - 1, PRIORITY_BASE - 2]
    s0 = field(cls[0], sch, "slope_key").range
    assert (s0.low, s0.high) == (b"\x00", (((-41000) & 0xFFFFFFFF) ^ 0x80000000).to_bytes(4, "big"))
    assert s0.high == b"\x7f\xff\x5f\xd8"
    s2 = field(cls[2], sch, "slope_key").range
    assert (s2.low, s2.high) == ((0x80000000 - 19999).to_bytes(4, "big"), b"\xff\xff\xff\xff")
    assert field(cls[0], sch, "level") is None                 # [0, 65535] is don't-care: omitted
    assert [params(te) for te in cls] == [[(1, b"\x03")], [(1, b"\x02")], [(1, b"\x01")]]
    cls1 = by_table["CivicIngress.mon1.classify"]
    lv = field(cls1[1], sch, "level").range
    assert (lv.low, lv.high) == ((6001).to_bytes(2, "big"), (7999).to_bytes(2, "big"))

    defaults = {sch.tables[te.table_id].name: te for te in want.defaults}
    assert all(te.is_default_action and not te.match for te in defaults.values())
    cfg = lambda k: [int.from_bytes(v, "big") for _, v in params(defaults[f"CivicIngress.mon{k}.config"])]
    # enabled, signal l3, window, ring_len = W (lsq), estimator lsq, not balance, hold 1,
    # aux_plus = aux_minus (uncompensated: aux = 0), no flow terms
    assert cfg(0) == [1, 2, 20, 20, 1, 0, 1, 2, 2] + [0] * 6
    assert cfg(1) == [1, 0, 9, 8, 0, 0, 1, 0, 0] + [0] * 6        # endpoint: ring_len = W - 1
    assert cfg(2) == cfg(3) == [0] * 15
    assert params(defaults["CivicIngress.mon0.classify"]) == [(1, b"\x03")]
    assert params(defaults["CivicIngress.mon1.classify"]) == [(1, b"\x02")]


def test_compensation_entries_and_config():
    raw = copy.deepcopy(ENTRIES)
    raw["format"] = "civic-entries/2"
    raw["monitors"][0]["compensation"] = {"signal": "l2", "minus": "l3", "offsets": [
        {"aux": [0, 99], "offset": 0}, {"aux": [100, 999], "offset": 19 * 100},
        {"aux": [1000, 65535], "offset": -19 * 3}]}
    sch = schema()
    want = desired_state(parse_entries(raw, "t"), sch)
    comp = [te for te in want.entries if sch.tables[te.table_id].name == "CivicIngress.mon0.compensate"]
    assert [te.priority for te in comp] == [PRIORITY_BASE - i for i in range(3)]
    aux = [(field(te, sch, "aux").range.low, field(te, sch, "aux").range.high) for te in comp]
    assert aux == [(b"\x00", b"\x63"), (b"\x64", b"\x03\xe7"), (b"\x03\xe8", b"\xff\xff")]  # canonical
    assert [int.from_bytes(params(te)[0][1], "big") for te in comp] == [0, 1900, (-57) & 0xFFFFFFFF]
    assert "offset=-57" in sch.describe(comp[2])
    defaults = {sch.tables[te.table_id].name: te for te in want.defaults}
    cfg = [int.from_bytes(v, "big") for _, v in params(defaults["CivicIngress.mon0.config"])]
    assert cfg[7:9] == [1, 2]                      # aux = l2 - l3


@pytest.mark.parametrize("change, message", [
    (lambda c: c.update(signal="l3"), "signal and minus must differ"),
    (lambda c: c.update(minus="p1"), "minus: 'p1' is not one of"),
    (lambda c: c["offsets"].append({"aux": [50, 60], "offset": 19}), "overlap"),
    (lambda c: c["offsets"].__setitem__(0, {"aux": [0, 99], "offset": 20}), "not a multiple of W - 1 = 19"),
    (lambda c: c.pop("offsets"), "missing key 'offsets'"),
])
def test_bad_compensation_is_one_clear_error(change, message):
    raw = copy.deepcopy(ENTRIES)
    raw["format"] = "civic-entries/2"
    comp = {"signal": "l2", "minus": "l3", "offsets": [{"aux": [0, 99], "offset": 0}]}
    change(comp)
    raw["monitors"][0]["compensation"] = comp
    with pytest.raises(CivicError, match=message.replace("(", r"\(")):
        parse_entries(raw, "t")


def test_precondition_ranges_and_forwarding_override():
    raw = copy.deepcopy(ENTRIES)
    raw["forwarding"] = {"1": 3, "3": 1}
    raw["plant_prefix"] = "10.0.7.128/25"
    sch = schema()
    want = desired_state(parse_entries(raw, "t"), sch)
    pre = [te for te in want.entries if sch.tables[te.table_id].name == "CivicIngress.mon0.precondition"][0]
    got = {n: (fm.range.low, fm.range.high) for n in PRECONDITION_FIELDS for fm in [field(pre, sch, n)] if fm is not None}
    assert got == {"l3": (b"\x0b\xb9", b"\xff\xff"), "v2": (b"\x03\x20", b"\xff\xff")}
    pre1 = [te for te in want.entries if sch.tables[te.table_id].name == "CivicIngress.mon1.precondition"][0]
    assert (field(pre1, sch, "l1").range.low, field(pre1, sch, "l1").range.high) == (b"\x13\x89", b"\x1f\x3f")
    fwd = [te for te in want.entries if sch.tables[te.table_id].name == "CivicIngress.forward"]
    assert [(field(te, sch, "ingress_port").exact.value, params(te)) for te in fwd] == \
        [(b"\x01", [(1, b"\x03")]), (b"\x03", [(1, b"\x01")])]
    pp = [te for te in want.entries if sch.tables[te.table_id].name == "CivicIngress.plant_prefix"][0]
    assert (field(pp, sch, "src_addr").lpm.value, field(pp, sch, "src_addr").lpm.prefix_len) == \
        (b"\x0a\x00\x07\x80", 25)


# ---------------------------------------------------------------- converge against the fixture


def test_more_monitors_than_slots_fails_before_any_write(servicer, tmp_path):
    raw = copy.deepcopy(ENTRIES)
    for i in range(3):
        m = copy.deepcopy(raw["monitors"][0])
        m["name"] = f"extra{i}"
        raw["monitors"].append(m)
    with pytest.raises(CivicError, match="5 monitors in the entries, the pipeline has 4 monitor slots"):
        configure(servicer.address, entries_file(tmp_path, raw))
    assert servicer.writes == []


def test_p4info_mismatch_names_the_missing_key(servicer, tmp_path):
    info = load_info()
    for t in info.tables:
        if t.preamble.name == mon(1, "precondition"):
            del t.match_fields[4]       # p1
    servicer._install(info)
    with pytest.raises(CivicError, match=r"CivicIngress.mon1.precondition has no key 'p1'"):
        configure(servicer.address, entries_file(tmp_path))
    assert servicer.writes == []


def test_window_exceeding_ring_capacity_is_rejected_locally(servicer, tmp_path):
    info = load_info()
    for r in info.registers:
        if r.preamble.name.endswith(".ring"):
            r.size = 256 * 16
    servicer._install(info)
    with pytest.raises(CivicError, match=r"monitor 0 \(drain_t3\): ring length 20 exceeds the pipeline's 16 cells"):
        configure(servicer.address, entries_file(tmp_path))
    assert servicer.writes == []
