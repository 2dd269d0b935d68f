"""Per-plant register state, read over P4Runtime (`civic configure --read`)."""
from __future__ import annotations

import ipaddress
from dataclasses import dataclass

from finsy import P4RegisterEntry

from civic.errors import CivicError
from civic.switch.connection import SwitchConnection
from civic.switch.schema import REGISTER_LAST_SEQ, SwitchSchema, mon


def read_register(conn: SwitchConnection, schema: SwitchSchema, name: str, indices=None) -> dict[int, int]:
    """index -> value of a register (all cells, or the given indices, in one Read)."""
    schema.register(name)
    query = [P4RegisterEntry(name, index=i).encode(schema) for i in ([None] if indices is None else indices)]
    cells = (P4RegisterEntry.decode(e, schema) for e in conn.read(query) if e.HasField("register_entry"))
    return {c.index: c.data for c in cells}


@dataclass
class PlantState:
    slot: int
    last_seq: int
    monitors: list          # per slot k: dict ptr, run, s0, s1, ring (oldest first)


def read_plant_state(conn: SwitchConnection, schema: SwitchSchema, config: list, slots=None) -> list[PlantState]:
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


def monitor_config(schema: SwitchSchema, defaults: list) -> list[tuple[int, int]]:
    """(enabled, ring_len) per monitor slot from the read-back config default actions."""
    by_table = {te.table_id: te for te in defaults}
    out = []
    for k in range(schema.monitor_slots()):
        vals = schema.action_params(by_table.get(schema.table(mon(k, "config")).id))
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
