"""Balance monitors, command steps and hold in the software switch (pipeline.md 3, 3b)."""
from __future__ import annotations

import numpy as np
import pytest

from civic.entries import parse_entries
from civic.pipeline import SwitchModel
from civic.pipeline.classification import holds, next_hold
from civic.pipeline.plant_lookup import command_steps, command_steps_stream
from civic.wire import MESSAGE_DTYPE, monitor_verdict, read_pcap
from data import ROOT

CONTINUOUS = ROOT / "traces" / "continuous"


def test_plain_and_vectorized_models_agree_on_closed_loop_operation(trained_entries):
    """Every monitor, the balance ones included, on a recording with a fault switched on mid-run."""
    msgs = read_pcap(CONTINUOUS / "cl_vm1_warning_onset300.pcap").messages
    model = SwitchModel(trained_entries)
    plain = model.run_plain(msgs)
    assert np.array_equal(plain, SwitchModel(trained_entries).run(msgs))
    assert np.count_nonzero(monitor_verdict(plain, 2)) > 4000          # balance_t3 evaluates most of the run
    # the plain model's changes and counters equal the vectorized ones
    fast = SwitchModel(trained_entries)
    assert [c.__dict__ for c in model.changes] == [c.__dict__ for c in fast.verdict_changes(msgs)]
    assert np.array_equal(model.counts, fast.verdict_counts(msgs))


def test_hold_counts_equal_results_in_a_row():
    rng = np.random.default_rng(3)
    for _ in range(50):
        c = rng.choice([0, 1, 2, 3], size=400, p=[0.1, 0.6, 0.2, 0.1])
        c[rng.integers(0, 400, 20)] = 1
        cand, hold, want = 0, 0, []
        for v in c:
            cand, hold = next_hold(cand, hold, int(v))
            want.append(hold)
        assert np.array_equal(holds(c), want)
    assert holds(np.ones(300, int))[-1] == 255                   # saturates like the 8-bit register


def test_command_steps_from_the_previous_message():
    rng = np.random.default_rng(4)
    f = {k: rng.integers(0, 1001, 200) for k in ("p1", "v1", "v2")}
    fast = command_steps_stream(f)
    last = {k: 0 for k in f}
    for i in range(200):
        row = {k: int(v[i]) for k, v in f.items()}
        assert command_steps(row, last) == {d: int(fast[d][i]) for d in fast}
        last = row


def balance_entries(flow_rows, classes, hold=1, window=10):
    """One balance monitor on l3: term 0 = the pump (zero, p1), term 1 = V2's outflow (l3, v2)."""
    return parse_entries({"format": "civic-entries/3", "monitors": [{
        "name": "b", "kind": "balance", "signal": "l3", "window": window, "hold": hold,
        "precondition": {"dv2": [0, 50]},
        "flows": ["P1", "V2"], "band": "V2",
        "flow_terms": [{"head": ["zero", "zero"], "command": "p1", "entries": []},
                       {"head": ["l3", "zero"], "command": "v2", "entries": flow_rows}],
        "default_class": 1, "classes": classes}]}, "t")


def steady(n, l3, v2):
    msgs = np.zeros(n, MESSAGE_DTYPE)
    msgs["plant"], msgs["src"], msgs["seq"] = True, 0x0A000001, np.arange(1, n + 1)
    msgs["l3"], msgs["v2"] = l3, v2
    return msgs


def test_balance_residual_is_level_change_minus_expected_flow():
    """T3 drains 2 mL a message while the table expects -128/64 = -2 mL: residual 0, class normal;
    the same drain with the table expecting -3 mL: residual +1 mL a message, the 'clog' class."""
    flow = [{"head": [0, 65535], "command": [500, 1000], "flow": -128, "band": 100}]
    classes = [{"slope": [-2147483648, 999], "level": [0, 65535], "class": 1},
               {"slope": [1000, 2147483647], "level": [0, 65535], "class": 2}]
    msgs = steady(60, 8000 - 2 * np.arange(60), 800)
    model = SwitchModel(balance_entries(flow, classes))
    _, (tr,) = model.traces(msgs)
    # the first message steps V2 from 0 (the plant's previous command before any message): the
    # run starts at message 1 and reaches W = 10 at message 10
    assert np.all(tr.slope[10:] == 0) and np.all(tr.code[10:] == 1) and np.all(tr.code[:10] == 0)
    # band_w: the band (100) summed over the ring's 10 messages, >> 7
    assert tr.band[20] == (100 * 10) >> 7
    flow[0]["flow"] = -192
    _, (tr,) = SwitchModel(balance_entries(flow, classes)).traces(msgs)
    mon = balance_entries(flow, classes).monitors[0]
    assert tr.slope[30] * mon.slope_scale == pytest.approx(10.0)     # +1 mL a message = +10 mL/s
    assert np.all(tr.code[10:] == 2)
    assert np.array_equal(SwitchModel(balance_entries(flow, classes)).run_plain(msgs), SwitchModel(
        balance_entries(flow, classes)).run(msgs))


def test_a_command_step_restarts_the_window_and_hold_delays_the_class():
    flow = [{"head": [0, 65535], "command": [0, 1000], "flow": -128, "band": 100}]
    classes = [{"slope": [-2147483648, 2147483647], "level": [0, 65535], "class": 2}]
    v2 = np.full(80, 800)
    v2[40:] = 860                                                   # a 6 % step: more than dv2 allows
    msgs = steady(80, 8000 - 2 * np.arange(80), v2)
    code = monitor_verdict(SwitchModel(balance_entries(flow, classes, hold=5)).run(msgs), 0)
    # run reaches W = 10 at message 10, hold 5 at message 14; the step at 40 restarts both
    assert np.all(code[:14] == 0) and np.all(code[14:40] == 2)
    assert np.all(code[40:54] == 0) and np.all(code[54:] == 2)


def test_class_zero_entries_give_no_verdict():
    flow = [{"head": [0, 65535], "command": [0, 1000], "flow": -128, "band": 10}]
    classes = [{"slope": [-2147483648, 2147483647], "level": [0, 99], "class": 0},
               {"slope": [-2147483648, 2147483647], "level": [100, 65535], "class": 1}]
    msgs = steady(40, 8000 - 2 * np.arange(40), 800)
    model = SwitchModel(balance_entries(flow, classes))
    assert not monitor_verdict(model.run(msgs), 0).any()            # band_w = 100 >> 7 = 0: no verdict
    assert model.verdict_changes(msgs) == []


def test_limit_monitor_classifies_the_value():
    entries = parse_entries({"format": "civic-entries/3", "monitors": [{
        "name": "rim_t1", "kind": "limit", "signal": "l1", "window": 2,
        "classes": [{"slope": [0, 9499], "class": 1}, {"slope": [9500, 9799], "class": 2},
                    {"slope": [9800, 65535], "class": 3}]}]}, "t")
    msgs = steady(6, 0, 0)
    msgs["l1"] = [9000, 9400, 9600, 9700, 9900, 9000]
    assert monitor_verdict(SwitchModel(entries).run(msgs), 0).tolist() == [0, 1, 2, 2, 3, 1]
    assert np.array_equal(SwitchModel(entries).run_plain(msgs), SwitchModel(entries).run(msgs))


@pytest.mark.parametrize("change, message", [
    (lambda m: m.update(kind="flow"), "kind: 'flow' is not one of"),
    (lambda m: m.update(band="V1"), "band: 'V1' is not one of the monitor's flows"),
    (lambda m: m.update(flows=["P1", "V2", "V1"]), "flows: expected 1 to 2"),
    (lambda m: m.update(hold=0), "hold: 0 is outside 1..255"),
    (lambda m: m["flow_terms"][1].update(head=["l3", "l9"]), "head: expected [plus, minus]"),
    (lambda m: m["flow_terms"][1]["entries"].append(
        {"head": [5, 9], "command": [0, 1000], "flow": 1, "band": 0}), "entries 0 and 1 overlap"),
    (lambda m: m["flow_terms"][1]["entries"][0].update(flow=2**30), "flow: 1073741824 is outside"),
    (lambda m: m.update(estimator="value"), "estimator: 'value' does not suit a balance monitor"),
    (lambda m: m["precondition"].update(dx9=[0, 1]), "precondition.dx9: unknown field"),
])
def test_broken_balance_entries_are_one_line_errors(change, message):
    from civic.errors import CivicError

    raw = {"format": "civic-entries/3", "monitors": [{
        "name": "b", "kind": "balance", "signal": "l3", "window": 10, "precondition": {"dv2": [0, 50]},
        "flows": ["P1", "V2"], "band": "V2",
        "flow_terms": [{"head": ["zero", "zero"], "command": "p1", "entries": []},
                       {"head": ["l3", "zero"], "command": "v2",
                        "entries": [{"head": [0, 65535], "command": [0, 1000], "flow": -3, "band": 1}]}],
        "classes": []}]}
    change(raw["monitors"][0])
    with pytest.raises(CivicError) as err:
        parse_entries(raw, "e.json")
    assert message in str(err.value) and "\n" not in str(err.value)


def test_limit_monitor_tables_come_from_the_configured_limits():
    from civic.config import load_monitors
    from civic.train import limit_entries

    rim = next(m for m in load_monitors(ROOT / "configs" / "monitors-rim.toml").monitors if m.kind == "limit")
    entries = limit_entries(rim)
    msgs = steady(14, 0, 0)
    msgs["l1"] = [9000] * 10 + [9699, 9700, 9899, 9900]
    model = SwitchModel(parse_entries({"format": "civic-entries/3", "monitors": [entries.to_json()]}, "t"))
    assert monitor_verdict(model.run(msgs), 0).tolist() == [0] * 9 + [1, 1, 2, 2, 3]
    low = limit_entries(type(rim)(**{**rim.__dict__, "limits": {"warning": 2000, "error": 1000}}))
    model = SwitchModel(parse_entries({"format": "civic-entries/3", "monitors": [low.to_json()]}, "t"))
    msgs["l1"] = [3000] * 10 + [2001, 2000, 1001, 1000]
    assert monitor_verdict(model.run(msgs), 0).tolist() == [0] * 9 + [1, 1, 2, 2, 3]
