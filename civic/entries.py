"""Table entries: the one format `civic train` writes and the switch (model or P4) runs.

See docs/pipeline.md section 6 for the JSON layout.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np

from civic.config import (MAX_FLOWS, Monitor, MonitorConfig, check_int, check_monitor_list, check_range,
                          parse_common, parse_monitor)
from civic.errors import CivicError
from civic.files import read_json
from civic.wire import CLASS_CODES

FORMAT = "civic-entries/3"
FORMATS = ("civic-entries/1", "civic-entries/2", FORMAT)   # 1: no compensation; 2: no balance/limit/hold
ESTIMATORS = ("endpoint", "lsq", "value")
OPERANDS = ("l1", "l2", "l3", "l4", "p1", "v1", "v2", "zero")   # what a flow term's keys read
FLOW_COLUMNS = ("head_lo", "head_hi", "cmd_lo", "cmd_hi", "flow", "band")
FLOW_MAX = 2**24            # |flow| bound, 1/64 mL per sample (pipeline.md 3b)
BALANCE_SHIFT = 6           # balance monitors push (x << 6) - acc: 1/64 mL
BAND_SUM_SHIFT = 7          # the class table sees the window's band sum >> 7 (pipeline.md 3b)
SLOPE_MIN, SLOPE_MAX = -(2**31), 2**31 - 1
LEVEL_MAX = 0xFFFF
CLASS_COLUMNS = ("slope_lo", "slope_hi", "level_lo", "level_hi", "cls")
OFFSET_COLUMNS = ("aux_lo", "aux_hi", "offset")
OFFSET_MAX = 2**30          # |offset| bound: slope - offset never wraps (pipeline.md 3a)


@dataclass
class FlowTerm:
    """One expected-flow lookup of a balance monitor: keys head = f[plus] - f[minus] (mod 2^16)
    and cmd = f[command]; rows of FLOW_COLUMNS (pipeline.md 3b)."""

    head: tuple[str, str]
    command: str
    rows: np.ndarray

    @cached_property
    def table(self):
        """The rows as a RangeTable on (head, cmd), built once (the lookup every message uses)."""
        from civic.pipeline.classification import RangeTable

        return RangeTable(self.rows[:, [0, 2]], self.rows[:, [1, 3]])

    def to_json(self) -> dict:
        return {"head": list(self.head), "command": self.command,
                "entries": [{"head": [int(r[0]), int(r[1])], "command": [int(r[2]), int(r[3])],
                             "flow": int(r[4]), "band": int(r[5])} for r in self.rows]}


@dataclass
class MonitorEntries(Monitor):
    """A monitor with its estimator, class table (rows of CLASS_COLUMNS) and compensation
    table (rows of OFFSET_COLUMNS)."""

    estimator: str = "lsq"
    default_class: int = CLASS_CODES["error"]
    classes: np.ndarray = field(default_factory=lambda: np.zeros((0, len(CLASS_COLUMNS)), dtype=np.int64))
    offsets: np.ndarray = field(default_factory=lambda: np.zeros((0, len(OFFSET_COLUMNS)), dtype=np.int64))
    terms: list[FlowTerm] = field(default_factory=list)

    @property
    def aux_signals(self) -> tuple[str, str]:
        """(aux_plus, aux_minus); an uncompensated monitor uses its own signal twice (aux = 0)."""
        return self.compensate or (self.signal, self.signal)

    @property
    def ring_len(self) -> int:
        """lsq needs the value leaving the W-window; endpoint needs the window's oldest."""
        return self.window - 1 if self.estimator == "endpoint" else self.window

    @property
    def slope_scale(self) -> float:
        """Raw slope -> mL/s (10 samples per second); a limit monitor's raw value is mL."""
        w = self.window
        if self.estimator == "value":
            return 1.0
        per_sample = 6.0 / (w * (w * w - 1)) if self.estimator == "lsq" else 1.0 / (w - 1)
        return per_sample * 10.0 / (1 << BALANCE_SHIFT if self.kind == "balance" else 1)

    def to_json(self) -> dict:
        return {
            "name": self.name, "kind": self.kind, "signal": self.signal, "window": self.window,
            "hold": self.hold, "estimator": self.estimator,
            "precondition": {k: list(v) for k, v in self.precondition.items()},
            **({"compensation": {"signal": self.compensate[0], "minus": self.compensate[1],
                                 "offsets": [{"aux": [int(r[0]), int(r[1])], "offset": int(r[2])}
                                             for r in self.offsets]}} if self.compensate else {}),
            **({"limits": dict(self.limits)} if self.limits else {}),
            **({"flows": list(self.flows), "band": self.band,
                "flow_terms": [t.to_json() for t in self.terms]} if self.kind == "balance" else {}),
            "slope_scale_ml_per_s": self.slope_scale,
            "default_class": self.default_class,
            "classes": [{"slope": [int(r[0]), int(r[1])], "level": [int(r[2]), int(r[3])], "class": int(r[4])}
                        for r in self.classes],
        }


@dataclass
class Entries:
    monitors: list[MonitorEntries]
    udp_port: int = 50000
    plant_prefix: str = "10.0.0.0/24"
    forwarding: dict[int, int] = field(default_factory=lambda: {1: 2, 2: 1})
    training: dict = field(default_factory=dict)

    def to_json(self) -> dict:
        return {
            "format": FORMAT, "udp_port": self.udp_port, "plant_prefix": self.plant_prefix,
            "forwarding": {str(k): v for k, v in self.forwarding.items()},
            "monitors": [m.to_json() for m in self.monitors],
            "training": self.training,
        }

    def save(self, path: str | Path) -> None:
        Path(path).write_text(json.dumps(self.to_json(), indent=1) + "\n")


def check_no_overlap(rows: np.ndarray, what: str) -> None:
    """Entries of one table (columns lo0, hi0, lo1, hi1) must not overlap: a packet matches at
    most one. How many entries cover each cell of the edge grid, by a 2-D difference array;
    only when some cell has two are the pairs searched, to name them."""
    if len(rows) < 2 or _max_cover(rows) <= 1:
        return
    for i in range(len(rows)):
        a = rows[i]
        rest = rows[i + 1:]
        hit = ((rest[:, 0] <= a[1]) & (a[0] <= rest[:, 1]) & (rest[:, 2] <= a[3]) & (a[2] <= rest[:, 3]))
        if np.any(hit):
            j = i + 1 + int(np.flatnonzero(hit)[0])
            raise CivicError(f"{what}: entries {i} and {j} overlap")


def _max_cover(rows: np.ndarray) -> int:
    """The most entries holding any one key pair."""
    cells = []
    for lo, hi in ((rows[:, 0], rows[:, 1]), (rows[:, 2], rows[:, 3])):
        edges = np.unique(np.concatenate((lo, hi + 1)))
        cells.append((np.searchsorted(edges, lo), np.searchsorted(edges, hi + 1), len(edges)))
    (a0, b0, n0), (a1, b1, n1) = cells
    d = np.zeros((n0 + 1, n1 + 1), np.int64)
    for x, y, sign in ((a0, a1, 1), (b0, a1, -1), (a0, b1, -1), (b0, b1, 1)):
        np.add.at(d, (x, y), sign)
    return int(d.cumsum(0).cumsum(1).max())


def parse_monitor_entries(raw, what: str) -> MonitorEntries:
    base = parse_monitor(raw, what)
    est = raw.get("estimator", "value" if base.kind == "limit" else "lsq")
    if est not in ESTIMATORS:
        raise CivicError(f"{what}.estimator: {est!r} is not one of {', '.join(ESTIMATORS)}")
    if (est == "value") != (base.kind == "limit"):
        raise CivicError(f"{what}.estimator: {est!r} does not suit a {base.kind} monitor "
                         f"(limit monitors use 'value', the others endpoint or lsq)")
    default = check_int(raw.get("default_class", 3), f"{what}.default_class", 1, 3)
    rows = raw.get("classes")
    if not isinstance(rows, list):
        raise CivicError(f"{what}: missing key 'classes' (a list)")
    table = np.zeros((len(rows), 5), dtype=np.int64)
    for i, row in enumerate(rows):
        w = f"{what}.classes[{i}]"
        if not isinstance(row, dict):
            raise CivicError(f"{w}: expected an object")
        for key in ("slope", "class"):
            if key not in row:
                raise CivicError(f"{w}: missing key '{key}'")
        table[i, 0:2] = check_range(row["slope"], f"{w}.slope", SLOPE_MIN, SLOPE_MAX)
        table[i, 2:4] = check_range(row.get("level", [0, LEVEL_MAX]), f"{w}.level", 0, LEVEL_MAX)
        table[i, 4] = check_int(row["class"], f"{w}.class", 0, 3)
    check_no_overlap(table, what)
    comp, offsets = parse_compensation(raw.get("compensation"), f"{what}.compensation", est, base.window)
    terms = parse_terms(raw.get("flow_terms"), f"{what}.flow_terms", base.kind)
    return MonitorEntries(name=base.name, signal=base.signal, window=base.window,
                          precondition=base.precondition, compensate=comp, kind=base.kind, hold=base.hold,
                          flows=base.flows, band=base.band, limits=base.limits,
                          estimator=est, default_class=default, classes=table, offsets=offsets, terms=terms)


def parse_terms(raw, what: str, kind: str) -> list[FlowTerm]:
    """A balance monitor's flow terms (pipeline.md 3b): keys, and disjoint entries per term."""
    if kind != "balance":
        if raw is not None:
            raise CivicError(f"{what}: only balance monitors have flow terms")
        return []
    if not isinstance(raw, list) or not 1 <= len(raw) <= MAX_FLOWS:
        raise CivicError(f"{what}: expected a list of 1 to {MAX_FLOWS} flow terms")
    terms = []
    for k, term in enumerate(raw):
        w = f"{what}[{k}]"
        if not isinstance(term, dict) or not all(key in term for key in ("head", "command", "entries")):
            raise CivicError(f"{w}: expected an object with head, command, entries")
        head = term["head"]
        if not isinstance(head, list) or len(head) != 2 or not all(h in OPERANDS for h in head):
            raise CivicError(f"{w}.head: expected [plus, minus] from {', '.join(OPERANDS)}, got {head!r}")
        if term["command"] not in OPERANDS:
            raise CivicError(f"{w}.command: {term['command']!r} is not one of {', '.join(OPERANDS)}")
        rows = term["entries"]
        if not isinstance(rows, list):
            raise CivicError(f"{w}.entries: expected a list")
        table = np.zeros((len(rows), 6), dtype=np.int64)
        for i, row in enumerate(rows):
            r = f"{w}.entries[{i}]"
            if not isinstance(row, dict) or not all(key in row for key in ("head", "command", "flow", "band")):
                raise CivicError(f"{r}: expected an object with head, command, flow, band")
            table[i, 0:2] = check_range(row["head"], f"{r}.head", 0, LEVEL_MAX)
            table[i, 2:4] = check_range(row["command"], f"{r}.command", 0, LEVEL_MAX)
            table[i, 4] = check_int(row["flow"], f"{r}.flow", -FLOW_MAX, FLOW_MAX)
            table[i, 5] = check_int(row["band"], f"{r}.band", 0, LEVEL_MAX)
        check_no_overlap(table, w)
        terms.append(FlowTerm((head[0], head[1]), term["command"], table))
    return terms


def parse_compensation(raw, what: str, estimator: str, window: int):
    """(aux_plus, aux_minus) or None, and the compensate table rows (aux_lo, aux_hi, offset)."""
    if raw is None:
        return None, np.zeros((0, 3), dtype=np.int64)
    if not isinstance(raw, dict):
        raise CivicError(f"{what}: expected an object with signal, minus, offsets")
    for key in ("signal", "minus", "offsets"):
        if key not in raw:
            raise CivicError(f"{what}: missing key '{key}'")
    levels = ("l1", "l2", "l3", "l4")
    for key in ("signal", "minus"):
        if raw[key] not in levels:
            raise CivicError(f"{what}.{key}: {raw[key]!r} is not one of {', '.join(levels)}")
    if raw["signal"] == raw["minus"]:
        raise CivicError(f"{what}: signal and minus must differ")
    rows = raw["offsets"]
    if not isinstance(rows, list):
        raise CivicError(f"{what}.offsets: expected a list")
    table = np.zeros((len(rows), 3), dtype=np.int64)
    step = window - 1 if estimator == "lsq" else 1
    for i, row in enumerate(rows):
        w = f"{what}.offsets[{i}]"
        if not isinstance(row, dict) or "aux" not in row or "offset" not in row:
            raise CivicError(f"{w}: expected an object with aux [lo, hi] and offset")
        table[i, 0:2] = check_range(row["aux"], f"{w}.aux", 0, LEVEL_MAX)
        table[i, 2] = check_int(row["offset"], f"{w}.offset", -OFFSET_MAX, OFFSET_MAX)
        if table[i, 2] % step:
            raise CivicError(f"{w}.offset: {table[i, 2]} is not a multiple of W - 1 = {step} (lsq)")
    order = np.argsort(table[:, 0], kind="stable")
    s = table[order]
    clash = np.flatnonzero(s[1:, 0] <= s[:-1, 1])
    if len(clash):
        raise CivicError(f"{what}: offsets entries {order[clash[0]]} and {order[clash[0] + 1]} overlap")
    return (raw["signal"], raw["minus"]), table


def parse_entries(raw, what: str) -> Entries:
    if not isinstance(raw, dict):
        raise CivicError(f"{what}: expected a JSON object")
    if raw.get("format") not in FORMATS:
        raise CivicError(f"{what}: format: expected one of {', '.join(map(repr, FORMATS))}, "
                         f"got {raw.get('format')!r}")
    port, prefix = parse_common(raw, what)
    items = raw.get("monitors")
    if not isinstance(items, list):
        raise CivicError(f"{what}: missing key 'monitors' (a list)")
    monitors = [parse_monitor_entries(m, f"{what}: monitors[{i}]") for i, m in enumerate(items)]
    check_monitor_list(monitors, what)
    fwd_raw = raw.get("forwarding", {"1": 2, "2": 1})
    if not isinstance(fwd_raw, dict):
        raise CivicError(f"{what}: forwarding: expected an object port -> port")
    forwarding = {}
    for k, v in fwd_raw.items():
        if not str(k).isdigit():
            raise CivicError(f"{what}: forwarding: port {k!r} is not a number")
        forwarding[check_int(int(k), f"{what}: forwarding key", 0, 511)] = check_int(v, f"{what}: forwarding[{k}]", 0, 511)
    training = raw.get("training", {})
    return Entries(monitors=monitors, udp_port=port, plant_prefix=prefix,
                   forwarding=forwarding, training=training if isinstance(training, dict) else {})


def load_entries(path: str | Path) -> Entries:
    """Read and validate an entries JSON file; errors are one line naming the key."""
    return parse_entries(read_json(path), str(path))


def monitor_entries(mon: Monitor, estimator: str, rows=None, default_class=3, offsets=None) -> MonitorEntries:
    """A configured monitor's entries: its class rows and compensate offsets (none: empty tables)."""
    table = np.zeros((0, 5), np.int64) if rows is None else np.asarray(rows, np.int64).reshape(-1, 5)
    offsets = np.zeros((0, 3), np.int64) if offsets is None else offsets
    return MonitorEntries(name=mon.name, signal=mon.signal, window=mon.window,
                          precondition=mon.precondition, compensate=mon.compensate if len(offsets) else None,
                          kind=mon.kind, hold=mon.hold, limits=mon.limits,
                          estimator="value" if mon.kind == "limit" else estimator,
                          default_class=default_class, classes=table, offsets=offsets)


def probe_entries(config: MonitorConfig, estimator: str) -> Entries:
    """Entries with empty class and compensate tables: the switch computes runs, slopes and the
    compensate key aux, every verdict says error."""
    monitors = [monitor_entries(m, estimator) for m in config.monitors]
    for m, mon in zip(monitors, config.monitors):
        m.compensate = mon.compensate          # aux computed, nothing subtracted
    return Entries(monitors=monitors, udp_port=config.udp_port, plant_prefix=config.plant_prefix)
