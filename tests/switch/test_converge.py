"""`civic configure`'s converge against the servicer fixture: batches, read-back, rollback, register state."""
from __future__ import annotations

import copy
from concurrent import futures

import grpc
import pytest
from finsy.proto import p4r as p4runtime_pb2
from finsy.proto import p4r_grpc as p4runtime_pb2_grpc
from finsy.proto import rpc_code as code_pb2

from civic.cli import main
from civic.entries import load_entries
from civic.errors import CivicError
from civic.switch.converge import action_key, configure
from civic.switch.desired import PRIORITY_BASE, desired_state
from civic.switch.schema import (
    MONITOR_REGISTERS,
    TABLE_FORWARD,
    TABLE_MONITORED_PORT,
    mon,
)

from switch.p4rt_servicer import (
    ENTRIES,
    FIXTURE_P4INFO,
    P4RuntimeFixture,
    entries_file,
    load_info,
    schema,
    update_types,
)


def test_configure_batches_one_write_per_phase_and_reads_back(servicer, tmp_path):
    path = entries_file(tmp_path)
    res = configure(servicer.address, path)
    n_entries = 2 + 1 + 1 + (1 + 3) + (1 + 2)
    assert (res.added, res.modified, res.deleted, res.unchanged) == (n_entries, 6, 0, 2)  # mon2/3 config already all-zero
    assert len(servicer.writes) == 2 == res.writes
    assert [update_types(w) for w in servicer.writes] == [{p4runtime_pb2.Update.INSERT}, {p4runtime_pb2.Update.MODIFY}]
    assert len(servicer.writes[0].updates) == n_entries
    assert all(w.election_id.low == 1 and w.device_id == 0 for w in servicer.writes)
    assert len(servicer.tables) == n_entries
    # read back happened after the writes and the store matches exactly what was desired
    sch = schema()
    want = desired_state(load_entries(path), sch)
    assert {servicer.key(te) for te in want.entries} == set(servicer.tables)
    for te in want.defaults:
        assert action_key(servicer.defaults[te.table_id]) == action_key(te)


def test_second_run_writes_nothing(servicer, tmp_path):
    path = entries_file(tmp_path)
    configure(servicer.address, path)
    before = servicer.snapshot()
    n = len(servicer.writes)
    res = configure(servicer.address, path)
    assert len(servicer.writes) == n and res.writes == 0
    assert (res.added, res.modified, res.deleted) == (0, 0, 0) and res.unchanged == 11 + 8
    assert servicer.snapshot() == before


def test_converges_after_manual_changes(servicer, tmp_path):
    path = entries_file(tmp_path)
    configure(servicer.address, path)
    wanted = servicer.snapshot()
    sch = schema()
    cls0 = sch.table(mon(0, "classify")).id
    fwd = sch.table(TABLE_FORWARD).id
    cfg1 = sch.table(mon(1, "config")).id
    with servicer.lock:
        # someone deleted a class entry, re-pointed port 1, added a stray entry, disabled monitor 1
        victim = next(k for k in servicer.tables if k[0] == cls0)
        del servicer.tables[victim]
        kf = next(k for k in servicer.tables if k[0] == fwd)
        servicer.tables[kf].action.action.params[0].value = b"\x07"
        stray = copy.deepcopy(servicer.tables[next(k for k in servicer.tables if k[0] == cls0)])
        stray.priority = 5
        servicer.tables[servicer.key(stray)] = stray
        servicer.defaults[cfg1].action.action.params[0].value = b"\x00"
    servicer.writes.clear()
    res = configure(servicer.address, path)
    assert (res.added, res.modified, res.deleted) == (1, 2, 1)
    assert [update_types(w) for w in servicer.writes] == [
        {p4runtime_pb2.Update.INSERT}, {p4runtime_pb2.Update.MODIFY}, {p4runtime_pb2.Update.DELETE}]
    assert servicer.snapshot() == wanted


def test_changed_entries_file_converges(servicer, tmp_path):
    configure(servicer.address, entries_file(tmp_path))
    raw = copy.deepcopy(ENTRIES)
    raw["udp_port"] = 50001
    raw["monitors"] = raw["monitors"][:1]                       # monitor 1 disabled
    raw["monitors"][0]["classes"][1]["class"] = 3               # same key, new action
    new = entries_file(tmp_path, raw, "new.json")
    servicer.writes.clear()
    res = configure(servicer.address, new)
    # +1 port; modify 1 class + mon1 config + mon1 classify default; -1 port, -3 mon1 entries
    assert (res.added, res.modified, res.deleted) == (1, 3, 4)
    # a fresh fixture configured directly from the new file holds the same state
    fresh = P4RuntimeFixture(load_info())
    server = grpc.server(futures.ThreadPoolExecutor(max_workers=4))
    p4runtime_pb2_grpc.add_P4RuntimeServicer_to_server(fresh, server)
    port = server.add_insecure_port("127.0.0.1:0")
    server.start()
    try:
        configure(f"127.0.0.1:{port}", new)
    finally:
        server.stop(grace=None)
    assert servicer.snapshot() == fresh.snapshot()


def test_full_table_deletes_before_inserting(servicer, tmp_path):
    info = load_info()
    for t in info.tables:
        if t.preamble.name == TABLE_MONITORED_PORT:
            t.size = 1
    servicer._install(info)
    configure(servicer.address, entries_file(tmp_path))
    raw = copy.deepcopy(ENTRIES)
    raw["udp_port"] = 40000
    servicer.writes.clear()
    res = configure(servicer.address, entries_file(tmp_path, raw, "b.json"))
    assert (res.added, res.deleted) == (1, 1)
    assert [update_types(w) for w in servicer.writes] == [{p4runtime_pb2.Update.DELETE}, {p4runtime_pb2.Update.INSERT}]


# ---------------------------------------------------------------- errors


def test_rejected_write_rolls_back_and_reports_one_line(servicer, tmp_path):
    configure(servicer.address, entries_file(tmp_path))
    before = servicer.snapshot()
    raw = copy.deepcopy(ENTRIES)
    raw["udp_port"] = 50001                                   # INSERT port, DELETE old port
    raw["monitors"][0]["classes"][2]["slope"] = [-19999, 0]   # INSERT new key, DELETE old key
    raw["monitors"][0]["classes"].append({"slope": [1, 2147483647], "level": [0, 65535], "class": 2})
    raw["monitors"][0]["window"] = 21                         # MODIFY config
    cls0 = servicer.by_name(mon(0, "classify"))

    def hook(u):   # the fixture refuses the class entry with priority BASE-3 (the appended one)
        te = u.entity.table_entry
        if u.type == p4runtime_pb2.Update.INSERT and te.table_id == cls0 and te.priority == PRIORITY_BASE - 3:
            return code_pb2.RESOURCE_EXHAUSTED, "no room in TCAM"
        return None

    servicer.reject_hook = hook
    servicer.writes.clear()
    with pytest.raises(CivicError) as info:
        configure(servicer.address, entries_file(tmp_path, raw, "b.json"))
    msg = str(info.value)
    assert "\n" not in msg
    assert "rejected update" in msg and "RESOURCE_EXHAUSTED: no room in TCAM" in msg
    assert "rolled back the 2 updates already applied" in msg
    assert servicer.snapshot() == before                      # no half-updated table
    assert [len(w.updates) for w in servicer.writes[:2]] == [1, 3]   # probe, then the whole INSERT phase


def set_state(fx, k, slot=1):
    with fx.lock:
        reg = lambda name: fx.registers[fx.by_name(name)]
        reg(mon(k, "ptr"))[slot] = 3
        reg(mon(k, "run"))[slot] = 50
        reg(mon(k, "s0"))[slot] = 12345
        reg(mon(k, "s1"))[slot] = 999
        reg(mon(k, "ring"))[slot * 128 + 2] = 777


def state_of(fx, k) -> dict:
    with fx.lock:
        return {r: {i: v for i, v in fx.registers[fx.by_name(mon(k, r))].items() if v}
                for r in MONITOR_REGISTERS}


def test_reconfigured_monitor_gets_registers_zeroed(servicer, tmp_path):
    configure(servicer.address, entries_file(tmp_path))
    set_state(servicer, 0)
    set_state(servicer, 1)
    raw = copy.deepcopy(ENTRIES)
    raw["monitors"][1]["classes"].pop()           # tables only: state stays
    res = configure(servicer.address, entries_file(tmp_path, raw, "b.json"))
    assert res.cleared == [] and state_of(servicer, 0)["s0"] == {1: 12345}
    raw["monitors"][0]["window"] = 25             # monitor 0 changes: its state is meaningless now
    res = configure(servicer.address, entries_file(tmp_path, raw, "c.json"))
    assert res.cleared == [0] and res.modified == 1
    assert state_of(servicer, 0) == {r: {} for r in MONITOR_REGISTERS}
    assert state_of(servicer, 1)["s0"] == {1: 12345} and state_of(servicer, 1)["ring"] == {130: 777}
    assert configure(servicer.address, entries_file(tmp_path, raw, "c.json")).writes == 0


def test_no_register_access_reinstalls_pipeline_or_refuses(servicer, tmp_path):
    servicer.register_support = False             # like BMv2's P4Runtime server
    build = tmp_path / "build"
    build.mkdir()
    (build / "civic.json").write_text("{}")
    (build / "civic.p4info.txtpb").write_text(FIXTURE_P4INFO.read_text())
    first = configure(servicer.address, entries_file(tmp_path), build)   # fresh: enabling needs no reset
    assert first.pipeline_pushed and len(servicer.pipelines) == 1
    raw = copy.deepcopy(ENTRIES)
    raw["monitors"][1]["estimator"] = "lsq"
    changed = entries_file(tmp_path, raw, "b.json")
    servicer.writes.clear()
    with pytest.raises(CivicError, match="monitor slot 1 changes configuration.*pass --pipeline DIR"):
        configure(servicer.address, changed)
    assert all(u.entity.WhichOneof("entity") == "register_entry" for w in servicer.writes for u in w.updates)
    assert len(servicer.writes) == 1              # only the probe, which the fixture refused
    res = configure(servicer.address, changed, build)
    assert res.pipeline_pushed and len(servicer.pipelines) == 2 and res.added == 11
    assert main(["configure", "--switch", servicer.address, "--read"]) == 0
    assert main(["configure", "--switch", servicer.address, "--read", "--plant", "10.0.0.1"]) == 2


def test_configures_what_civic_train_writes(servicer, tmp_path, capsys, trained_entries):
    """The output of training on traces/training installs, reads back equal, and is idempotent."""
    path = tmp_path / "trained.json"
    trained_entries.save(path)
    entries = load_entries(path)
    assert main(["configure", "--switch", servicer.address, "--entries", str(path)]) == 0
    sch = schema()
    n_classes = [len(m.classes) for m in entries.monitors]
    for k, n in enumerate(n_classes):
        tid = sch.table(mon(k, "classify")).id
        prios = sorted((te.priority for key, te in servicer.tables.items() if key[0] == tid), reverse=True)
        assert prios == [PRIORITY_BASE - i for i in range(n)]
    writes = len(servicer.writes)
    res = configure(servicer.address, path)
    assert res.writes == 0 and len(servicer.writes) == writes
    n_offsets = sum(len(m.offsets) for m in entries.monitors)
    assert n_offsets > 0                                        # the default compensates drain_t3
    n_flows = sum(len(t.rows) for m in entries.monitors for t in m.terms)
    assert n_flows > 0                                          # the balance monitors' flow terms
    assert res.unchanged == sum(n_classes) + n_offsets + n_flows + len(entries.monitors) + 4 + 8


def test_padded_byte_strings_for_old_servers(servicer, tmp_path, capsys):
    servicer.padded_only = True                  # like PI before it accepted canonical byte strings
    path = entries_file(tmp_path)
    assert main(["configure", "--switch", servicer.address, "--entries", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "INVALID_ARGUMENT: ingress_port: bytestring has wrong size" in err
    assert "rolled back the 8 updates already applied" in err     # entries whose bytes happened to be full width
    assert servicer.tables == {}
    assert main(["configure", "--switch", servicer.address, "--entries", str(path), "--padded-bytes"]) == 0
    ins = servicer.writes[-2]
    sch = schema()
    fwd = next(u.entity.table_entry for u in ins.updates if u.entity.table_entry.table_id == sch.table(TABLE_FORWARD).id)
    assert fwd.match[0].exact.value == b"\x00\x01" and fwd.action.action.params[0].value == b"\x00\x02"
    res = configure(servicer.address, path, padded_bytes=True)
    assert res.writes == 0                       # read-back compares values, not encodings
    raw = copy.deepcopy(ENTRIES)
    raw["monitors"][0]["window"] = 30            # register clearing with full-width zeros too
    set_state(servicer, 0)
    res = configure(servicer.address, entries_file(tmp_path, raw, "b.json"), padded_bytes=True)
    assert res.cleared == [0] and state_of(servicer, 0) == {r: {} for r in MONITOR_REGISTERS}
