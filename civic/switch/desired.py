"""The table entries and default actions an entries file asks for (docs/pipeline.md section 6).

finsy encodes them (canonical byte strings, ids from the P4Info); CIVIC decides
what they are: don't-care range/LPM fields omitted, priorities for range tables
(earlier entries in the file get higher priority), keyless config tables and the
class tables' miss class set as default actions.
"""
from __future__ import annotations

from dataclasses import dataclass

from finsy import P4TableAction, P4TableEntry, P4TableMatch
from finsy.proto import p4r

from civic.config import PRECONDITION_FIELDS
from civic.entries import OPERANDS, Entries
from civic.errors import CivicError
from civic.switch.schema import (ACTION_SET_EGRESS, ACTION_SET_MONITORED, ACTION_SET_PLANT, FLOW_TABLES,
                                 TABLE_FORWARD, TABLE_MONITORED_PORT, TABLE_PLANT_PREFIX, SwitchSchema, mon,
                                 slope_key)
from civic.wire import parse_prefix

SIGNAL_CODES = {"l1": 0, "l2": 1, "l3": 2, "l4": 3}
ESTIMATOR_CODES = {"endpoint": 0, "lsq": 1, "value": 2}
OPERAND_CODES = {name: i for i, name in enumerate(OPERANDS)}       # define.p4 OPERAND_*
PRIORITY_BASE = 0xFFFF       # entry i of a range table gets priority PRIORITY_BASE - i
DISABLED = dict(enabled=0, signal=0, window=0, ring_len=0, estimator=0, balance=0, hold_min=0, aux_plus=0,
                aux_minus=0, f0_plus=0, f0_minus=0, f0_cmd=0, f1_plus=0, f1_minus=0, f1_cmd=0)


@dataclass
class DesiredState:
    entries: list            # TableEntry (match entries)
    defaults: list           # TableEntry with is_default_action


class _Table:
    """Builds one table's entries with finsy; keys checked by name, don't-care fields left out."""

    def __init__(self, schema: SwitchSchema, name: str):
        self.schema, self.name = schema, name
        self.info = schema.table(name)

    def range(self, key: str, lo: int, hi: int) -> dict:
        width = self.schema.key(self.info, key).bitwidth
        if lo > hi:
            raise CivicError(f"{self.name}.{key}: empty range [{lo}, {hi}]")
        return {} if lo == 0 and hi == (1 << width) - 1 else {key: (lo, hi)}

    def entry(self, match: dict, action: str, priority: int = 0, default: bool = False,
              **params) -> p4r.TableEntry:
        for key in match:
            self.schema.key(self.info, key)
        try:
            return P4TableEntry(self.name, match=P4TableMatch(match), action=P4TableAction(action, **params),
                                priority=priority, is_default_action=default).encode_entry(self.schema)
        except ValueError as exc:
            raise CivicError(f"{self.name}: {exc}") from None


def desired_state(entries: Entries, schema: SwitchSchema) -> DesiredState:
    """Every table entry and default action the entries file asks for; validates against the P4Info."""
    slots = schema.monitor_slots()
    if slots == 0:
        raise CivicError(f"P4Info has no table '{mon(0, 'config')}' (is the pipeline a CIVIC v1model build?)")
    if len(entries.monitors) > slots:
        raise CivicError(f"{len(entries.monitors)} monitors in the entries, the pipeline has {slots} monitor slots")
    out = DesiredState([], [])

    fwd = _Table(schema, TABLE_FORWARD)
    for port_in, port_out in sorted(entries.forwarding.items()):
        out.entries.append(fwd.entry({"ingress_port": port_in}, ACTION_SET_EGRESS, port=port_out))
    out.entries.append(_Table(schema, TABLE_MONITORED_PORT).entry({"dst_port": entries.udp_port},
                                                                  ACTION_SET_MONITORED))
    net, plen = parse_prefix(entries.plant_prefix)
    out.entries.append(_Table(schema, TABLE_PLANT_PREFIX).entry({"src_addr": (net, plen)}, ACTION_SET_PLANT))

    stride = schema.ring_stride()
    for k in range(slots):
        cfg, pre, comp, cls = (_Table(schema, mon(k, t)) for t in ("config", "precondition", "compensate",
                                                                   "classify"))
        if k >= len(entries.monitors):
            out.defaults.append(cfg.entry({}, mon(k, "set_config"), default=True, **DISABLED))
            out.defaults.append(cls.entry({}, mon(k, "set_class"), default=True, cls=3))
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
        out.defaults.append(cfg.entry(
            {}, mon(k, "set_config"), default=True, enabled=1, signal=SIGNAL_CODES[m.signal], window=m.window,
            ring_len=m.ring_len, estimator=ESTIMATOR_CODES[m.estimator], balance=int(m.kind == "balance"),
            hold_min=m.hold, aux_plus=SIGNAL_CODES[m.aux_signals[0]], aux_minus=SIGNAL_CODES[m.aux_signals[1]],
            **terms))
        for t, term in enumerate(m.terms):
            flow = _Table(schema, mon(k, FLOW_TABLES[t]))
            if len(term.rows) >= PRIORITY_BASE:
                raise CivicError(f"{what}: {len(term.rows)} flow entries, at most {PRIORITY_BASE - 1}")
            for i, (hlo, hhi, clo, chi, rate, band) in enumerate(term.rows.tolist()):
                out.entries.append(flow.entry(flow.range("head", hlo, hhi) | flow.range("cmd", clo, chi),
                                              mon(k, f"set_{FLOW_TABLES[t]}"), PRIORITY_BASE - i,
                                              flow=rate & 0xFFFFFFFF, band=band))
        match = {}
        for f, (lo, hi) in zip(PRECONDITION_FIELDS, m.ranges()):
            match |= pre.range(f, lo, hi)
        out.entries.append(pre.entry(match, mon(k, "qualify"), PRIORITY_BASE))
        for i, (lo, hi, off) in enumerate(m.offsets.tolist()):
            out.entries.append(comp.entry(comp.range("aux", lo, hi), mon(k, "set_offset"), PRIORITY_BASE - i,
                                          offset=off & 0xFFFFFFFF))
        if len(m.classes) >= PRIORITY_BASE:
            raise CivicError(f"{what}: {len(m.classes)} class entries, at most {PRIORITY_BASE - 1}")
        for i, (lo, hi, llo, lhi, c) in enumerate(m.classes.tolist()):
            match = cls.range("slope_key", slope_key(lo), slope_key(hi)) | cls.range("level", llo, lhi)
            out.entries.append(cls.entry(match, mon(k, "set_class"), PRIORITY_BASE - i, cls=c))
        out.defaults.append(cls.entry({}, mon(k, "set_class"), default=True, cls=m.default_class))

    counts: dict[int, int] = {}
    for te in out.entries:
        counts[te.table_id] = counts.get(te.table_id, 0) + 1
    for tid, n in counts.items():
        t = schema.tables[tid]
        if t.size and n > t.size:
            raise CivicError(f"{n} entries for table {t.name}, which holds {t.size}")
    return out
