"""`civic watch`: a P4Runtime controller that follows the verdicts of a running CIVIC switch.

It joins with a low election id (1; `civic configure` uses 10), so a configure run
takes over writes for a moment and the watch is primary again when it leaves. It
never writes tables or the pipeline: as primary it only enables the verdict-change
digest (docs/pipeline.md section 7), acknowledges every digest list, turns digests
into events, and reads the `monK.verdicts` counters. `WatchState` is what it
knows, for the live table and the Prometheus metrics.
"""
from __future__ import annotations

import ipaddress
import json
import time
from dataclasses import dataclass, field

from finsy import P4TableEntry

from civic.errors import CivicError
from civic.events import digest_changes, event
from civic.switch.connection import SwitchConnection
from civic.switch.counters import read_counter
from civic.switch.digests import digest_members, enable_digest
from civic.switch.schema import COUNTER_VERDICTS, DIGEST_VERDICT_CHANGE, TABLE_PLANT_PREFIX, SwitchSchema, mon
from civic.wire import CLASS_CODES, VERDICT_NAMES, plant_address

WATCH_ELECTION_ID = 1
COUNTER_POLL_S = 1.0


@dataclass
class PlantMonitor:
    """What the watch knows about one (plant, monitor)."""

    cls: int = 0                   # current class (0: none yet)
    since: float | None = None     # wall time of the change to it
    counts: dict = field(default_factory=lambda: {1: 0, 2: 0, 3: 0})
    changed_at: float = 0.0        # for highlighting


@dataclass
class WatchState:
    monitors: list[str]
    cells: dict = field(default_factory=dict)        # (plant ip, monitor name) -> PlantMonitor
    events_total: int = 0
    last_digest: float | None = None
    switch_up: bool = False                          # connected to the switch (metric civic_switch_up)
    events: list = field(default_factory=list)       # every event seen (for --plot)

    def cell(self, plant: str, monitor: str) -> PlantMonitor:
        return self.cells.setdefault((plant, monitor), PlantMonitor())

    def apply_event(self, ev: dict, now: float) -> None:
        c = self.cell(ev["plant"], ev["monitor"])
        c.cls = CLASS_CODES[ev["to"]]
        c.since = ev["t"]
        c.changed_at = now
        self.events_total += 1
        self.events.append(ev)

    def apply_counts(self, plant: str, monitor: str, counts: dict) -> None:
        self.cell(plant, monitor).counts = counts


class Watcher:
    """One watch session on a switch: connect, enable digests, turn what arrives into state."""

    def __init__(self, address: str, monitors: list[str] | None = None, device_id: int = 0,
                 election_id: int = WATCH_ELECTION_ID, timeout: float = 5.0, events_file=None,
                 plant_prefix: str | None = None, on_event=None):
        self.address = address
        self.device_id = device_id
        self.election_id = election_id
        self.timeout = timeout
        self.events_file = events_file
        self.on_event = on_event
        self.plant_prefix = plant_prefix
        self.state = WatchState(list(monitors or []))
        self.conn: SwitchConnection | None = None
        self.schema: SwitchSchema | None = None
        self._enabled_as_primary = False
        self._last_poll = 0.0

    # -- session
    def connect(self) -> None:
        conn = SwitchConnection(self.address, self.device_id, self.election_id, self.timeout)
        conn.connect()
        config = conn.get_pipeline()
        if config is None or not config.HasField("p4info"):
            conn.close()
            raise CivicError(f"switch {self.address} runs no pipeline (install one with civic configure --pipeline)")
        schema = SwitchSchema(config.p4info)
        try:
            schema.digest(DIGEST_VERDICT_CHANGE)
            slots = schema.monitor_slots()
            for k in range(slots):
                schema.counter(mon(k, COUNTER_VERDICTS))
            if slots == 0:
                raise CivicError(f"P4Info has no table '{mon(0, 'config')}'")
        except CivicError as exc:
            conn.close()
            raise CivicError(f"switch {self.address}: not a CIVIC pipeline with verdict digests: {exc}") from None
        if not self.state.monitors:
            self.state.monitors = [f"m{k}" for k in range(slots)]
        self.conn, self.schema = conn, schema
        self._enabled_as_primary = False
        if self.plant_prefix is None:
            self.plant_prefix = self._read_plant_prefix()
        self.state.switch_up = True

    def _read_plant_prefix(self) -> str:
        """The plant prefix the switch holds (its plant_prefix table), to name plants by address."""
        for ent in self.conn.read([P4TableEntry(TABLE_PLANT_PREFIX).encode(self.schema)]):
            entry = P4TableEntry.decode(ent, self.schema)
            if entry.match:
                net, prefix_len = entry.match["src_addr"]
                return f"{ipaddress.IPv4Address(net)}/{prefix_len}"
        return "10.0.0.0/24"

    def close(self) -> None:
        self.state.switch_up = False
        if self.conn is not None:
            self.conn.close()
            self.conn = None

    # -- work
    def ensure_digest(self) -> None:
        """As primary, (re-)enable the digest: a pipeline push by configure drops it."""
        if self.conn.primary and not self._enabled_as_primary:
            enable_digest(self.conn, self.schema)
            self._enabled_as_primary = True
        elif not self.conn.primary:
            self._enabled_as_primary = False

    def poll(self, wait: float) -> None:
        """Handle stream messages for up to `wait` s, then read the counters if due."""
        self.ensure_digest()
        deadline = time.monotonic() + wait
        while (left := deadline - time.monotonic()) > 0:
            msg = self.conn.next_stream_message(left)
            if msg is None:
                break
            if msg.HasField("arbitration"):
                self.ensure_digest()
            elif msg.HasField("digest"):
                now = time.time()
                self.state.last_digest = now
                for member in digest_members(msg, self.schema):
                    for change in digest_changes(member, len(self.state.monitors)):
                        publish(self.state, event(change, now, self.state.monitors), now, self.events_file,
                                self.on_event)
                self.conn.ack_digest(msg.digest)
        if time.monotonic() - self._last_poll >= COUNTER_POLL_S:
            self.read_counters()
            self._last_poll = time.monotonic()

    def read_counters(self) -> None:
        for k, name in enumerate(self.state.monitors):
            cells = read_counter(self.conn, self.schema, mon(k, COUNTER_VERDICTS))
            per_slot: dict = {}
            for index, packets in cells.items():
                slot, cls = divmod(index, 4)
                if cls and packets:
                    per_slot.setdefault(slot, {1: 0, 2: 0, 3: 0})[cls] = packets
            for slot, counts in per_slot.items():
                self.state.apply_counts(plant_address(self.plant_prefix, slot), name, counts)


def publish(state: WatchState, ev: dict, now: float, events_file=None, on_event=None) -> None:
    """A verdict-change event into the state, as a line of the --events file, and to on_event."""
    state.apply_event(ev, now)
    if events_file is not None:
        events_file.write(json.dumps(ev) + "\n")
        events_file.flush()
    if on_event is not None:
        on_event(ev)


def class_name(code: int) -> str:
    return VERDICT_NAMES[code] if code else "-"
