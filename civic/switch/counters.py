"""Indirect counters read over P4Runtime (`civic watch` reads the monK.verdicts counters)."""
from __future__ import annotations

from finsy import P4CounterEntry

from civic.switch.connection import SwitchConnection
from civic.switch.schema import SwitchSchema


def read_counter(conn: SwitchConnection, schema: SwitchSchema, name: str) -> dict[int, int]:
    """Packet count of every cell of a counter."""
    schema.counter(name)
    cells = (P4CounterEntry.decode(e, schema) for e in conn.read([P4CounterEntry(name).encode(schema)]))
    return {c.index: c.packet_count for c in cells}
