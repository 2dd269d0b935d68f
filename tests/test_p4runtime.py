"""`civic configure` against an in-process P4Runtime servicer fixture.

`P4RuntimeFixture` is a test fixture, not a switch: a grpcio servicer on
127.0.0.1 that implements Write / Read / pipeline config / StreamChannel
minimally, records every request and keeps a table store. It rejects what a
P4Runtime server must reject (unknown ids, bytes wider than the field,
non-canonical byte strings, don't-care fields sent explicitly, missing
priorities, duplicate INSERT, MODIFY/DELETE of missing entries, full tables),
so the tests check the encoding, not only the bookkeeping.
"""
from __future__ import annotations

import copy
import json
import threading
from concurrent import futures
from pathlib import Path

import grpc
import pytest
from google.protobuf import any_pb2, text_format

from civic.config import PRECONDITION_FIELDS
from civic import p4runtime as p4rt
from civic.p4runtime import code_pb2, p4info_pb2, p4runtime_pb2, p4runtime_pb2_grpc, status_pb2
from civic.cli import main
from civic.entries import load_entries, parse_entries
from civic.errors import CivicError

FIXTURE_P4INFO = Path(__file__).parent / "fixtures" / "civic.p4info.txtpb"
MF = p4info_pb2.MatchField

ENTRIES = {
    "format": "civic-entries/1",
    "udp_port": 50000,
    "plant_prefix": "10.0.0.0/24",
    "monitors": [
        {"name": "drain_t3", "signal": "l3", "window": 20, "estimator": "lsq",
         "precondition": {"l3": [3001, 65535], "v2": [800, 65535]},
         "slope_scale_ml_per_s": 0.0090225, "default_class": 3,
         "classes": [
             {"slope": [-2147483648, -41000], "level": [0, 65535], "class": 3},
             {"slope": [-40999, -20000], "level": [0, 65535], "class": 2},
             {"slope": [-19999, 2147483647], "level": [0, 65535], "class": 1},
         ]},
        {"name": "fill_t1", "signal": "l1", "window": 9, "estimator": "endpoint",
         "precondition": {"p1": [991, 65535], "l1": [5001, 7999]},
         "default_class": 2,
         "classes": [
             {"slope": [100, 400], "level": [5001, 6000], "class": 1},
             {"slope": [100, 400], "level": [6001, 7999], "class": 2},
         ]},
    ],
    "training": {"note": "hand-written for tests"},
}


def load_info() -> p4info_pb2.P4Info:
    info = p4info_pb2.P4Info()
    text_format.Merge(FIXTURE_P4INFO.read_text(), info)
    return info


def entries_file(tmp_path, raw=None, name="entries.json") -> Path:
    path = tmp_path / name
    path.write_text(json.dumps(ENTRIES if raw is None else raw))
    return path


# ---------------------------------------------------------------- the servicer fixture
class Reject(Exception):
    def __init__(self, code, msg):
        super().__init__(msg)
        self.code, self.msg = code, msg


class P4RuntimeFixture(p4runtime_pb2_grpc.P4RuntimeServicer):
    """Minimal recording P4Runtime servicer with strict request checks (a test fixture)."""

    def __init__(self, p4info: p4info_pb2.P4Info | None, device_id: int = 0):
        self.device_id = device_id
        self.lock = threading.Lock()
        self.writes: list[p4runtime_pb2.WriteRequest] = []
        self.reads: list[p4runtime_pb2.ReadRequest] = []
        self.pipelines: list[p4runtime_pb2.SetForwardingPipelineConfigRequest] = []
        self.reject_hook = None          # update -> (code, msg) | None
        self.primary_floor = 0           # election ids below this are told they are backups
        self.register_support = True     # False: register access UNIMPLEMENTED, like BMv2 (p4lang/PI#376)
        self.padded_only = False         # True: only full-width byte strings, like PI before 2021
        self.canonical_only = True       # False: canonical or full width, like current PI
        self.legacy_device_config = False  # True: p4_device_config must be a p4.tmp.P4DeviceConfig (old PI)
        self.device_data = b""
        self.cookie = 0
        self._install(p4info)

    # -- state
    def _install(self, p4info):
        self.p4info = p4info
        self.tables: dict[tuple, p4runtime_pb2.TableEntry] = {}
        self.defaults: dict[int, p4runtime_pb2.TableEntry] = {}
        self.registers: dict[int, dict[int, int]] = {}
        self.digests: dict[int, p4runtime_pb2.DigestEntry.Config] = {}
        if p4info is None:
            return
        self.t = {t.preamble.id: t for t in p4info.tables}
        self.a = {a.preamble.id: a for a in p4info.actions}
        self.r = {r.preamble.id: r for r in p4info.registers}
        for t in p4info.tables:
            d = p4runtime_pb2.TableEntry(table_id=t.preamble.id, is_default_action=True)
            d.action.action.action_id = t.action_refs[-1].id
            for p in self.a[t.action_refs[-1].id].params:
                d.action.action.params.add(param_id=p.id, value=b"\x00")
            self.defaults[t.preamble.id] = d
        self.registers = {r.preamble.id: {} for r in p4info.registers}

    def by_name(self, name: str) -> int:
        for obj in list(self.p4info.tables) + list(self.p4info.actions) + list(self.p4info.registers):
            if obj.preamble.name == name:
                return obj.preamble.id
        raise KeyError(name)

    @staticmethod
    def key(te) -> tuple:
        """Entry identity with byte strings normalised (a server compares values, not encodings)."""
        fields = []
        for fm in te.match:
            kind = fm.WhichOneof("field_match_type")
            sub = getattr(fm, kind)
            vals = tuple(int.from_bytes(v, "big") if isinstance(v, bytes) else v
                         for _, v in sorted((f.name, val) for f, val in sub.ListFields()))
            fields.append((fm.field_id, kind) + vals)
        return te.table_id, te.priority, tuple(sorted(fields))

    def snapshot(self) -> tuple:
        with self.lock:
            return ({k: v.SerializeToString(deterministic=True) for k, v in self.tables.items()},
                    {k: v.SerializeToString(deterministic=True) for k, v in self.defaults.items()})

    # -- checks a P4Runtime server makes
    def _bytes(self, value: bytes, width: int, what: str):
        if not value:
            raise Reject(code_pb2.INVALID_ARGUMENT, f"{what}: empty byte string")
        if self.padded_only:
            if len(value) != (width + 7) // 8:
                raise Reject(code_pb2.INVALID_ARGUMENT, f"{what}: bytestring has wrong size")
        elif self.canonical_only and len(value) > 1 and value[0] == 0:
            raise Reject(code_pb2.INVALID_ARGUMENT, f"{what}: not canonical")
        v = int.from_bytes(value, "big")
        if v >> width:
            raise Reject(code_pb2.INVALID_ARGUMENT, f"{what}: wider than {width} bits")
        return v

    def _check_action(self, t, ta):
        if ta.WhichOneof("type") != "action":
            raise Reject(code_pb2.INVALID_ARGUMENT, "direct action required")
        a = self.a.get(ta.action.action_id)
        if a is None or ta.action.action_id not in {r.id for r in t.action_refs}:
            raise Reject(code_pb2.INVALID_ARGUMENT, f"action {ta.action.action_id:#x} not in table")
        params = {p.id: p for p in a.params}
        if sorted(p.param_id for p in ta.action.params) != sorted(params):
            raise Reject(code_pb2.INVALID_ARGUMENT, "wrong action parameters")
        for p in ta.action.params:
            self._bytes(p.value, params[p.param_id].bitwidth, f"param {p.param_id}")

    def _check_entry(self, te):
        t = self.t.get(te.table_id)
        if t is None:
            raise Reject(code_pb2.NOT_FOUND, f"unknown table id {te.table_id:#x}")
        fields = {m.id: m for m in t.match_fields}
        needs_priority = any(m.match_type in (MF.RANGE, MF.TERNARY, MF.OPTIONAL) for m in t.match_fields)
        if te.is_default_action:
            if te.match or te.priority:
                raise Reject(code_pb2.INVALID_ARGUMENT, "default entry with match/priority")
            self._check_action(t, te.action)
            return
        if needs_priority != (te.priority > 0):
            raise Reject(code_pb2.INVALID_ARGUMENT, f"priority {te.priority} invalid for this table")
        seen = set()
        for fm in te.match:
            m = fields.get(fm.field_id)
            if m is None or fm.field_id in seen:
                raise Reject(code_pb2.INVALID_ARGUMENT, f"bad field id {fm.field_id}")
            seen.add(fm.field_id)
            kind = fm.WhichOneof("field_match_type")
            if kind == "exact" and m.match_type == MF.EXACT:
                self._bytes(fm.exact.value, m.bitwidth, m.name)
            elif kind == "lpm" and m.match_type == MF.LPM:
                v = self._bytes(fm.lpm.value, m.bitwidth, m.name)
                plen = fm.lpm.prefix_len
                if not 0 < plen <= m.bitwidth or v & ((1 << (m.bitwidth - plen)) - 1):
                    raise Reject(code_pb2.INVALID_ARGUMENT, f"{m.name}: bad lpm")
            elif kind == "range" and m.match_type == MF.RANGE:
                lo = self._bytes(fm.range.low, m.bitwidth, m.name)
                hi = self._bytes(fm.range.high, m.bitwidth, m.name)
                if lo > hi or (lo == 0 and hi == (1 << m.bitwidth) - 1):
                    raise Reject(code_pb2.INVALID_ARGUMENT, f"{m.name}: empty or don't-care range")
            else:
                raise Reject(code_pb2.INVALID_ARGUMENT, f"{m.name}: wrong match kind {kind}")
        for m in t.match_fields:
            if m.match_type == MF.EXACT and m.id not in seen:
                raise Reject(code_pb2.INVALID_ARGUMENT, f"exact field {m.name} missing")
        self._check_action(t, te.action)

    def _apply(self, u):
        if self.reject_hook:
            verdict = self.reject_hook(u)
            if verdict:
                raise Reject(*verdict)
        if u.entity.WhichOneof("entity") == "register_entry":
            r = u.entity.register_entry
            if not self.register_support:
                raise Reject(code_pb2.UNIMPLEMENTED, "Register writes are not supported yet")
            reg = self.r.get(r.register_id)
            if reg is None or u.type != p4runtime_pb2.Update.MODIFY or not r.HasField("index"):
                raise Reject(code_pb2.INVALID_ARGUMENT, "bad register write")
            if not 0 <= r.index.index < reg.size:
                raise Reject(code_pb2.OUT_OF_RANGE, "register index")
            v = self._bytes(r.data.bitstring, reg.type_spec.bitstring.bit.bitwidth, "register data")
            self.registers[r.register_id][r.index.index] = v
            return
        if u.entity.WhichOneof("entity") == "digest_entry":       # a controller enabling a digest
            d = u.entity.digest_entry
            if d.digest_id not in {x.preamble.id for x in self.p4info.digests}:
                raise Reject(code_pb2.NOT_FOUND, "no such digest")
            self.digests[d.digest_id] = copy.deepcopy(d.config)
            return
        te = u.entity.table_entry
        self._check_entry(te)
        if te.is_default_action:
            if u.type != p4runtime_pb2.Update.MODIFY:
                raise Reject(code_pb2.INVALID_ARGUMENT, "default entry: only MODIFY")
            self.defaults[te.table_id] = copy.deepcopy(te)
            return
        k = self.key(te)
        if u.type == p4runtime_pb2.Update.INSERT:
            if k in self.tables:
                raise Reject(code_pb2.ALREADY_EXISTS, "entry exists")
            size = self.t[te.table_id].size
            if sum(1 for kk in self.tables if kk[0] == te.table_id) >= size:
                raise Reject(code_pb2.RESOURCE_EXHAUSTED, "table full")
            self.tables[k] = copy.deepcopy(te)
        elif u.type == p4runtime_pb2.Update.MODIFY:
            if k not in self.tables:
                raise Reject(code_pb2.NOT_FOUND, "no such entry")
            self.tables[k] = copy.deepcopy(te)
        elif u.type == p4runtime_pb2.Update.DELETE:
            if k not in self.tables:
                raise Reject(code_pb2.NOT_FOUND, "no such entry")
            del self.tables[k]
        else:
            raise Reject(code_pb2.INVALID_ARGUMENT, "bad update type")

    # -- RPCs
    def Write(self, request, context):
        with self.lock:
            self.writes.append(request)
            if self.p4info is None:
                context.abort(grpc.StatusCode.FAILED_PRECONDITION, "no pipeline")
            errors, failed = [], False
            for u in request.updates:
                err = p4runtime_pb2.Error(canonical_code=code_pb2.OK)
                try:
                    self._apply(u)
                except Reject as rej:
                    err = p4runtime_pb2.Error(canonical_code=rej.code, message=rej.msg)
                    failed = True
                any_ = any_pb2.Any()
                any_.Pack(err)
                errors.append(any_)
            if failed:
                st = status_pb2.Status(code=code_pb2.UNKNOWN, message="write failed", details=errors)
                context.set_trailing_metadata([("grpc-status-details-bin", st.SerializeToString())])
                context.abort(grpc.StatusCode.UNKNOWN, "write failed")
            return p4runtime_pb2.WriteResponse()

    def Read(self, request, context):
        with self.lock:
            self.reads.append(request)
            if self.p4info is None:
                context.abort(grpc.StatusCode.FAILED_PRECONDITION, "no pipeline")
            resp = p4runtime_pb2.ReadResponse()
            for ent in request.entities:
                kind = ent.WhichOneof("entity")
                if kind == "table_entry":
                    q = ent.table_entry
                    if q.is_default_action:
                        resp.entities.add().table_entry.CopyFrom(self.defaults[q.table_id])
                        continue
                    for k, te in self.tables.items():
                        if q.table_id in (0, te.table_id):
                            resp.entities.add().table_entry.CopyFrom(te)
                elif kind == "register_entry":
                    if not self.register_support:
                        context.abort(grpc.StatusCode.UNIMPLEMENTED, "Register reads are not supported yet")
                    q = ent.register_entry
                    reg = self.r.get(q.register_id)
                    if reg is None:
                        context.abort(grpc.StatusCode.NOT_FOUND, "unknown register")
                    idxs = [q.index.index] if q.HasField("index") else range(reg.size)
                    for i in idxs:
                        if not 0 <= i < reg.size:
                            context.abort(grpc.StatusCode.OUT_OF_RANGE, "index")
                        r = resp.entities.add().register_entry
                        r.register_id, r.index.index = q.register_id, i
                        r.data.bitstring = p4rt.encode_value(self.registers[q.register_id].get(i, 0), 64, "reg")
            yield resp

    def SetForwardingPipelineConfig(self, request, context):
        with self.lock:
            self.pipelines.append(copy.deepcopy(request))
            if request.action != p4runtime_pb2.SetForwardingPipelineConfigRequest.VERIFY_AND_COMMIT:
                context.abort(grpc.StatusCode.UNIMPLEMENTED, "only VERIFY_AND_COMMIT")
            data = request.config.p4_device_config
            if not data:
                context.abort(grpc.StatusCode.INVALID_ARGUMENT, "no device config")
            if self.legacy_device_config:
                if not data.startswith(b"\x08\x01\x1a"):     # reassign: true, then device_data (field 3)
                    context.abort(grpc.StatusCode.INVALID_ARGUMENT,
                                  "Invalid 'p4_device_config', not an instance of p4::tmp::P4DeviceConfig")
                n, shift, i = 0, 0, 3
                while True:
                    n |= (data[i] & 0x7F) << shift
                    shift += 7
                    i += 1
                    if not data[i - 1] & 0x80:
                        break
                data = data[i:i + n]
            self.device_data = data
            self._install(copy.deepcopy(request.config.p4info))
            self.cookie = request.config.cookie.cookie
            return p4runtime_pb2.SetForwardingPipelineConfigResponse()

    def GetForwardingPipelineConfig(self, request, context):
        with self.lock:
            if self.p4info is None:
                context.abort(grpc.StatusCode.FAILED_PRECONDITION, "no pipeline")
            resp = p4runtime_pb2.GetForwardingPipelineConfigResponse()
            resp.config.cookie.cookie = self.cookie
            if request.response_type != p4runtime_pb2.GetForwardingPipelineConfigRequest.COOKIE_ONLY:
                resp.config.p4info.CopyFrom(self.p4info)
            return resp

    def Capabilities(self, request, context):
        return p4runtime_pb2.CapabilitiesResponse(p4runtime_api_version="1.4.1")

    def StreamChannel(self, request_iterator, context):
        for req in request_iterator:
            if req.HasField("arbitration"):
                arb = req.arbitration
                eid = (arb.election_id.high << 64) | arb.election_id.low
                out = p4runtime_pb2.StreamMessageResponse()
                out.arbitration.CopyFrom(arb)
                out.arbitration.status.code = code_pb2.OK if eid >= self.primary_floor else code_pb2.ALREADY_EXISTS
                yield out


@pytest.fixture
def servicer():
    fx = P4RuntimeFixture(load_info())
    server = grpc.server(futures.ThreadPoolExecutor(max_workers=8))
    p4runtime_pb2_grpc.add_P4RuntimeServicer_to_server(fx, server)
    port = server.add_insecure_port("127.0.0.1:0")
    server.start()
    fx.address = f"127.0.0.1:{port}"
    yield fx
    server.stop(grace=None)


def schema() -> p4rt.P4Schema:
    return p4rt.P4Schema(load_info())


def update_types(req) -> set:
    return {u.type for u in req.updates}


# ---------------------------------------------------------------- encoding
def field(te, sch, name):
    t = sch.table_by_id[te.table_id]
    fid = t.keys[name].id
    hits = [fm for fm in te.match if fm.field_id == fid]
    return hits[0] if hits else None


def params(te) -> list:
    return [(p.param_id, p.value) for p in te.action.action.params]


def test_entries_to_protos_encoding():
    sch = schema()
    want = p4rt.desired_state(parse_entries(copy.deepcopy(ENTRIES), "t"), sch)
    by_table: dict = {}
    for te in want.entries:
        by_table.setdefault(sch.table_by_id[te.table_id].name, []).append(te)

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
    assert pre.priority == p4rt.PRIORITY_BASE
    assert len(pre.match) == 2                                  # l3 and v2; l1, l2, l4, p1, v1 don't-care
    l3, v2 = field(pre, sch, "l3").range, field(pre, sch, "v2").range
    assert (l3.low, l3.high, v2.low, v2.high) == (b"\x0b\xb9", b"\xff\xff", b"\x03\x20", b"\xff\xff")
    cls = by_table["CivicIngress.mon0.classify"]
    assert [te.priority for te in cls] == [p4rt.PRIORITY_BASE, p4rt.PRIORITY_BASE - 1, p4rt.PRIORITY_BASE - 2]
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

    defaults = {sch.table_by_id[te.table_id].name: te for te in want.defaults}
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
    want = p4rt.desired_state(parse_entries(raw, "t"), sch)
    comp = [te for te in want.entries if sch.table_by_id[te.table_id].name == "CivicIngress.mon0.compensate"]
    assert [te.priority for te in comp] == [p4rt.PRIORITY_BASE - i for i in range(3)]
    aux = [(field(te, sch, "aux").range.low, field(te, sch, "aux").range.high) for te in comp]
    assert aux == [(b"\x00", b"\x63"), (b"\x64", b"\x03\xe7"), (b"\x03\xe8", b"\xff\xff")]  # canonical
    assert [int.from_bytes(params(te)[0][1], "big") for te in comp] == [0, 1900, (-57) & 0xFFFFFFFF]
    assert "offset=-57" in sch.describe(comp[2])
    defaults = {sch.table_by_id[te.table_id].name: te for te in want.defaults}
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
    want = p4rt.desired_state(parse_entries(raw, "t"), sch)
    pre = [te for te in want.entries if sch.table_by_id[te.table_id].name == "CivicIngress.mon0.precondition"][0]
    got = {n: (fm.range.low, fm.range.high) for n in PRECONDITION_FIELDS for fm in [field(pre, sch, n)] if fm is not None}
    assert got == {"l3": (b"\x0b\xb9", b"\xff\xff"), "v2": (b"\x03\x20", b"\xff\xff")}
    pre1 = [te for te in want.entries if sch.table_by_id[te.table_id].name == "CivicIngress.mon1.precondition"][0]
    assert (field(pre1, sch, "l1").range.low, field(pre1, sch, "l1").range.high) == (b"\x13\x89", b"\x1f\x3f")
    fwd = [te for te in want.entries if sch.table_by_id[te.table_id].name == "CivicIngress.forward"]
    assert [(field(te, sch, "ingress_port").exact.value, params(te)) for te in fwd] == \
        [(b"\x01", [(1, b"\x03")]), (b"\x03", [(1, b"\x01")])]
    pp = [te for te in want.entries if sch.table_by_id[te.table_id].name == "CivicIngress.plant_prefix"][0]
    assert (field(pp, sch, "src_addr").lpm.value, field(pp, sch, "src_addr").lpm.prefix_len) == \
        (b"\x0a\x00\x07\x80", 25)


# ---------------------------------------------------------------- converge against the fixture
def test_configure_batches_one_write_per_phase_and_reads_back(servicer, tmp_path):
    path = entries_file(tmp_path)
    res = p4rt.configure(servicer.address, path)
    n_entries = 2 + 1 + 1 + (1 + 3) + (1 + 2)
    assert (res.added, res.modified, res.deleted, res.unchanged) == (n_entries, 6, 0, 2)  # mon2/3 config already all-zero
    assert len(servicer.writes) == 2 == res.writes
    assert [update_types(w) for w in servicer.writes] == [{p4runtime_pb2.Update.INSERT}, {p4runtime_pb2.Update.MODIFY}]
    assert len(servicer.writes[0].updates) == n_entries
    assert all(w.election_id.low == 1 and w.device_id == 0 for w in servicer.writes)
    assert len(servicer.tables) == n_entries
    # read back happened after the writes and the store matches exactly what was desired
    sch = schema()
    want = p4rt.desired_state(load_entries(path), sch)
    assert {servicer.key(te) for te in want.entries} == set(servicer.tables)
    for te in want.defaults:
        assert p4rt.action_key(servicer.defaults[te.table_id]) == p4rt.action_key(te)


def test_second_run_writes_nothing(servicer, tmp_path):
    path = entries_file(tmp_path)
    p4rt.configure(servicer.address, path)
    before = servicer.snapshot()
    n = len(servicer.writes)
    res = p4rt.configure(servicer.address, path)
    assert len(servicer.writes) == n and res.writes == 0
    assert (res.added, res.modified, res.deleted) == (0, 0, 0) and res.unchanged == 11 + 8
    assert servicer.snapshot() == before


def test_converges_after_manual_changes(servicer, tmp_path):
    path = entries_file(tmp_path)
    p4rt.configure(servicer.address, path)
    wanted = servicer.snapshot()
    sch = schema()
    cls0 = sch.table(p4rt.mon(0, "classify")).id
    fwd = sch.table(p4rt.TABLE_FORWARD).id
    cfg1 = sch.table(p4rt.mon(1, "config")).id
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
    res = p4rt.configure(servicer.address, path)
    assert (res.added, res.modified, res.deleted) == (1, 2, 1)
    assert [update_types(w) for w in servicer.writes] == [
        {p4runtime_pb2.Update.INSERT}, {p4runtime_pb2.Update.MODIFY}, {p4runtime_pb2.Update.DELETE}]
    assert servicer.snapshot() == wanted


def test_changed_entries_file_converges(servicer, tmp_path):
    p4rt.configure(servicer.address, entries_file(tmp_path))
    raw = copy.deepcopy(ENTRIES)
    raw["udp_port"] = 50001
    raw["monitors"] = raw["monitors"][:1]                       # monitor 1 disabled
    raw["monitors"][0]["classes"][1]["class"] = 3               # same key, new action
    new = entries_file(tmp_path, raw, "new.json")
    servicer.writes.clear()
    res = p4rt.configure(servicer.address, new)
    # +1 port; modify 1 class + mon1 config + mon1 classify default; -1 port, -3 mon1 entries
    assert (res.added, res.modified, res.deleted) == (1, 3, 4)
    # a fresh fixture configured directly from the new file holds the same state
    fresh = P4RuntimeFixture(load_info())
    server = grpc.server(futures.ThreadPoolExecutor(max_workers=4))
    p4runtime_pb2_grpc.add_P4RuntimeServicer_to_server(fresh, server)
    port = server.add_insecure_port("127.0.0.1:0")
    server.start()
    try:
        p4rt.configure(f"127.0.0.1:{port}", new)
    finally:
        server.stop(grace=None)
    assert servicer.snapshot() == fresh.snapshot()


def test_full_table_deletes_before_inserting(servicer, tmp_path):
    info = load_info()
    for t in info.tables:
        if t.preamble.name == p4rt.TABLE_MONITORED_PORT:
            t.size = 1
    servicer._install(info)
    p4rt.configure(servicer.address, entries_file(tmp_path))
    raw = copy.deepcopy(ENTRIES)
    raw["udp_port"] = 40000
    servicer.writes.clear()
    res = p4rt.configure(servicer.address, entries_file(tmp_path, raw, "b.json"))
    assert (res.added, res.deleted) == (1, 1)
    assert [update_types(w) for w in servicer.writes] == [{p4runtime_pb2.Update.DELETE}, {p4runtime_pb2.Update.INSERT}]


# ---------------------------------------------------------------- errors
def test_more_monitors_than_slots_fails_before_any_write(servicer, tmp_path):
    raw = copy.deepcopy(ENTRIES)
    for i in range(3):
        m = copy.deepcopy(raw["monitors"][0])
        m["name"] = f"extra{i}"
        raw["monitors"].append(m)
    with pytest.raises(CivicError, match="5 monitors in the entries, the pipeline has 4 monitor slots"):
        p4rt.configure(servicer.address, entries_file(tmp_path, raw))
    assert servicer.writes == []


def test_p4info_mismatch_names_the_missing_key(servicer, tmp_path):
    info = load_info()
    for t in info.tables:
        if t.preamble.name == p4rt.mon(1, "precondition"):
            del t.match_fields[4]       # p1
    servicer._install(info)
    with pytest.raises(CivicError, match=r"CivicIngress.mon1.precondition has no key 'p1'"):
        p4rt.configure(servicer.address, entries_file(tmp_path))
    assert servicer.writes == []


def test_window_exceeding_ring_capacity_is_rejected_locally(servicer, tmp_path):
    info = load_info()
    for r in info.registers:
        if r.preamble.name.endswith(".ring"):
            r.size = 256 * 16
    servicer._install(info)
    with pytest.raises(CivicError, match=r"monitor 0 \(drain_t3\): ring length 20 exceeds the pipeline's 16 cells"):
        p4rt.configure(servicer.address, entries_file(tmp_path))
    assert servicer.writes == []


@pytest.mark.parametrize("mutate, message", [
    (lambda r: r["monitors"][0]["precondition"].update(p9=[0, 1]), "precondition.p9: unknown field"),
    (lambda r: r["monitors"][0]["classes"][0].update(slope=[-2**31, -20000]), "entries 0 and 1 overlap"),
    (lambda r: r.update(udp_port=70000), "udp_port: 70000 is outside 1..65535"),
])
def test_cli_bad_entries_one_line_exit_2(servicer, tmp_path, capsys, mutate, message):
    raw = copy.deepcopy(ENTRIES)
    mutate(raw)
    code = main(["configure", "--switch", servicer.address, "--entries", str(entries_file(tmp_path, raw))])
    err = capsys.readouterr().err
    assert code == 2
    assert err.count("\n") == 1 and message in err and "Traceback" not in err
    assert servicer.writes == []


def test_cli_unreachable_switch_one_line(tmp_path, capsys):
    import socket
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()                   # nothing listens there now
    code = main(["configure", "--switch", f"127.0.0.1:{port}", "--entries", str(entries_file(tmp_path)),
                 "--timeout", "0.5"])
    err = capsys.readouterr().err
    assert code == 2
    assert err.splitlines() == [f"civic configure: error: cannot reach switch 127.0.0.1:{port} "
                                "(no P4Runtime server answered within 0.5 s)"]


def test_rejected_write_rolls_back_and_reports_one_line(servicer, tmp_path):
    p4rt.configure(servicer.address, entries_file(tmp_path))
    before = servicer.snapshot()
    raw = copy.deepcopy(ENTRIES)
    raw["udp_port"] = 50001                                   # INSERT port, DELETE old port
    raw["monitors"][0]["classes"][2]["slope"] = [-19999, 0]   # INSERT new key, DELETE old key
    raw["monitors"][0]["classes"].append({"slope": [1, 2147483647], "level": [0, 65535], "class": 2})
    raw["monitors"][0]["window"] = 21                         # MODIFY config
    cls0 = servicer.by_name(p4rt.mon(0, "classify"))

    def hook(u):   # the fixture refuses the class entry with priority BASE-3 (the appended one)
        te = u.entity.table_entry
        if u.type == p4runtime_pb2.Update.INSERT and te.table_id == cls0 and te.priority == p4rt.PRIORITY_BASE - 3:
            return code_pb2.RESOURCE_EXHAUSTED, "no room in TCAM"
        return None

    servicer.reject_hook = hook
    servicer.writes.clear()
    with pytest.raises(CivicError) as info:
        p4rt.configure(servicer.address, entries_file(tmp_path, raw, "b.json"))
    msg = str(info.value)
    assert "\n" not in msg
    assert "rejected update" in msg and "RESOURCE_EXHAUSTED: no room in TCAM" in msg
    assert "rolled back the 2 updates already applied" in msg
    assert servicer.snapshot() == before                      # no half-updated table
    assert [len(w.updates) for w in servicer.writes[:2]] == [1, 3]   # probe, then the whole INSERT phase


def test_not_primary_refuses_to_write(servicer, tmp_path):
    servicer.primary_floor = 10
    with pytest.raises(CivicError, match="another controller is primary"):
        p4rt.configure(servicer.address, entries_file(tmp_path), election_id=3)
    assert servicer.writes == []
    res = p4rt.configure(servicer.address, entries_file(tmp_path), election_id=11)
    assert res.added == 11 and all(w.election_id.low == 11 for w in servicer.writes)


def test_pipeline_pushed_once(tmp_path):
    fx = P4RuntimeFixture(None)     # no pipeline yet
    server = grpc.server(futures.ThreadPoolExecutor(max_workers=4))
    p4runtime_pb2_grpc.add_P4RuntimeServicer_to_server(fx, server)
    port = server.add_insecure_port("127.0.0.1:0")
    server.start()
    addr = f"127.0.0.1:{port}"
    try:
        path = entries_file(tmp_path)
        with pytest.raises(CivicError, match="has no pipeline installed; pass --pipeline"):
            p4rt.configure(addr, path)
        build = tmp_path / "build"
        build.mkdir()
        (build / "civic.json").write_text('{"program": "civic.p4"}')
        (build / "civic.p4info.txtpb").write_text(FIXTURE_P4INFO.read_text())
        res = p4rt.configure(addr, path, build)
        assert res.pipeline_pushed and res.added == 11
        (req,) = fx.pipelines
        assert req.action == p4runtime_pb2.SetForwardingPipelineConfigRequest.VERIFY_AND_COMMIT
        assert req.config.p4_device_config == b'{"program": "civic.p4"}'
        assert req.config.p4info == load_info() and req.config.cookie.cookie != 0
        res = p4rt.configure(addr, path, build)       # same pipeline: not pushed again, nothing written
        assert not res.pipeline_pushed and res.writes == 0 and len(fx.pipelines) == 1
        assert main(["configure", "--switch", addr, "--entries", str(path), "--pipeline", str(tmp_path / "nope")]) == 2
    finally:
        server.stop(grace=None)


def test_cli_summary_and_read(servicer, tmp_path, capsys):
    path = entries_file(tmp_path)
    assert main(["configure", "--switch", servicer.address, "--entries", str(path)]) == 0
    out = capsys.readouterr().out
    assert "added" in out and "unchanged" in out and "11" in out
    # registers of plant 10.0.0.1 (slot 1) as the P4 program would leave them
    with servicer.lock:
        reg = lambda name: servicer.registers[servicer.by_name(name)]
        reg(p4rt.REGISTER_LAST_SEQ)[1] = 4242
        reg(p4rt.mon(0, "ptr"))[1] = 2
        reg(p4rt.mon(0, "run"))[1] = 7
        reg(p4rt.mon(0, "s0"))[1] = 600
        for i in range(20):
            reg(p4rt.mon(0, "ring"))[1 * 128 + i] = 100 + i
        reg(p4rt.REGISTER_LAST_SEQ)[9] = 5                      # another plant
    servicer.primary_floor = 100                 # another controller is primary: reading needs no session
    assert main(["configure", "--switch", servicer.address, "--read", "--plant", "10.0.0.1"]) == 0
    out = capsys.readouterr().out
    assert "4242" in out and "mon0" in out and "mon1" in out and "600" in out
    ring = " ".join(str(100 + (2 + i) % 20) for i in range(20))   # oldest first: starts at ptr
    assert ring.split()[:3] == ["102", "103", "104"]
    assert "102 103 104" in out.replace("\n", " ").replace("│", " ").replace("  ", " ")
    assert "set_class(cls=3)" in out and "slope=[-2147483648, -41000]" in out
    states = None
    with p4rt.SwitchConnection(servicer.address) as conn:
        sch, _ = p4rt.ensure_pipeline(conn, None)
        _, defaults = p4rt.read_state(conn, sch)
        states = p4rt.read_plant_state(conn, sch, p4rt.monitor_config(sch, defaults))
    assert [s.slot for s in states] == [1, 9]
    assert states[0].monitors[0]["ring"] == [100 + (2 + i) % 20 for i in range(20)]
    assert len(states[0].monitors[1]["ring"]) == 8 and states[0].monitors[2] is None
    assert main(["configure", "--switch", servicer.address, "--read", "--plant", "10.0.1.1",
                 "--entries", str(path)]) == 2
    assert "outside the plant prefix 10.0.0.0/24" in capsys.readouterr().err


# ---------------------------------------------------------------- register state on reconfiguration
def set_state(fx, k, slot=1):
    with fx.lock:
        reg = lambda name: fx.registers[fx.by_name(name)]
        reg(p4rt.mon(k, "ptr"))[slot] = 3
        reg(p4rt.mon(k, "run"))[slot] = 50
        reg(p4rt.mon(k, "s0"))[slot] = 12345
        reg(p4rt.mon(k, "s1"))[slot] = 999
        reg(p4rt.mon(k, "ring"))[slot * 128 + 2] = 777


def state_of(fx, k) -> dict:
    with fx.lock:
        return {r: {i: v for i, v in fx.registers[fx.by_name(p4rt.mon(k, r))].items() if v}
                for r in p4rt.MONITOR_REGISTERS}


def test_reconfigured_monitor_gets_registers_zeroed(servicer, tmp_path):
    p4rt.configure(servicer.address, entries_file(tmp_path))
    set_state(servicer, 0)
    set_state(servicer, 1)
    raw = copy.deepcopy(ENTRIES)
    raw["monitors"][1]["classes"].pop()           # tables only: state stays
    res = p4rt.configure(servicer.address, entries_file(tmp_path, raw, "b.json"))
    assert res.cleared == [] and state_of(servicer, 0)["s0"] == {1: 12345}
    raw["monitors"][0]["window"] = 25             # monitor 0 changes: its state is meaningless now
    res = p4rt.configure(servicer.address, entries_file(tmp_path, raw, "c.json"))
    assert res.cleared == [0] and res.modified == 1
    assert state_of(servicer, 0) == {r: {} for r in p4rt.MONITOR_REGISTERS}
    assert state_of(servicer, 1)["s0"] == {1: 12345} and state_of(servicer, 1)["ring"] == {130: 777}
    assert p4rt.configure(servicer.address, entries_file(tmp_path, raw, "c.json")).writes == 0


def test_no_register_access_reinstalls_pipeline_or_refuses(servicer, tmp_path):
    servicer.register_support = False             # like BMv2's P4Runtime server
    build = tmp_path / "build"
    build.mkdir()
    (build / "civic.json").write_text("{}")
    (build / "civic.p4info.txtpb").write_text(FIXTURE_P4INFO.read_text())
    first = p4rt.configure(servicer.address, entries_file(tmp_path), build)   # fresh: enabling needs no reset
    assert first.pipeline_pushed and len(servicer.pipelines) == 1
    raw = copy.deepcopy(ENTRIES)
    raw["monitors"][1]["estimator"] = "lsq"
    changed = entries_file(tmp_path, raw, "b.json")
    servicer.writes.clear()
    with pytest.raises(CivicError, match="monitor slot 1 changes configuration.*pass --pipeline DIR"):
        p4rt.configure(servicer.address, changed)
    assert all(u.entity.WhichOneof("entity") == "register_entry" for w in servicer.writes for u in w.updates)
    assert len(servicer.writes) == 1              # only the probe, which the fixture refused
    res = p4rt.configure(servicer.address, changed, build)
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
        tid = sch.table(p4rt.mon(k, "classify")).id
        prios = sorted((te.priority for key, te in servicer.tables.items() if key[0] == tid), reverse=True)
        assert prios == [p4rt.PRIORITY_BASE - i for i in range(n)]
    writes = len(servicer.writes)
    res = p4rt.configure(servicer.address, path)
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
    fwd = next(u.entity.table_entry for u in ins.updates if u.entity.table_entry.table_id == sch.table(p4rt.TABLE_FORWARD).id)
    assert fwd.match[0].exact.value == b"\x00\x01" and fwd.action.action.params[0].value == b"\x00\x02"
    res = p4rt.configure(servicer.address, path, padded_bytes=True)
    assert res.writes == 0                       # read-back compares values, not encodings
    raw = copy.deepcopy(ENTRIES)
    raw["monitors"][0]["window"] = 30            # register clearing with full-width zeros too
    set_state(servicer, 0)
    res = p4rt.configure(servicer.address, entries_file(tmp_path, raw, "b.json"), padded_bytes=True)
    assert res.cleared == [0] and state_of(servicer, 0) == {r: {} for r in p4rt.MONITOR_REGISTERS}


def test_pipeline_for_pi_builds_that_want_the_legacy_wrapper(tmp_path):
    fx = P4RuntimeFixture(None)
    fx.legacy_device_config = True
    server = grpc.server(futures.ThreadPoolExecutor(max_workers=4))
    p4runtime_pb2_grpc.add_P4RuntimeServicer_to_server(fx, server)
    port = server.add_insecure_port("127.0.0.1:0")
    server.start()
    try:
        build = tmp_path / "build"
        build.mkdir()
        blob = json.dumps({"program": "civic.p4", "pad": "x" * 300}).encode()    # > 127 bytes: 2-byte varint
        (build / "civic.json").write_bytes(blob)
        (build / "civic.p4info.txtpb").write_text(FIXTURE_P4INFO.read_text())
        res = p4rt.configure(f"127.0.0.1:{port}", entries_file(tmp_path), build)
        assert res.pipeline_pushed and res.added == 11
        assert [p.config.p4_device_config[:1] for p in fx.pipelines] == [b"{", b"\x08"]   # raw, then wrapped
        assert fx.device_data == blob
    finally:
        server.stop(grace=None)
