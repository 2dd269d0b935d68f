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
from pathlib import Path

import grpc
from finsy.proto import p4i as p4info_pb2
from finsy.proto import p4r as p4runtime_pb2
from finsy.proto import p4r_grpc as p4runtime_pb2_grpc
from finsy.proto import rpc_code as code_pb2
from finsy.proto import rpc_status as status_pb2
from google.protobuf import any_pb2, text_format

from civic.switch.schema import SwitchSchema

FIXTURE_P4INFO = Path(__file__).parents[1] / "fixtures" / "civic.p4info.txtpb"
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
                        r.data.bitstring = canonical_bytes(self.registers[q.register_id].get(i, 0))
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


def canonical_bytes(value: int) -> bytes:
    """Canonical P4Runtime byte string of a non-negative int."""
    return value.to_bytes(max(1, (value.bit_length() + 7) // 8), "big")


def schema() -> SwitchSchema:
    return SwitchSchema(load_info())


def update_types(req) -> set:
    return {u.type for u in req.updates}


# ---------------------------------------------------------------- encoding
def field(te, sch, name):
    t = sch.tables[te.table_id]
    fid = t.match_fields[name].id
    hits = [fm for fm in te.match if fm.field_id == fid]
    return hits[0] if hits else None


def params(te) -> list:
    return [(p.param_id, p.value) for p in te.action.action.params]
