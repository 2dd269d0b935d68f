"""The P4 program's control-plane names and CIVIC's view of its P4Info (finsy's P4Schema).

Every object is looked up by name (ids and bit widths are never hard-coded); a
missing one is a one-line `CivicError` that names it.
"""
from __future__ import annotations

import ipaddress

from finsy import P4Schema
from finsy.proto import p4i, p4r
from google.protobuf import text_format

from civic.errors import CivicError

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
FLOW_TABLES = ("flow0", "flow1")
SLOPE_BIAS = 0x80000000
MAX_PLANTS = 256


def mon(k: int, name: str) -> str:
    """Name of monitor slot k's object `name` (mon0..monN-1)."""
    return f"{CONTROL}.mon{k}.{name}"


def decode_value(data: bytes) -> int:
    return int.from_bytes(data, "big") if data else 0


def slope_key(slope: int) -> int:
    """Order-preserving unsigned 32-bit key of a signed slope (docs/pipeline.md section 4)."""
    return (int(slope) & 0xFFFFFFFF) ^ SLOPE_BIAS


def _signed32(v: int) -> int:
    return v - (1 << 32) if v >= 1 << 31 else v


class SwitchSchema(P4Schema):
    """finsy's P4Schema plus the lookups CIVIC needs, each failing with a one-line CivicError.

    With `p4blob` (the BMv2 JSON) it is a whole pipeline: `get_pipeline_config()` carries
    finsy's cookie, a hash of P4Info and blob.
    """

    def __init__(self, p4info: p4i.P4Info, p4blob: bytes | None = None):
        super().__init__(p4info, p4blob)

    @classmethod
    def from_text(cls, text: str, what: str = "P4Info", p4blob: bytes | None = None) -> "SwitchSchema":
        info = p4i.P4Info()
        try:
            text_format.Merge(text, info, allow_unknown_field=True)
        except text_format.ParseError as exc:
            raise CivicError(f"{what}: not a P4Info text file: {exc}") from exc
        return cls(info, p4blob)

    def _find(self, objects, name: str, kind: str, hint: str = ""):
        found = objects.get(name)
        if found is None:
            raise CivicError(f"P4Info has no {kind} '{name}'{hint}")
        return found

    def table(self, name: str):
        return self._find(self.tables, name, "table", " (is the pipeline a CIVIC v1model build?)")

    def action(self, name: str):
        return self._find(self.actions, name, "action", " (is the pipeline a CIVIC v1model build?)")

    def register(self, name: str):
        return self._find(self.registers, name, "register")

    def counter(self, name: str):
        return self._find(self.counters, name, "counter", " (is the pipeline a CIVIC build with verdict counters?)")

    def digest(self, name: str):
        return self._find(self.digests, name, "digest", " (is the pipeline a CIVIC build with verdict digests?)")

    def key(self, table, name: str):
        """Match field `name` of a table."""
        field = table.match_fields.get(name)
        if field is None:
            have = ", ".join(m.name for m in table.match_fields) or "none"
            raise CivicError(f"P4Info table {table.name} has no key '{name}' (it has: {have})")
        return field

    def monitor_slots(self) -> int:
        """Number of monitor slots the program has: mon0.config, mon1.config, ..."""
        k = 0
        while self.tables.get(mon(k, "config")) is not None:
            k += 1
        return k

    def ring_stride(self) -> int | None:
        """Ring cells per plant slot (ring register size / 256), if mon0.ring exists."""
        reg = self.registers.get(mon(0, "ring"))
        return reg.size // MAX_PLANTS if reg is not None and reg.size else None

    def managed_tables(self) -> list[str]:
        """Tables whose entries the entries file owns."""
        names = [TABLE_FORWARD, TABLE_MONITORED_PORT, TABLE_PLANT_PREFIX]
        for k in range(self.monitor_slots()):
            names += [mon(k, "config"), mon(k, "precondition"), mon(k, "compensate"), mon(k, "classify")]
            names += [mon(k, t) for t in FLOW_TABLES if self.tables.get(mon(k, t)) is not None]
        return names

    def default_tables(self) -> list[str]:
        """Tables whose default action the control plane sets."""
        return [mon(k, t) for k in range(self.monitor_slots()) for t in ("config", "classify")]

    def describe(self, te: p4r.TableEntry) -> str:
        """One line for a table entry (for --read and error messages); slopes and offsets signed."""
        t = self.tables.get(te.table_id)
        parts = []
        for fm in te.match:
            m = t.match_fields.get(fm.field_id) if t else None
            n = m.name if m else f"field{fm.field_id}"
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
                    lo, hi, n = _signed32(lo ^ SLOPE_BIAS), _signed32(hi ^ SLOPE_BIAS), "slope"
                parts.append(f"{n}=[{lo}, {hi}]")
            else:
                parts.append(f"{n}=<{kind}>")
        if te.is_default_action:
            parts.append("(default)")
        if te.priority:
            parts.append(f"prio {te.priority}")
        tname = t.name if t else f"table 0x{te.table_id:08x}"
        return f"{tname} {' '.join(parts)} -> {self.describe_action(te)}".replace("  ", " ")

    def describe_action(self, te: p4r.TableEntry) -> str:
        if te.action.WhichOneof("type") != "action":
            return "(no action)"
        a = te.action.action
        info = self.actions.get(a.action_id)
        if info is None:
            return f"action 0x{a.action_id:08x}"

        def shown(p):
            param = info.params.get(p.param_id)
            name, v = (param.name if param else p.param_id), decode_value(p.value)
            return f"{name}={_signed32(v) if name == 'offset' else v}"
        return f"{info.name.split('.')[-1]}({', '.join(shown(p) for p in a.params)})"

    def action_params(self, te: p4r.TableEntry | None) -> dict:
        """name -> value of an entry's direct action parameters ({} for none)."""
        if te is None or te.action.WhichOneof("type") != "action":
            return {}
        info = self.actions.get(te.action.action.action_id)
        names = {p.id: p.name for p in info.params} if info else {}
        return {names.get(p.param_id, p.param_id): decode_value(p.value) for p in te.action.action.params}
