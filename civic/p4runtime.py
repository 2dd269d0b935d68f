"""P4Runtime control plane: install table entries (docs/pipeline.md section 6) on a switch.

Pieces, in the order `civic configure` uses them:

* `P4Schema` looks every object up **by name** in the P4Info (ids and bit
  widths are never hard-coded) and checks the names the v1model program
  exposes (see `TABLE_*` below).
* `desired_state` translates validated entries (`civic.entries.load_entries`)
  into P4Runtime `TableEntry` protos: canonical (minimal) byte strings,
  don't-care range/LPM fields omitted, priorities for range tables (earlier
  entries in the file get higher priority), keyless config tables and the
  class tables' miss class set as default actions.
* `SwitchConnection` talks to the switch with grpcio and the p4runtime protos:
  arbitration on the StreamChannel, SetForwardingPipelineConfig,
  Read, Write. `padded_bytes=True` sends full-width byte strings instead of
  canonical ones (PI builds from before 2021 accept nothing else).
* `converge` reads what is installed in the tables it manages, computes
  INSERT / MODIFY / DELETE (entries nobody asked for are deleted: the entries
  file owns these tables), validates everything first, sends one batched
  WriteRequest per phase (make-before-break when the tables have room),
  rolls back the updates already applied if the switch rejects one, zeroes
  the registers of monitors whose configuration changed (or reinstalls the
  pipeline where registers are not writable), reads back and checks the
  switch now holds exactly the desired entries.
* `read_state` / `read_plant_state` back `civic configure --read`.

Every user-facing failure is a one-line `CivicError`.
"""
from __future__ import annotations

import hashlib
import ipaddress
import queue
import threading
from dataclasses import dataclass, field
from pathlib import Path

import grpc
from google.protobuf import text_format
# P4Runtime's protos as finsy ships them, generated for current protobuf (PyPI's p4runtime stubs
# still need protobuf <= 3.20); the client below is ours
from finsy.proto import p4i as p4info_pb2
from finsy.proto import p4r as p4runtime_pb2
from finsy.proto import p4r_grpc as p4runtime_pb2_grpc
from finsy.proto import rpc_code as code_pb2
from finsy.proto import rpc_status as status_pb2

from civic.entries import Entries, load_entries
from civic.errors import CivicError
from civic.config import PRECONDITION_FIELDS
from civic.entries import OPERANDS
from civic.wire import parse_prefix

# ---------------------------------------------------------------- P4 object names (fixed contract)
CONTROL = "CivicIngress"
TABLE_FORWARD = f"{CONTROL}.forward"              # key ingress_port exact -> set_egress(port)
TABLE_MONITORED_PORT = f"{CONTROL}.monitored_port"  # key dst_port exact -> set_monitored()
TABLE_PLANT_PREFIX = f"{CONTROL}.plant_prefix"    # key src_addr lpm -> set_plant()
ACTION_SET_EGRESS = f"{CONTROL}.set_egress"
ACTION_SET_MONITORED = f"{CONTROL}.set_monitored"
ACTION_SET_PLANT = f"{CONTROL}.set_plant"
REGISTER_LAST_SEQ = f"{CONTROL}.last_seq"
MONITOR_REGISTERS = ("ring", "ptr", "run", "s0", "s1", "last_class", "acc", "accb", "ringb", "cand", "hold")
COUNTER_VERDICTS = "verdicts"       # monK.verdicts: packets per cell slot * 4 + class
DIGEST_VERDICT_CHANGE = "verdict_change_t"   # one per message on which a verdict changes
SIGNAL_CODES = {"l1": 0, "l2": 1, "l3": 2, "l4": 3}
ESTIMATOR_CODES = {"endpoint": 0, "lsq": 1, "value": 2}
OPERAND_CODES = {name: i for i, name in enumerate(OPERANDS)}       # define.p4 OPERAND_*
FLOW_TABLES = ("flow0", "flow1")
SLOPE_BIAS = 0x80000000
PRIORITY_BASE = 0xFFFF       # entry i of a range table gets priority PRIORITY_BASE - i
MAX_PLANTS = 256
PIPELINE_JSON = "civic.json"
PIPELINE_P4INFO = ("civic.p4info.txtpb", "civic.p4info.txt", "civic.p4info.txtpb.txt")


def mon(k: int, name: str) -> str:
    """Name of monitor slot k's object `name` (mon0..monN-1)."""
    return f"{CONTROL}.mon{k}.{name}"


# ---------------------------------------------------------------- byte strings
def encode_value(value: int, bitwidth: int, what: str) -> bytes:
    """Canonical P4Runtime byte string: big-endian, no leading zero bytes (0 is b'\\x00')."""
    value = int(value)
    if value < 0 or value >= (1 << bitwidth):
        raise CivicError(f"{what}: {value} does not fit in {bitwidth} bits")
    return value.to_bytes(max(1, (value.bit_length() + 7) // 8), "big")


def canonical(data: bytes) -> bytes:
    stripped = data.lstrip(b"\x00")
    return stripped if stripped else (b"\x00" if data else b"")


def decode_value(data: bytes) -> int:
    return int.from_bytes(data, "big") if data else 0


def padded(data: bytes, bitwidth: int) -> bytes:
    """Full-width form ((bitwidth + 7) // 8 bytes) of a byte string, for servers that need it."""
    n = (bitwidth + 7) // 8
    data = canonical(data)
    return data.rjust(n, b"\x00") if len(data) <= n else data


# ---------------------------------------------------------------- P4Info lookups
@dataclass
class TableInfo:
    id: int
    name: str
    keys: dict            # key name -> MatchField proto
    size: int
    action_ids: set

    def key(self, name: str) -> p4info_pb2.MatchField:
        if name not in self.keys:
            raise CivicError(f"P4Info table {self.name} has no key '{name}' "
                             f"(it has: {', '.join(self.keys) or 'none'})")
        return self.keys[name]


@dataclass
class ActionInfo:
    id: int
    name: str
    params: dict          # param name -> Action.Param proto

    def param(self, name: str) -> p4info_pb2.Action.Param:
        if name not in self.params:
            raise CivicError(f"P4Info action {self.name} has no parameter '{name}'")
        return self.params[name]


class P4Schema:
    """Name-based view of a P4Info."""

    def __init__(self, p4info: p4info_pb2.P4Info):
        self.p4info = p4info
        self.actions = {a.preamble.name: ActionInfo(a.preamble.id, a.preamble.name, {p.name: p for p in a.params})
                        for a in p4info.actions}
        self.tables = {t.preamble.name: TableInfo(t.preamble.id, t.preamble.name,
                                                  {m.name: m for m in t.match_fields}, int(t.size),
                                                  {r.id for r in t.action_refs})
                       for t in p4info.tables}
        self.registers = {r.preamble.name: r for r in p4info.registers}
        self.counters = {c.preamble.name: c for c in p4info.counters}
        self.digests = {d.preamble.name: d for d in p4info.digests}
        self.structs = {name: [m.name for m in s.members] for name, s in p4info.type_info.structs.items()}
        self.table_by_id = {t.id: t for t in self.tables.values()}
        self.action_by_id = {a.id: a for a in self.actions.values()}
        self.register_by_id = {r.preamble.id: r for r in p4info.registers}

    @classmethod
    def from_text(cls, text: str, what: str = "P4Info") -> "P4Schema":
        info = p4info_pb2.P4Info()
        try:
            text_format.Merge(text, info, allow_unknown_field=True)
        except text_format.ParseError as exc:
            raise CivicError(f"{what}: not a P4Info text file: {exc}") from exc
        return cls(info)

    def table(self, name: str) -> TableInfo:
        if name not in self.tables:
            raise CivicError(f"P4Info has no table '{name}' (is the pipeline a CIVIC v1model build?)")
        return self.tables[name]

    def action(self, name: str) -> ActionInfo:
        if name not in self.actions:
            raise CivicError(f"P4Info has no action '{name}' (is the pipeline a CIVIC v1model build?)")
        return self.actions[name]

    def register(self, name: str) -> p4info_pb2.Register:
        if name not in self.registers:
            raise CivicError(f"P4Info has no register '{name}'")
        return self.registers[name]

    def counter(self, name: str) -> p4info_pb2.Counter:
        if name not in self.counters:
            raise CivicError(f"P4Info has no counter '{name}' (is the pipeline a CIVIC build with verdict counters?)")
        return self.counters[name]

    def digest(self, name: str) -> p4info_pb2.Digest:
        if name not in self.digests:
            raise CivicError(f"P4Info has no digest '{name}' (is the pipeline a CIVIC build with verdict digests?)")
        return self.digests[name]

    def register_width(self, name: str) -> int:
        return int(self.register(name).type_spec.bitstring.bit.bitwidth)

    def monitor_slots(self) -> int:
        """Number of monitor slots the program has: mon0.config, mon1.config, ..."""
        k = 0
        while mon(k, "config") in self.tables:
            k += 1
        return k

    def ring_stride(self) -> int | None:
        """Ring cells per plant slot (ring register size / 256), if mon0.ring exists."""
        reg = self.registers.get(mon(0, "ring"))
        return int(reg.size) // MAX_PLANTS if reg is not None and reg.size else None

    def managed_tables(self) -> list[str]:
        names = [TABLE_FORWARD, TABLE_MONITORED_PORT, TABLE_PLANT_PREFIX]
        for k in range(self.monitor_slots()):
            names += [mon(k, "config"), mon(k, "precondition"), mon(k, "compensate"), mon(k, "classify")]
            names += [mon(k, t) for t in FLOW_TABLES if mon(k, t) in self.tables]
        return names

    def default_tables(self) -> list[str]:
        """Tables whose default action the control plane sets."""
        return [mon(k, t) for k in range(self.monitor_slots()) for t in ("config", "classify")]

    # -- human-readable rendering (for --read and error messages)
    def describe(self, te: p4runtime_pb2.TableEntry) -> str:
        t = self.table_by_id.get(te.table_id)
        tname = t.name if t else f"table 0x{te.table_id:08x}"
        parts = []
        names = {m.id: m.name for m in t.keys.values()} if t else {}
        for fm in te.match:
            n = names.get(fm.field_id, f"field{fm.field_id}")
            kind = fm.WhichOneof("field_match_type")
            if kind == "exact":
                parts.append(f"{n}={decode_value(fm.exact.value)}")
            elif kind == "lpm":
                v = decode_value(fm.lpm.value)
                shown = str(ipaddress.IPv4Address(v)) if v < 2**32 and n == "src_addr" else str(v)
                parts.append(f"{n}={shown}/{fm.lpm.prefix_len}")
            elif kind == "range":
                lo, hi = decode_value(fm.range.low), decode_value(fm.range.high)
                if n == "slope_key":
                    lo, hi = _unbias(lo), _unbias(hi)
                    n = "slope"
                parts.append(f"{n}=[{lo}, {hi}]")
            elif kind == "ternary":
                parts.append(f"{n}={decode_value(fm.ternary.value):#x}&&&{decode_value(fm.ternary.mask):#x}")
            else:
                parts.append(f"{n}=<{kind}>")
        if te.is_default_action:
            parts.append("(default)")
        if te.priority:
            parts.append(f"prio {te.priority}")
        return f"{tname} {' '.join(parts)} -> {self.describe_action(te)}".replace("  ", " ")

    def describe_action(self, te: p4runtime_pb2.TableEntry) -> str:
        if te.action.WhichOneof("type") != "action":
            return "(no action)"
        a = te.action.action
        info = self.action_by_id.get(a.action_id)
        if info is None:
            return f"action 0x{a.action_id:08x}"
        pnames = {p.id: p.name for p in info.params.values()}
        def shown(p):
            name, v = pnames.get(p.param_id, p.param_id), decode_value(p.value)
            return f"{name}={v - (1 << 32) if name == 'offset' and v >= 1 << 31 else v}"  # signed
        args = ", ".join(shown(p) for p in a.params)
        return f"{info.name.split('.')[-1]}({args})"


def _unbias(key: int) -> int:
    v = key ^ SLOPE_BIAS
    return v - (1 << 32) if v >= 1 << 31 else v


def slope_key(slope: int) -> int:
    """Order-preserving unsigned 32-bit key of a signed slope (docs/pipeline.md section 4)."""
    return (int(slope) & 0xFFFFFFFF) ^ SLOPE_BIAS


# ---------------------------------------------------------------- entry construction
def _exact(table: TableInfo, key: str, value: int) -> p4runtime_pb2.FieldMatch:
    mf = table.key(key)
    if mf.match_type != p4info_pb2.MatchField.EXACT:
        raise CivicError(f"P4Info table {table.name} key '{key}' is not an exact match")
    fm = p4runtime_pb2.FieldMatch(field_id=mf.id)
    fm.exact.value = encode_value(value, mf.bitwidth, f"{table.name}.{key}")
    return fm


def _range(table: TableInfo, key: str, lo: int, hi: int) -> p4runtime_pb2.FieldMatch | None:
    """A range field, or None for the full range (a don't-care field must be omitted)."""
    mf = table.key(key)
    if mf.match_type != p4info_pb2.MatchField.RANGE:
        raise CivicError(f"P4Info table {table.name} key '{key}' is not a range match")
    what = f"{table.name}.{key}"
    low, high = encode_value(lo, mf.bitwidth, what), encode_value(hi, mf.bitwidth, what)
    if lo > hi:
        raise CivicError(f"{what}: empty range [{lo}, {hi}]")
    if lo == 0 and hi == (1 << mf.bitwidth) - 1:
        return None
    fm = p4runtime_pb2.FieldMatch(field_id=mf.id)
    fm.range.low, fm.range.high = low, high
    return fm


def _lpm(table: TableInfo, key: str, value: int, prefix_len: int) -> p4runtime_pb2.FieldMatch | None:
    mf = table.key(key)
    if mf.match_type != p4info_pb2.MatchField.LPM:
        raise CivicError(f"P4Info table {table.name} key '{key}' is not an LPM match")
    if not 0 <= prefix_len <= mf.bitwidth:
        raise CivicError(f"{table.name}.{key}: prefix length {prefix_len} outside 0..{mf.bitwidth}")
    if prefix_len == 0:
        return None
    mask = ((1 << prefix_len) - 1) << (mf.bitwidth - prefix_len)
    fm = p4runtime_pb2.FieldMatch(field_id=mf.id)
    fm.lpm.value = encode_value(value & mask, mf.bitwidth, f"{table.name}.{key}")
    fm.lpm.prefix_len = prefix_len
    return fm


def _action(schema: P4Schema, table: TableInfo, name: str, **params) -> p4runtime_pb2.TableAction:
    info = schema.action(name)
    if table.action_ids and info.id not in table.action_ids:
        raise CivicError(f"P4Info: action {name} is not an action of table {table.name}")
    ta = p4runtime_pb2.TableAction()
    ta.action.action_id = info.id
    if set(params) != set(info.params):
        raise CivicError(f"P4Info action {name} has parameters ({', '.join(info.params) or 'none'}), "
                         f"civic sets ({', '.join(params) or 'none'})")
    for pname, p in sorted(info.params.items(), key=lambda kv: kv[1].id):
        ap = ta.action.params.add()
        ap.param_id = p.id
        ap.value = encode_value(params[pname], p.bitwidth, f"{name}({pname})")
    return ta


def _entry(table: TableInfo, matches, action, priority: int = 0, default: bool = False):
    te = p4runtime_pb2.TableEntry(table_id=table.id, priority=priority, is_default_action=default)
    te.match.extend(sorted((m for m in matches if m is not None), key=lambda m: m.field_id))
    te.action.CopyFrom(action)
    return te


@dataclass
class DesiredState:
    entries: list            # TableEntry (match entries)
    defaults: list           # TableEntry with is_default_action


DISABLED = dict(enabled=0, signal=0, window=0, ring_len=0, estimator=0, balance=0, hold_min=0, aux_plus=0,
                aux_minus=0, f0_plus=0, f0_minus=0, f0_cmd=0, f1_plus=0, f1_minus=0, f1_cmd=0)


def desired_state(entries: Entries, schema: P4Schema) -> DesiredState:
    """Every table entry and default action the entries file asks for; validates against the P4Info."""
    slots = schema.monitor_slots()
    if slots == 0:
        raise CivicError(f"P4Info has no table '{mon(0, 'config')}' (is the pipeline a CIVIC v1model build?)")
    if len(entries.monitors) > slots:
        raise CivicError(f"{len(entries.monitors)} monitors in the entries, the pipeline has {slots} monitor slots")
    out = DesiredState([], [])

    fwd = schema.table(TABLE_FORWARD)
    for port_in, port_out in sorted(entries.forwarding.items()):
        out.entries.append(_entry(fwd, [_exact(fwd, "ingress_port", port_in)],
                                  _action(schema, fwd, ACTION_SET_EGRESS, port=port_out)))
    mp = schema.table(TABLE_MONITORED_PORT)
    out.entries.append(_entry(mp, [_exact(mp, "dst_port", entries.udp_port)],
                              _action(schema, mp, ACTION_SET_MONITORED)))
    pp = schema.table(TABLE_PLANT_PREFIX)
    net, plen = parse_prefix(entries.plant_prefix)
    out.entries.append(_entry(pp, [_lpm(pp, "src_addr", net, plen)], _action(schema, pp, ACTION_SET_PLANT)))

    stride = schema.ring_stride()
    for k in range(slots):
        cfg, pre, comp, cls = (schema.table(mon(k, t)) for t in ("config", "precondition", "compensate", "classify"))
        if k >= len(entries.monitors):
            out.defaults.append(_entry(cfg, [], _action(schema, cfg, mon(k, "set_config"), **DISABLED),
                                       default=True))
            out.defaults.append(_entry(cls, [], _action(schema, cls, mon(k, "set_class"), cls=3), default=True))
            continue
        m = entries.monitors[k]
        what = f"monitor {k} ({m.name})"
        if stride is not None and m.ring_len > stride:
            raise CivicError(f"{what}: ring length {m.ring_len} exceeds the pipeline's {stride} cells per plant")
        if m.signal not in SIGNAL_CODES:
            raise CivicError(f"{what}: signal {m.signal!r} cannot be monitored (one of l1..l4)")
        terms = {f"f{t}_{part}": 0 for t in range(len(FLOW_TABLES)) for part in ("plus", "minus", "cmd")}
        for t, term in enumerate(m.terms):
            terms.update({f"f{t}_plus": OPERAND_CODES[term.head[0]], f"f{t}_minus": OPERAND_CODES[term.head[1]],
                          f"f{t}_cmd": OPERAND_CODES[term.command]})
        out.defaults.append(_entry(cfg, [], _action(
            schema, cfg, mon(k, "set_config"), enabled=1, signal=SIGNAL_CODES[m.signal], window=m.window,
            ring_len=m.ring_len, estimator=ESTIMATOR_CODES[m.estimator], balance=int(m.kind == "balance"),
            hold_min=m.hold, aux_plus=SIGNAL_CODES[m.aux_signals[0]],
            aux_minus=SIGNAL_CODES[m.aux_signals[1]], **terms), default=True))
        for t, term in enumerate(m.terms):
            ft = schema.table(mon(k, FLOW_TABLES[t]))
            if len(term.rows) >= PRIORITY_BASE:
                raise CivicError(f"{what}: {len(term.rows)} flow entries, at most {PRIORITY_BASE - 1}")
            for i, (hlo, hhi, clo, chi, flow, band) in enumerate(term.rows.tolist()):
                out.entries.append(_entry(ft, [_range(ft, "head", hlo, hhi), _range(ft, "cmd", clo, chi)],
                                          _action(schema, ft, mon(k, f"set_{FLOW_TABLES[t]}"),
                                                  flow=flow & 0xFFFFFFFF, band=band),
                                          priority=PRIORITY_BASE - i))
        ranges = dict(zip(PRECONDITION_FIELDS, m.ranges()))
        out.entries.append(_entry(pre, [_range(pre, f, lo, hi) for f, (lo, hi) in ranges.items()],
                                  _action(schema, pre, mon(k, "qualify")), priority=PRIORITY_BASE))
        for i, (lo, hi, off) in enumerate(m.offsets.tolist()):
            out.entries.append(_entry(comp, [_range(comp, "aux", lo, hi)],
                                      _action(schema, comp, mon(k, "set_offset"), offset=off & 0xFFFFFFFF),
                                      priority=PRIORITY_BASE - i))
        if len(m.classes) >= PRIORITY_BASE:
            raise CivicError(f"{what}: {len(m.classes)} class entries, at most {PRIORITY_BASE - 1}")
        for i, (lo, hi, llo, lhi, c) in enumerate(m.classes.tolist()):
            out.entries.append(_entry(cls, [_range(cls, "slope_key", slope_key(lo), slope_key(hi)),
                                            _range(cls, "level", llo, lhi)],
                                      _action(schema, cls, mon(k, "set_class"), cls=c),
                                      priority=PRIORITY_BASE - i))
        out.defaults.append(_entry(cls, [], _action(schema, cls, mon(k, "set_class"), cls=m.default_class),
                                   default=True))

    counts: dict[int, int] = {}
    for te in out.entries:
        counts[te.table_id] = counts.get(te.table_id, 0) + 1
    for tid, n in counts.items():
        t = schema.table_by_id[tid]
        if t.size and n > t.size:
            raise CivicError(f"{n} entries for table {t.name}, which holds {t.size}")
    return out


# ---------------------------------------------------------------- comparison keys
def match_key(te: p4runtime_pb2.TableEntry, schema: P4Schema | None = None) -> tuple:
    """Identity of an entry (table, match fields, priority); don't-care fields normalised away."""
    widths = {}
    t = schema.table_by_id.get(te.table_id) if schema else None
    if t:
        widths = {m.id: m.bitwidth for m in t.keys.values()}
    fields = []
    for fm in te.match:
        kind = fm.WhichOneof("field_match_type")
        if kind == "exact":
            v = (canonical(fm.exact.value),)
        elif kind == "lpm":
            if fm.lpm.prefix_len == 0:
                continue
            v = (canonical(fm.lpm.value), fm.lpm.prefix_len)
        elif kind == "range":
            lo, hi = decode_value(fm.range.low), decode_value(fm.range.high)
            w = widths.get(fm.field_id)
            if w and lo == 0 and hi == (1 << w) - 1:
                continue
            v = (lo, hi)
        elif kind == "ternary":
            if decode_value(fm.ternary.mask) == 0:
                continue
            v = (canonical(fm.ternary.value), canonical(fm.ternary.mask))
        elif kind == "optional":
            v = (canonical(fm.optional.value),)
        else:
            v = (fm.SerializeToString(),)
        fields.append((fm.field_id, kind) + v)
    return te.table_id, bool(te.is_default_action), tuple(sorted(fields)), int(te.priority)


def action_key(te: p4runtime_pb2.TableEntry) -> tuple:
    kind = te.action.WhichOneof("type")
    if kind is None:
        return (None,)
    if kind == "action":
        a = te.action.action
        return ("action", a.action_id, tuple(sorted((p.param_id, canonical(p.value)) for p in a.params)))
    return (kind, te.action.SerializeToString(deterministic=True))


def padded_entry(te: p4runtime_pb2.TableEntry, schema: P4Schema) -> p4runtime_pb2.TableEntry:
    """A copy of te with every byte string at full field width (old PI/BMv2 servers reject shorter)."""
    out = p4runtime_pb2.TableEntry()
    out.CopyFrom(te)
    t = schema.table_by_id.get(te.table_id)
    widths = {m.id: m.bitwidth for m in t.keys.values()} if t else {}
    for fm in out.match:
        w = widths.get(fm.field_id)
        if not w:
            continue
        kind = fm.WhichOneof("field_match_type")
        if kind == "exact":
            fm.exact.value = padded(fm.exact.value, w)
        elif kind == "lpm":
            fm.lpm.value = padded(fm.lpm.value, w)
        elif kind == "range":
            fm.range.low, fm.range.high = padded(fm.range.low, w), padded(fm.range.high, w)
        elif kind == "ternary":
            fm.ternary.value, fm.ternary.mask = padded(fm.ternary.value, w), padded(fm.ternary.mask, w)
        elif kind == "optional":
            fm.optional.value = padded(fm.optional.value, w)
    if out.action.WhichOneof("type") == "action":
        info = schema.action_by_id.get(out.action.action.action_id)
        pw = {p.id: p.bitwidth for p in info.params.values()} if info else {}
        for ap in out.action.action.params:
            if ap.param_id in pw:
                ap.value = padded(ap.value, pw[ap.param_id])
    return out


def writable_copy(te: p4runtime_pb2.TableEntry) -> p4runtime_pb2.TableEntry:
    """The parts of a read-back entry a Write may carry (no counter data, no hit times)."""
    out = p4runtime_pb2.TableEntry(table_id=te.table_id, priority=te.priority,
                                   is_default_action=te.is_default_action,
                                   controller_metadata=te.controller_metadata, metadata=te.metadata,
                                   idle_timeout_ns=te.idle_timeout_ns)
    out.match.extend(te.match)
    if te.HasField("action"):
        out.action.CopyFrom(te.action)
    return out


# ---------------------------------------------------------------- plan
INSERT, MODIFY, DELETE = (p4runtime_pb2.Update.INSERT, p4runtime_pb2.Update.MODIFY, p4runtime_pb2.Update.DELETE)
TYPE_NAMES = {INSERT: "INSERT", MODIFY: "MODIFY", DELETE: "DELETE"}


@dataclass
class Plan:
    inserts: list = field(default_factory=list)        # TableEntry
    modifies: list = field(default_factory=list)       # (new TableEntry, old TableEntry)
    deletes: list = field(default_factory=list)        # TableEntry (as read)
    unchanged: int = 0

    @property
    def empty(self) -> bool:
        return not (self.inserts or self.modifies or self.deletes)

    def phases(self, schema: P4Schema, current_counts: dict) -> list[tuple[int, list]]:
        """(update type, [(update entry, inverse update or None)]) in write order.

        Make before break (INSERT, MODIFY, DELETE) when every table has room for
        the new entries next to the old ones, else DELETE first.
        """
        ins = [(te, (DELETE, te)) for te in self.inserts]
        mod = [(new, (MODIFY, old)) for new, old in self.modifies]
        dele = [(te, (INSERT, te)) for te in self.deletes]
        grow: dict[int, int] = dict(current_counts)
        for te in self.inserts:
            grow[te.table_id] = grow.get(te.table_id, 0) + 1
        roomy = all(not schema.table_by_id[t].size or n <= schema.table_by_id[t].size
                    for t, n in grow.items() if t in schema.table_by_id)
        order = [(INSERT, ins), (MODIFY, mod), (DELETE, dele)] if roomy else \
            [(DELETE, dele), (MODIFY, mod), (INSERT, ins)]
        return [(t, items) for t, items in order if items]


def make_plan(desired: DesiredState, current: list, current_defaults: list, schema: P4Schema) -> Plan:
    plan = Plan()
    have = {match_key(te, schema): te for te in current}
    want = {}
    for te in desired.entries:
        k = match_key(te, schema)
        if k in want:
            raise CivicError(f"two entries with the same key: {schema.describe(te)}")
        want[k] = te
    for k, te in want.items():
        old = have.get(k)
        if old is None:
            plan.inserts.append(te)
        elif action_key(old) != action_key(te):
            plan.modifies.append((te, writable_copy(old)))
        else:
            plan.unchanged += 1
    plan.deletes = [writable_copy(te) for k, te in have.items() if k not in want]
    have_def = {te.table_id: te for te in current_defaults}
    for te in desired.defaults:
        old = have_def.get(te.table_id)
        if old is not None and action_key(old) == action_key(te):
            plan.unchanged += 1
        else:
            plan.modifies.append((te, writable_copy(old) if old is not None else None))
    return plan


# ---------------------------------------------------------------- connection
def _varint(n: int) -> bytes:
    out = bytearray()
    while True:
        b = n & 0x7F
        n >>= 7
        out.append(b | (0x80 if n else 0))
        if not n:
            return bytes(out)


def legacy_device_config(device_data: bytes) -> bytes:
    """p4.tmp.P4DeviceConfig{reassign: true, device_data} serialized (PI's proto/p4/tmp/p4config.proto:
    bool reassign = 1; Extras extras = 2; bytes device_data = 3), for PI builds that require it."""
    return b"\x08\x01" + b"\x1a" + _varint(len(device_data)) + device_data


class WriteRejected(Exception):
    """A Write the switch refused: per-update (index, code name, message) for failed updates."""

    def __init__(self, failed: list, applied: list, summary: str):
        super().__init__(summary)
        self.failed = failed      # [(index, code name, message)]
        self.applied = applied    # indices of updates the switch applied
        self.summary = summary


def _parse_write_error(err: grpc.RpcError, n: int) -> WriteRejected:
    failed, applied = [], []
    details = None
    for key, value in (err.trailing_metadata() or ()):
        if key == "grpc-status-details-bin":
            st = status_pb2.Status()
            st.ParseFromString(value)
            details = st.details
    if details is not None and len(details) == n:
        for i, anyv in enumerate(details):
            e = p4runtime_pb2.Error()
            anyv.Unpack(e)
            if e.canonical_code == code_pb2.OK:
                applied.append(i)
            else:
                failed.append((i, code_pb2.Code.Name(e.canonical_code), e.message))
        return WriteRejected(failed, applied, err.details() or "")
    # no per-update detail: the whole batch failed (nothing applied)
    return WriteRejected([(None, err.code().name, err.details() or "")], [], err.details() or "")


class Unsupported(CivicError):
    """The switch does not implement this P4Runtime operation (e.g. registers on BMv2)."""


class SwitchConnection:
    """One P4Runtime session (grpcio, p4.v1 protos): arbitration, pipeline, Read, Write."""

    def __init__(self, address: str, device_id: int = 0, election_id: int = 1, timeout: float = 5.0,
                 padded_bytes: bool = False, arbitrate: bool = True):
        self.address = address
        self.arbitrate = arbitrate         # False: read-only session, no StreamChannel (Read needs none)
        self.padded_bytes = padded_bytes   # send full-width byte strings instead of canonical ones
        self.device_id = device_id
        self.election_id = election_id
        self.timeout = timeout
        self.channel = None
        self.stub = None
        self.primary = False
        self._requests: queue.Queue = queue.Queue()
        self._responses: queue.Queue = queue.Queue()
        self._stream = None
        self._reader = None

    # -- session
    def __enter__(self) -> "SwitchConnection":
        self.connect()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _election(self, msg) -> None:
        msg.election_id.high = (self.election_id >> 64) & 0xFFFFFFFFFFFFFFFF
        msg.election_id.low = self.election_id & 0xFFFFFFFFFFFFFFFF

    def connect(self) -> None:
        self.channel = grpc.insecure_channel(self.address)
        self.stub = p4runtime_pb2_grpc.P4RuntimeStub(self.channel)
        try:   # any answer, even UNIMPLEMENTED, means a server is there
            self.stub.Capabilities(p4runtime_pb2.CapabilitiesRequest(), timeout=self.timeout, wait_for_ready=True)
        except grpc.RpcError as exc:
            if exc.code() in (grpc.StatusCode.DEADLINE_EXCEEDED, grpc.StatusCode.UNAVAILABLE):
                self.close()
                raise CivicError(f"cannot reach switch {self.address} (no P4Runtime server answered "
                                 f"within {self.timeout:g} s)") from None
        if not self.arbitrate:
            return

        def requests():
            while True:
                item = self._requests.get()
                if item is None:
                    return
                yield item

        self._stream = self.stub.StreamChannel(requests())

        def reader():
            try:
                for msg in self._stream:
                    self._responses.put(msg)
            except grpc.RpcError as exc:
                self._responses.put(exc)
            self._responses.put(None)

        self._reader = threading.Thread(target=reader, name="p4rt-stream", daemon=True)
        self._reader.start()
        req = p4runtime_pb2.StreamMessageRequest()
        req.arbitration.device_id = self.device_id
        self._election(req.arbitration)
        self._requests.put(req)
        while True:
            try:
                msg = self._responses.get(timeout=self.timeout)
            except queue.Empty:
                self.close()
                raise CivicError(f"switch {self.address}: no arbitration answer within {self.timeout:g} s") from None
            if isinstance(msg, grpc.RpcError):
                self.close()
                raise self._rpc_error("arbitration", msg)
            if msg is None:
                self.close()
                raise CivicError(f"switch {self.address}: stream closed during arbitration")
            if msg.HasField("arbitration"):
                self.primary = msg.arbitration.status.code == code_pb2.OK
                return

    def close(self) -> None:
        if self._stream is not None:
            self._requests.put(None)
            self._stream.cancel()
            self._stream = None
        if self._reader is not None:
            self._reader.join(timeout=2)
            self._reader = None
        if self.channel is not None:
            self.channel.close()
            self.channel = None

    # -- stream (digests, arbitration updates)
    def next_stream_message(self, timeout: float):
        """The next StreamChannel message (digest lists, arbitration updates), None after `timeout`
        s of silence. Arbitration updates also update `primary`. A closed stream is a CivicError."""
        try:
            msg = self._responses.get(timeout=timeout)
        except queue.Empty:
            return None
        if isinstance(msg, grpc.RpcError):
            raise self._rpc_error("stream", msg)
        if msg is None:
            self._responses.put(None)           # stays closed for every later call
            raise CivicError(f"switch {self.address}: the P4Runtime stream closed")
        if msg.HasField("arbitration"):
            self.primary = msg.arbitration.status.code == code_pb2.OK
        return msg

    def ack_digest(self, digest_list) -> None:
        req = p4runtime_pb2.StreamMessageRequest()
        req.digest_ack.digest_id = digest_list.digest_id
        req.digest_ack.list_id = digest_list.list_id
        self._requests.put(req)

    def require_primary(self) -> None:
        if not self.arbitrate:
            raise CivicError("internal: a read-only session cannot write")
        if not self.primary:
            raise CivicError(f"switch {self.address} device {self.device_id}: another controller is primary "
                             f"(election id above {self.election_id}); pass a higher --election-id")

    def _rpc_error(self, what: str, exc: grpc.RpcError) -> CivicError:
        code = exc.code() if hasattr(exc, "code") else None
        if code in (grpc.StatusCode.UNAVAILABLE, grpc.StatusCode.DEADLINE_EXCEEDED):
            return CivicError(f"cannot reach switch {self.address} ({what}: {code.name})")
        name = code.name if code else "error"
        detail = (exc.details() or "").strip().splitlines()
        return CivicError(f"switch {self.address}: {what} failed: {name}: {detail[0] if detail else ''}".rstrip(": "))

    # -- pipeline
    def get_pipeline(self, response_type=p4runtime_pb2.GetForwardingPipelineConfigRequest.P4INFO_AND_COOKIE):
        req = p4runtime_pb2.GetForwardingPipelineConfigRequest(device_id=self.device_id, response_type=response_type)
        try:
            return self.stub.GetForwardingPipelineConfig(req, timeout=self.timeout).config
        except grpc.RpcError as exc:
            if exc.code() == grpc.StatusCode.FAILED_PRECONDITION:
                return None  # no pipeline installed
            raise self._rpc_error("GetForwardingPipelineConfig", exc) from None

    def set_pipeline(self, p4info: p4info_pb2.P4Info, device_config: bytes, cookie: int) -> None:
        """VERIFY_AND_COMMIT. The BMv2 JSON goes as is; PI builds that only take the deprecated
        p4.tmp.P4DeviceConfig wrapper say so (INVALID_ARGUMENT) and get it on a second try."""
        self.require_primary()
        req = p4runtime_pb2.SetForwardingPipelineConfigRequest(
            device_id=self.device_id,
            action=p4runtime_pb2.SetForwardingPipelineConfigRequest.VERIFY_AND_COMMIT)
        self._election(req)
        req.config.p4info.CopyFrom(p4info)
        req.config.p4_device_config = device_config
        req.config.cookie.cookie = cookie
        try:
            self.stub.SetForwardingPipelineConfig(req, timeout=max(self.timeout, 30.0))
            return
        except grpc.RpcError as exc:
            legacy = exc.code() == grpc.StatusCode.INVALID_ARGUMENT and "P4DeviceConfig" in (exc.details() or "")
            if not legacy:
                raise self._rpc_error("SetForwardingPipelineConfig", exc) from None
        req.config.p4_device_config = legacy_device_config(device_config)
        try:
            self.stub.SetForwardingPipelineConfig(req, timeout=max(self.timeout, 30.0))
        except grpc.RpcError as exc:
            raise self._rpc_error("SetForwardingPipelineConfig", exc) from None

    # -- read / write
    def read(self, entities: list) -> list:
        req = p4runtime_pb2.ReadRequest(device_id=self.device_id)
        req.entities.extend(entities)
        out = []
        try:
            for resp in self.stub.Read(req, timeout=max(self.timeout, 30.0)):
                out.extend(resp.entities)
        except grpc.RpcError as exc:
            if exc.code() == grpc.StatusCode.UNIMPLEMENTED:
                raise Unsupported(f"switch {self.address} does not implement this Read: "
                                  f"{(exc.details() or '').strip()}") from None
            raise self._rpc_error("Read", exc) from None
        return out

    def write(self, updates: list) -> None:
        """One WriteRequest; raises WriteRejected with the per-update outcome."""
        req = p4runtime_pb2.WriteRequest(device_id=self.device_id)
        self._election(req)
        req.updates.extend(updates)
        try:
            self.stub.Write(req, timeout=max(self.timeout, 30.0))
        except grpc.RpcError as exc:
            if exc.code() in (grpc.StatusCode.UNAVAILABLE, grpc.StatusCode.DEADLINE_EXCEEDED):
                raise self._rpc_error("Write", exc) from None
            raise _parse_write_error(exc, len(updates)) from None


# ---------------------------------------------------------------- pipeline files
@dataclass
class Pipeline:
    p4info: p4info_pb2.P4Info
    device_config: bytes
    cookie: int


def load_pipeline(directory: str | Path) -> Pipeline:
    """civic.json + civic.p4info.txtpb from a p4c-bm2-ss build directory."""
    d = Path(directory)
    if not d.is_dir():
        raise CivicError(f"pipeline directory {d} does not exist (build it with p4c-bm2-ss)")
    js = d / PIPELINE_JSON
    info_path = next((d / n for n in PIPELINE_P4INFO if (d / n).is_file()), None)
    if not js.is_file():
        raise CivicError(f"{d}: no {PIPELINE_JSON} (BMv2 JSON from p4c-bm2-ss)")
    if info_path is None:
        raise CivicError(f"{d}: no {PIPELINE_P4INFO[0]} (P4Info from p4c-bm2-ss --p4runtime-files)")
    config = js.read_bytes()
    info_text = info_path.read_text()
    schema = P4Schema.from_text(info_text, str(info_path))
    digest = hashlib.sha256(config + b"\0" + schema.p4info.SerializeToString(deterministic=True)).digest()
    return Pipeline(schema.p4info, config, int.from_bytes(digest[:8], "big") or 1)


def ensure_pipeline(conn: SwitchConnection, pipeline_dir: str | Path | None) -> tuple[P4Schema, bool]:
    """Install the pipeline unless the switch already runs it (same cookie); return (schema, pushed)."""
    if pipeline_dir is not None:
        pipe = load_pipeline(pipeline_dir)
        cur = conn.get_pipeline(p4runtime_pb2.GetForwardingPipelineConfigRequest.COOKIE_ONLY)
        if cur is not None and cur.HasField("cookie") and cur.cookie.cookie == pipe.cookie:
            return P4Schema(pipe.p4info), False
        conn.set_pipeline(pipe.p4info, pipe.device_config, pipe.cookie)
        return P4Schema(pipe.p4info), True
    cur = conn.get_pipeline()
    if cur is None or not (cur.p4info.tables or cur.p4info.actions or cur.p4info.HasField("pkg_info")):
        raise CivicError(f"switch {conn.address} has no pipeline installed; pass --pipeline build/v1model")
    return P4Schema(cur.p4info), False


# ---------------------------------------------------------------- converge
@dataclass
class ConvergeResult:
    added: int = 0
    modified: int = 0
    deleted: int = 0
    unchanged: int = 0
    pipeline_pushed: bool = False
    writes: int = 0           # WriteRequests sent
    cleared: list = field(default_factory=list)   # monitor slots whose registers were zeroed


def read_state(conn: SwitchConnection, schema: P4Schema) -> tuple[list, list]:
    """(match entries, default entries) of every table the control plane manages."""
    ents = []
    for name in schema.managed_tables():
        e = p4runtime_pb2.Entity()
        e.table_entry.table_id = schema.table(name).id
        ents.append(e)
    for name in schema.default_tables():
        e = p4runtime_pb2.Entity()
        e.table_entry.table_id = schema.table(name).id
        e.table_entry.is_default_action = True
        ents.append(e)
    entries, defaults = [], []
    for ent in conn.read(ents):
        if ent.WhichOneof("entity") != "table_entry":
            continue
        (defaults if ent.table_entry.is_default_action else entries).append(ent.table_entry)
    return entries, defaults


def _update(kind: int, te, schema: P4Schema | None = None) -> p4runtime_pb2.Update:
    u = p4runtime_pb2.Update(type=kind)
    u.entity.table_entry.CopyFrom(padded_entry(te, schema) if schema is not None else te)
    if kind == MODIFY and te.is_default_action and not te.HasField("action"):
        u.entity.table_entry.ClearField("action")  # reset to the P4 program's default
    return u


def _config_params(schema: P4Schema, te) -> dict:
    if te is None or te.action.WhichOneof("type") != "action":
        return {}
    info = schema.action_by_id.get(te.action.action.action_id)
    names = {p.id: p.name for p in info.params.values()} if info else {}
    return {names.get(p.param_id, p.param_id): decode_value(p.value) for p in te.action.action.params}


def changed_monitors(schema: P4Schema, desired: DesiredState, current_defaults: list) -> list[tuple[int, dict, dict]]:
    """(slot, old config params, new config params) of every monitor slot whose config action changes."""
    have = {te.table_id: te for te in current_defaults}
    out = []
    for te in desired.defaults:
        name = schema.table_by_id[te.table_id].name
        if not name.endswith(".config"):
            continue
        k = int(name.split(".")[-2].removeprefix("mon"))
        old = have.get(te.table_id)
        if old is None or action_key(old) != action_key(te):
            out.append((k, _config_params(schema, old), _config_params(schema, te)))
    return sorted(out, key=lambda c: c[0])


def clear_updates(schema: P4Schema, k: int, ring_cells: int, slots=range(MAX_PLANTS), only=None,
                  full_width: bool = False) -> list:
    """MODIFY updates writing 0 into monitor slot k's registers: ptr, run, s0, s1 of every plant
    slot and the first `ring_cells` ring cells of every plant slot (cell = slot * stride + i)."""
    stride = schema.ring_stride() or 0
    ups = []
    for r in (only or MONITOR_REGISTERS):
        reg = schema.registers.get(mon(k, r))
        if reg is None:
            continue
        if r in ("ring", "ringb"):
            cells = [s * stride + i for s in slots for i in range(min(ring_cells, stride))]
        else:
            cells = list(slots)
        zero = padded(b"\x00", int(reg.type_spec.bitstring.bit.bitwidth)) if full_width else b"\x00"
        for i in cells:
            u = p4runtime_pb2.Update(type=MODIFY)
            u.entity.register_entry.register_id = reg.preamble.id
            u.entity.register_entry.index.index = i
            u.entity.register_entry.data.bitstring = zero
            ups.append(u)
    return ups


def registers_writable(conn: SwitchConnection, schema: P4Schema, k: int) -> bool:
    """Probe: zero monitor k's run counter of slot 0 (harmless: k's state is about to be cleared).

    BMv2's P4Runtime server does not implement register access (p4lang/PI#376).
    """
    if mon(k, "run") not in schema.registers:
        return False
    try:
        conn.write(clear_updates(schema, k, 0, slots=[0], only=["run"], full_width=conn.padded_bytes))
        return True
    except WriteRejected:
        return False


def converge(conn: SwitchConnection, entries: Entries, schema: P4Schema,
             pipeline: Pipeline | None = None) -> ConvergeResult:
    """Make the switch hold exactly the entries' tables; one WriteRequest per phase.

    An enabled monitor whose configuration (signal, window, estimator) changes,
    or that is disabled, gets its registers zeroed after the tables are
    written: its ring and running sums only make sense for the configuration
    that filled them. When the switch cannot write registers over P4Runtime
    (BMv2, p4lang/PI#376) the pipeline is reinstalled instead, which zeroes
    all state; that needs `pipeline`.
    """
    desired = desired_state(entries, schema)          # validates before anything is written
    conn.require_primary()
    current, current_defaults = read_state(conn, schema)
    # a slot that was enabled and changes keeps state that is wrong for the new configuration;
    # a disabled slot's registers are always zero (fresh pipeline, or zeroed when it was changed)
    # (cells with index >= the current ring length are always zero: each change clears up to the larger one)
    stale = {k: max(old.get("ring_len", 0), new.get("ring_len", 0))
             for k, old, new in changed_monitors(schema, desired, current_defaults) if old.get("enabled")}
    clear = {}
    reinstall = False
    if stale:
        if registers_writable(conn, schema, min(stale)):
            clear = stale
        elif pipeline is not None:
            reinstall = True
        else:
            raise CivicError(f"monitor slot {', '.join(map(str, sorted(stale)))} changes configuration, so its registers "
                             f"must be zeroed, and switch {conn.address} cannot write registers over P4Runtime; "
                             "pass --pipeline DIR to reinstall the pipeline (this clears every plant's state)")
    pushed = False
    if reinstall:
        conn.set_pipeline(pipeline.p4info, pipeline.device_config, pipeline.cookie)
        pushed = True
        current, current_defaults = read_state(conn, schema)
    plan = make_plan(desired, current, current_defaults, schema)
    result = ConvergeResult(added=len(plan.inserts), modified=len(plan.modifies),
                            deleted=len(plan.deletes), unchanged=plan.unchanged, pipeline_pushed=pushed)
    counts: dict[int, int] = {}
    for te in current:
        counts[te.table_id] = counts.get(te.table_id, 0) + 1
    done: list = []          # inverse updates of everything applied so far, in order
    for kind, items in plan.phases(schema, counts):
        pad = schema if conn.padded_bytes else None
        updates = [_update(kind, te, pad) for te, _ in items]
        try:
            conn.write(updates)
            result.writes += 1
        except WriteRejected as rej:
            result.writes += 1
            done += [items[i][1] for i in rej.applied]
            rollback = _rollback(conn, done, pad)
            i, code, msg = rej.failed[0]
            where = f"update {i} ({TYPE_NAMES[kind]} {schema.describe(items[i][0])})" if i is not None else \
                f"{TYPE_NAMES[kind]} batch"
            more = f" and {len(rej.failed) - 1} more" if len(rej.failed) > 1 else ""
            raise CivicError(f"switch {conn.address} rejected {where}: {code}: {msg}{more}; {rollback}") from None
        done += [inv for _, inv in items]
    for k, cells in sorted(clear.items()):
        try:
            conn.write(clear_updates(schema, k, cells, full_width=conn.padded_bytes))
            result.writes += 1
        except WriteRejected as rej:
            i, code, msg = rej.failed[0]
            raise CivicError(f"switch {conn.address}: tables updated, but zeroing monitor slot {k}'s registers "
                             f"failed: {code}: {msg}") from None
        result.cleared.append(k)
    after, after_defaults = read_state(conn, schema)
    check = make_plan(desired, after, after_defaults, schema)
    if not check.empty:
        bad = (check.inserts or [m[0] for m in check.modifies] or check.deletes)[0]
        n = len(check.inserts) + len(check.modifies) + len(check.deletes)
        raise CivicError(f"switch {conn.address}: read-back differs from what was written in {n} entries, "
                         f"e.g. {schema.describe(bad)}")
    return result


def _rollback(conn: SwitchConnection, done: list, pad: P4Schema | None = None) -> str:
    """Undo applied updates (newest first); return a phrase for the error message."""
    if not done:
        return "nothing was changed"
    undo = [_update(kind, te, pad) for kind, te in reversed(done) if te is not None]
    try:
        for u in undo:       # one at a time: a failure must not hide the others
            conn.write([u])
    except (WriteRejected, CivicError) as exc:
        return f"rolling back {len(done)} applied updates failed too ({exc}); the switch is half-updated"
    return f"rolled back the {len(done)} updates already applied"


# ---------------------------------------------------------------- registers
def read_register(conn: SwitchConnection, schema: P4Schema, name: str, indices=None) -> dict[int, int]:
    """index -> value of a register (all cells, or the given indices, in one Read)."""
    reg = schema.register(name)
    ents = []
    for idx in ([None] if indices is None else indices):
        e = p4runtime_pb2.Entity()
        e.register_entry.register_id = reg.preamble.id
        if idx is not None:
            e.register_entry.index.index = int(idx)
        ents.append(e)
    out = {}
    for ent in conn.read(ents):
        if ent.WhichOneof("entity") == "register_entry":
            r = ent.register_entry
            out[int(r.index.index)] = decode_value(r.data.bitstring)
    return out


@dataclass
class PlantState:
    slot: int
    last_seq: int
    monitors: list          # per slot k: dict ptr, run, s0, s1, ring (oldest first)


def read_plant_state(conn: SwitchConnection, schema: P4Schema, config: list, slots=None) -> list[PlantState]:
    """Registers of the given plant slots (default: every slot with a message seen).

    `config` is the per monitor slot (enabled, ring_len) read from the config tables.
    The ring register is indexed slot * stride + i with stride = ring size / 256.
    """
    last = read_register(conn, schema, REGISTER_LAST_SEQ, slots)
    if slots is None:
        slots = sorted(s for s, v in last.items() if v)
        # a plant whose last seq happens to be 0 still counts if a ring pointer moved
        for k, (enabled, _) in enumerate(config):
            if enabled:
                ptrs = read_register(conn, schema, mon(k, "ptr"))
                slots = sorted(set(slots) | {s for s, v in ptrs.items() if v})
    stride = schema.ring_stride() or 0
    states = []
    for s in slots:
        mons = []
        for k, (enabled, ring_len) in enumerate(config):
            if not enabled:
                mons.append(None)
                continue
            vals = {r: read_register(conn, schema, mon(k, r), [s]).get(s, 0) for r in ("ptr", "run", "s0", "s1")}
            ring = read_register(conn, schema, mon(k, "ring"), [s * stride + i for i in range(ring_len)])
            cells = [ring.get(s * stride + i, 0) for i in range(ring_len)]
            p = vals["ptr"] if vals["ptr"] < max(ring_len, 1) else 0
            vals["ring"] = cells[p:] + cells[:p]
            mons.append(vals)
        states.append(PlantState(s, last.get(s, 0), mons))
    return states


def monitor_config(schema: P4Schema, defaults: list) -> list[tuple[int, int]]:
    """(enabled, ring_len) per monitor slot from the read-back config default actions."""
    by_table = {te.table_id: te for te in defaults}
    out = []
    for k in range(schema.monitor_slots()):
        te = by_table.get(schema.table(mon(k, "config")).id)
        vals = {}
        if te is not None and te.action.WhichOneof("type") == "action":
            info = schema.action_by_id.get(te.action.action.action_id)
            names = {p.id: p.name for p in info.params.values()} if info else {}
            vals = {names.get(p.param_id): decode_value(p.value) for p in te.action.action.params}
        out.append((vals.get("enabled", 0), vals.get("ring_len", 0)))
    return out


def plant_slot(ip: str, prefix: str | None = None) -> int:
    try:
        addr = ipaddress.IPv4Address(ip)
    except ValueError:
        raise CivicError(f"--plant: not an IPv4 address: {ip!r}") from None
    if prefix is not None and addr not in ipaddress.IPv4Network(prefix):
        raise CivicError(f"--plant {ip} is outside the plant prefix {prefix}")
    return int(addr) & 0xFF


# ---------------------------------------------------------------- top level
def configure(address: str, entries_path: str | Path, pipeline_dir: str | Path | None = None,
              device_id: int = 0, election_id: int = 1, timeout: float = 5.0,
              padded_bytes: bool = False) -> ConvergeResult:
    """Validate the entries file, connect, (install the pipeline,) converge. Used by `civic configure`."""
    entries = load_entries(entries_path)
    if pipeline_dir is not None:     # validate against the P4Info before touching the switch
        desired_state(entries, P4Schema(load_pipeline(pipeline_dir).p4info))
    with SwitchConnection(address, device_id, election_id, timeout, padded_bytes) as conn:
        conn.require_primary()
        schema, pushed = ensure_pipeline(conn, pipeline_dir)
        pipeline = load_pipeline(pipeline_dir) if pipeline_dir is not None else None
        result = converge(conn, entries, schema, pipeline)
        result.pipeline_pushed = result.pipeline_pushed or pushed
        return result


# ---------------------------------------------------------------- verdict digests and counters
def enable_digest(conn: SwitchConnection, schema: P4Schema, max_timeout_ns: int = 1_000_000,
                  max_list_size: int = 64, ack_timeout_ns: int = 1_000_000_000) -> int:
    """Ask the switch to send the verdict-change digest (INSERT, or MODIFY if configured); its id."""
    digest_id = schema.digest(DIGEST_VERDICT_CHANGE).preamble.id
    entry = p4runtime_pb2.DigestEntry(digest_id=digest_id)
    entry.config.max_timeout_ns = max_timeout_ns
    entry.config.max_list_size = max_list_size
    entry.config.ack_timeout_ns = ack_timeout_ns
    for kind in (INSERT, MODIFY):
        u = p4runtime_pb2.Update(type=kind)
        u.entity.digest_entry.CopyFrom(entry)
        try:
            conn.write([u])
            return digest_id
        except WriteRejected as exc:
            if kind == MODIFY:
                raise CivicError(f"switch {conn.address}: cannot enable the verdict digest: {exc.summary}") from None
    return digest_id


def digest_members(digest_list, schema: P4Schema) -> list[dict[str, int]]:
    """The verdict_change_t structs of one DigestList, as {member: value}."""
    names = schema.structs.get(DIGEST_VERDICT_CHANGE)
    if not names:
        raise CivicError(f"P4Info has no type for digest '{DIGEST_VERDICT_CHANGE}'")
    out = []
    for data in digest_list.data:
        values = [decode_value(m.bitstring) for m in data.struct.members]
        if len(values) != len(names):
            raise CivicError(f"digest with {len(values)} members, P4Info says {len(names)}")
        out.append(dict(zip(names, values)))
    return out


def read_counter(conn: SwitchConnection, schema: P4Schema, name: str) -> dict[int, int]:
    """Packet count of every cell of a counter."""
    ent = p4runtime_pb2.Entity()
    ent.counter_entry.counter_id = schema.counter(name).preamble.id
    return {int(e.counter_entry.index.index): int(e.counter_entry.data.packet_count)
            for e in conn.read([ent])}
