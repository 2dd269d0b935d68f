"""Converge a switch to an entries file: diff desired vs read-back, write, roll back, verify.

`converge` reads what is installed in the tables the entries file owns, computes
INSERT / MODIFY / DELETE (entries nobody asked for are deleted), validates
everything first, sends one batched WriteRequest per phase (make-before-break
when the tables have room), rolls back the updates already applied if the
switch rejects one, zeroes the registers of monitors whose configuration changed
(or reinstalls the pipeline where registers are not writable), reads back and
checks the switch now holds exactly the desired entries.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from finsy import P4RegisterEntry, P4TableEntry
from finsy.proto import p4r

from civic.entries import Entries, load_entries
from civic.errors import CivicError
from civic.switch.connection import SwitchConnection, WriteRejected
from civic.switch.desired import DesiredState, desired_state
from civic.switch.pipeline import ensure_pipeline, load_pipeline
from civic.switch.schema import MAX_PLANTS, MONITOR_REGISTERS, SwitchSchema, decode_value, mon

INSERT, MODIFY, DELETE = p4r.Update.INSERT, p4r.Update.MODIFY, p4r.Update.DELETE
TYPE_NAMES = {INSERT: "INSERT", MODIFY: "MODIFY", DELETE: "DELETE"}


# ---------------------------------------------------------------- comparing and encoding entries
def canonical(data: bytes) -> bytes:
    stripped = data.lstrip(b"\x00")
    return stripped if stripped else (b"\x00" if data else b"")


def padded(data: bytes, bitwidth: int) -> bytes:
    """Full-width form ((bitwidth + 7) // 8 bytes) of a byte string, for servers that need it."""
    return canonical(data).rjust((bitwidth + 7) // 8, b"\x00")


def match_key(te: p4r.TableEntry, schema: SwitchSchema) -> tuple:
    """Identity of an entry (table, match fields, priority) by value; don't-care fields normalised away."""
    t = schema.tables.get(te.table_id)
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
            m = t.match_fields.get(fm.field_id) if t else None
            if m and lo == 0 and hi == (1 << m.bitwidth) - 1:
                continue
            v = (lo, hi)
        else:
            v = (fm.SerializeToString(),)
        fields.append((fm.field_id, kind) + v)
    return te.table_id, bool(te.is_default_action), tuple(sorted(fields)), int(te.priority)


def action_key(te: p4r.TableEntry) -> tuple:
    kind = te.action.WhichOneof("type")
    if kind == "action":
        a = te.action.action
        return ("action", a.action_id, tuple(sorted((p.param_id, canonical(p.value)) for p in a.params)))
    return (kind, te.action.SerializeToString(deterministic=True) if kind else None)


def padded_entry(te: p4r.TableEntry, schema: SwitchSchema) -> p4r.TableEntry:
    """A copy of te with every byte string at full field width (old PI/BMv2 servers reject shorter)."""
    out = p4r.TableEntry()
    out.CopyFrom(te)
    t = schema.tables[te.table_id]
    for fm in out.match:
        w = t.match_fields[fm.field_id].bitwidth
        kind = fm.WhichOneof("field_match_type")
        if kind == "exact":
            fm.exact.value = padded(fm.exact.value, w)
        elif kind == "lpm":
            fm.lpm.value = padded(fm.lpm.value, w)
        elif kind == "range":
            fm.range.low, fm.range.high = padded(fm.range.low, w), padded(fm.range.high, w)
    if out.action.WhichOneof("type") == "action":
        params = schema.actions[out.action.action.action_id].params
        for ap in out.action.action.params:
            ap.value = padded(ap.value, params[ap.param_id].bitwidth)
    return out


def writable_copy(te: p4r.TableEntry) -> p4r.TableEntry:
    """The parts of a read-back entry a Write may carry (no counter data, no hit times)."""
    out = p4r.TableEntry(table_id=te.table_id, priority=te.priority, is_default_action=te.is_default_action,
                         controller_metadata=te.controller_metadata, metadata=te.metadata,
                         idle_timeout_ns=te.idle_timeout_ns)
    out.match.extend(te.match)
    if te.HasField("action"):
        out.action.CopyFrom(te.action)
    return out


def _update(kind: int, te: p4r.TableEntry, pad: SwitchSchema | None = None) -> p4r.Update:
    u = p4r.Update(type=kind)
    u.entity.table_entry.CopyFrom(padded_entry(te, pad) if pad is not None else te)
    if kind == MODIFY and te.is_default_action and not te.HasField("action"):
        u.entity.table_entry.ClearField("action")  # reset to the P4 program's default
    return u


# ---------------------------------------------------------------- plan
@dataclass
class Plan:
    inserts: list = field(default_factory=list)        # TableEntry
    modifies: list = field(default_factory=list)       # (new TableEntry, old TableEntry)
    deletes: list = field(default_factory=list)        # TableEntry (as read)
    unchanged: int = 0

    @property
    def empty(self) -> bool:
        return not (self.inserts or self.modifies or self.deletes)

    def phases(self, schema: SwitchSchema, current_counts: dict) -> list[tuple[int, list]]:
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
        roomy = all(not schema.tables[t].size or n <= schema.tables[t].size
                    for t, n in grow.items() if schema.tables.get(t) is not None)
        order = [(INSERT, ins), (MODIFY, mod), (DELETE, dele)] if roomy else \
            [(DELETE, dele), (MODIFY, mod), (INSERT, ins)]
        return [(t, items) for t, items in order if items]


def make_plan(desired: DesiredState, current: list, current_defaults: list, schema: SwitchSchema) -> Plan:
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


def read_state(conn: SwitchConnection, schema: SwitchSchema) -> tuple[list, list]:
    """(match entries, default entries) of every table the control plane manages, in one Read."""
    ents = [P4TableEntry(name).encode(schema) for name in schema.managed_tables()]
    ents += [P4TableEntry(name, is_default_action=True).encode(schema) for name in schema.default_tables()]
    entries, defaults = [], []
    for ent in conn.read(ents):
        if ent.WhichOneof("entity") == "table_entry":
            (defaults if ent.table_entry.is_default_action else entries).append(ent.table_entry)
    return entries, defaults


# ---------------------------------------------------------------- monitor state
def changed_monitors(schema: SwitchSchema, desired: DesiredState, current_defaults: list) -> list[tuple]:
    """(slot, old config params, new config params) of every monitor slot whose config action changes."""
    have = {te.table_id: te for te in current_defaults}
    out = []
    for te in desired.defaults:
        name = schema.tables[te.table_id].name
        if not name.endswith(".config"):
            continue
        old = have.get(te.table_id)
        if old is None or action_key(old) != action_key(te):
            k = int(name.split(".")[-2].removeprefix("mon"))
            out.append((k, schema.action_params(old), schema.action_params(te)))
    return sorted(out, key=lambda c: c[0])


def clear_updates(schema: SwitchSchema, k: int, ring_cells: int, slots=range(MAX_PLANTS), only=None,
                  full_width: bool = False) -> list:
    """MODIFY updates writing 0 into monitor slot k's registers: every plant slot's cell, and the
    first `ring_cells` ring cells of every plant slot (cell = slot * stride + i)."""
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
        for i in cells:
            u = P4RegisterEntry(reg.name, index=i, data=0).encode_update(schema)
            if full_width:
                u.entity.register_entry.data.bitstring = padded(b"\x00", reg.type_spec.bitwidth)
            ups.append(u)
    return ups


def registers_writable(conn: SwitchConnection, schema: SwitchSchema, k: int) -> bool:
    """Probe: zero monitor k's run counter of slot 0 (harmless: k's state is about to be cleared).

    BMv2's P4Runtime server does not implement register access (p4lang/PI#376).
    """
    if schema.registers.get(mon(k, "run")) is None:
        return False
    try:
        conn.write(clear_updates(schema, k, 0, slots=[0], only=["run"], full_width=conn.padded_bytes))
        return True
    except WriteRejected:
        return False


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


def converge(conn: SwitchConnection, entries: Entries, schema: SwitchSchema,
             pipeline: SwitchSchema | None = None) -> ConvergeResult:
    """Make the switch hold exactly the entries' tables; one WriteRequest per phase.

    An enabled monitor whose configuration (signal, window, estimator) changes,
    or that is disabled, gets its registers zeroed after the tables are
    written: its ring and running sums only make sense for the configuration
    that filled them. When the switch cannot write registers over P4Runtime
    (BMv2, p4lang/PI#376) the pipeline is reinstalled instead, which zeroes
    all state; that needs `pipeline` (a schema with its blob).
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
    if reinstall:
        conn.set_pipeline(pipeline.get_pipeline_config())
        current, current_defaults = read_state(conn, schema)
    plan = make_plan(desired, current, current_defaults, schema)
    result = ConvergeResult(added=len(plan.inserts), modified=len(plan.modifies),
                            deleted=len(plan.deletes), unchanged=plan.unchanged, pipeline_pushed=reinstall)
    counts: dict[int, int] = {}
    for te in current:
        counts[te.table_id] = counts.get(te.table_id, 0) + 1
    pad = schema if conn.padded_bytes else None
    done: list = []          # inverse updates of everything applied so far, in order
    for kind, items in plan.phases(schema, counts):
        try:
            result.writes += 1
            conn.write([_update(kind, te, pad) for te, _ in items])
        except WriteRejected as rej:
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
            _, code, msg = rej.failed[0]
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


def _rollback(conn: SwitchConnection, done: list, pad: SwitchSchema | None = None) -> str:
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


def configure(address: str, entries_path: str | Path, pipeline_dir: str | Path | None = None,
              device_id: int = 0, election_id: int = 1, timeout: float = 5.0,
              padded_bytes: bool = False) -> ConvergeResult:
    """Validate the entries file, connect, (install the pipeline,) converge. Used by `civic configure`."""
    entries = load_entries(entries_path)
    pipeline = load_pipeline(pipeline_dir) if pipeline_dir is not None else None
    if pipeline is not None:     # validate against the P4Info before touching the switch
        desired_state(entries, pipeline)
    with SwitchConnection(address, device_id, election_id, timeout, padded_bytes) as conn:
        conn.require_primary()
        schema, pushed = ensure_pipeline(conn, pipeline)
        result = converge(conn, entries, schema, pipeline)
        result.pipeline_pushed = result.pipeline_pushed or pushed
        return result
