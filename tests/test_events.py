"""Verdict-change events: digest decoding, the JSON-lines format, placing digests on messages."""
from __future__ import annotations

import json

import numpy as np
import pytest

from civic.errors import CivicError
from civic.events import KEYS, digest_changes, event, place, read_events, write_events
from civic.pipeline.notify import Change
from civic.wire import MESSAGE_DTYPE, ip_to_int


def member(**kw):
    base = {"plant": ip_to_int("10.0.0.7"), "seq": 41, "changed": 0, "prev": 0, "cls": 0}
    for m in range(4):
        base[f"slope{m}"] = 0
        base[f"level{m}"] = 0
    base.update(kw)
    return base


def test_one_digest_with_two_changed_monitors_is_two_events_in_monitor_order():
    d = member(changed=0b101, prev=0b10_00_00, cls=0b11_00_01, slope0=(-41000) & 0xFFFFFFFF, level0=6500,
               slope2=1234, level2=7000)
    got = digest_changes(d, 4)
    assert [(c.monitor, c.prev, c.cls, c.slope, c.level) for c in got] == [(0, 0, 1, -41000, 6500),
                                                                           (2, 2, 3, 1234, 7000)]
    evs = [event(c, 12.5, ["drain_t3", "fill_t1", "x", "y"]) for c in got]
    assert tuple(evs[0]) == KEYS
    assert evs[0] == {"t": 12.5, "plant": "10.0.0.7", "monitor": "drain_t3", "from": None, "to": "normal",
                      "seq": 41, "slope": -41000, "level": 6500}
    assert evs[1]["monitor"] == "x" and evs[1]["from"] == "warning" and evs[1]["to"] == "error"


def test_digests_are_placed_on_their_message_in_order_even_with_a_repeated_seq():
    msgs = np.zeros(6, MESSAGE_DTYPE)
    msgs["plant"] = True
    msgs["src"] = [1, 2, 1, 1, 2, 1]
    msgs["seq"] = [5, 5, 6, 5, 6, 7]              # plant 1 repeats seq 5 at index 3
    digests = [[Change(-1, 2, 0, 0, 1, 5, 0, 0)], [Change(-1, 1, 0, 0, 2, 5, 0, 0)],
               [Change(-1, 1, 0, 2, 3, 7, 0, 0), Change(-1, 1, 1, 0, 1, 7, 0, 0)]]
    got = place(digests, msgs)
    assert [c.index for c in got] == [1, 3, 5, 5]
    with pytest.raises(CivicError, match="seq 9"):
        place([[Change(-1, 1, 0, 0, 1, 9, 0, 0)]], msgs)


def test_events_round_trip_as_json_lines(tmp_path):
    evs = [event(Change(3, ip_to_int("10.0.0.1"), 0, 1, 2, 7, -5, 4000), 1.25, ["drain_t3"])]
    write_events(tmp_path / "e.jsonl", evs)
    assert read_events(tmp_path / "e.jsonl") == evs
    assert json.loads((tmp_path / "e.jsonl").read_text().splitlines()[0])["from"] == "normal"
