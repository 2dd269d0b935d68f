"""The whole switch: plant lookup -> data collection -> slope -> classification -> notify -> verdict.

`SwitchModel.step` is the plain per-message model (state kept between calls,
exactly the P4 registers and counters; verdict changes collected in
`.changes`, counts in `.counts`); `SwitchModel.run` / `.verdict_changes` /
`.verdict_counts` are the vectorized model of a freshly reset switch.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from civic.entries import Entries, MonitorEntries
from civic.pipeline import classification, data_collection, notify, plant_lookup, slope
from civic.pipeline.verdict import verdict_bits
from civic.wire import SIGNALS


@dataclass
class MonitorTrace:
    """What one monitor computed for each plant message (arrays aligned with them)."""

    monitor: MonitorEntries
    run: np.ndarray       # qualifying-run counter after the message
    slope: np.ndarray     # raw estimator value (signed)
    level: np.ndarray     # the monitored signal's current value
    aux: np.ndarray       # compensate table key
    offset: np.ndarray    # compensate table result (the expected inflow, raw units)
    code: np.ndarray      # 0 not evaluated, 1..3 class

    @property
    def evaluated(self) -> np.ndarray:
        return self.run >= self.monitor.window

    @property
    def resid(self) -> np.ndarray:
        """What the class table sees: the slope minus the expected inflow."""
        return slope.to_int32(self.slope - self.offset)


class SwitchModel:
    """Software twin of the CIVIC P4 program, configured by table entries."""

    def __init__(self, entries: Entries, plants: int = plant_lookup.MAX_PLANTS):
        self.entries = entries
        self.plants = plants
        self.reset()

    def reset(self) -> None:
        """Zero every register, as a freshly started switch."""
        self.last_seq = np.zeros(self.plants, dtype=np.int64)
        self.rings = [data_collection.RingState(self.plants, m.ring_len) for m in self.entries.monitors]
        n = len(self.entries.monitors)
        self.last_class = np.zeros((n, self.plants), dtype=np.int64)
        self.counts = np.zeros((n, self.plants, notify.CLASSES), dtype=np.int64)
        self.changes: list[notify.Change] = []

    # -- plain per-message model: one call per plant message, mirrors the P4 control flow
    def step(self, src: int, seq: int, fields: dict, index: int = -1) -> int:
        slot = int(plant_lookup.plant_slot(src))
        gap = plant_lookup.seq_gap(seq, int(self.last_seq[slot]))
        self.last_seq[slot] = seq
        verdict = 0
        for m, (mon, ring) in enumerate(zip(self.entries.monitors, self.rings)):
            q = all(lo <= fields[name] <= hi for name, (lo, hi) in zip(SIGNALS, mon.ranges()))
            ring.run[slot] = data_collection.next_run(int(ring.run[slot]), q, gap)
            x = fields[mon.signal]
            old = ring.push(slot, x)
            if mon.estimator == "lsq":
                s = int(slope.lsq(ring.s0[slot], ring.s1[slot], mon.window))
            else:
                s = int(slope.endpoint(x, old))
            a = classification.aux(fields, *mon.aux_signals)
            resid = int(slope.to_int32(s - int(classification.compensate(a, mon.offsets))))
            code = 0
            if ring.run[slot] >= mon.window:
                code = int(classification.classify(np.array([resid]), np.array([x]), mon.classes,
                                                   mon.default_class)[0])
            if code:                                  # notify: counters, last_class, changes
                self.counts[m, slot, code] += 1
                prev = int(self.last_class[m, slot])
                if code != prev:
                    self.changes.append(notify.Change(index, int(src), m, prev, code, int(seq), s, int(x)))
                    self.last_class[m, slot] = code
            verdict |= code << (2 * m)
        return verdict

    def run_plain(self, messages: np.ndarray) -> np.ndarray:
        """Verdict of every message via `step`; non-plant messages keep their verdict field."""
        out = messages["verdict"].copy()
        for i in np.flatnonzero(messages["plant"]):
            row = messages[i]
            out[i] = self.step(int(row["src"]), int(row["seq"]), {k: int(row[k]) for k in SIGNALS}, int(i))
        return out

    # -- vectorized model of a freshly reset switch
    def traces(self, messages: np.ndarray) -> tuple[np.ndarray, list[MonitorTrace]]:
        """Per plant message (indices returned) what every monitor computed."""
        plant = messages["plant"]
        idx = np.flatnonzero(plant)
        msgs = messages if len(idx) == len(messages) else messages[idx]
        # each plant's messages as one contiguous stretch: sort by slot once, unsort at the end
        slots = plant_lookup.plant_slot(msgs["src"])
        order = np.argsort(slots, kind="stable")
        unsort = np.empty_like(order)
        unsort[order] = np.arange(len(order))
        slot = slots[order]
        cuts = np.concatenate(([0], np.flatnonzero(np.diff(slot)) + 1, [len(order)]))
        spans = [slice(a, b) for a, b in zip(cuts[:-1], cuts[1:]) if b > a]
        seq = msgs["seq"][order]
        gap = np.concatenate([plant_lookup.seq_gaps(seq[s]) for s in spans]) if spans else np.zeros(0, bool)
        fields = {k: msgs[k].astype(np.int64)[order] for k in SIGNALS}
        traces = []
        for mon in self.entries.monitors:
            q = classification.qualified(fields, mon.ranges())
            x = fields[mon.signal]
            run = np.zeros(len(order), dtype=np.int64)
            s = np.zeros(len(order), dtype=np.int64)
            for sp in spans:
                run[sp] = data_collection.runs(q[sp], gap[sp])
                old, s0, s1 = data_collection.window_sums(x[sp], mon.ring_len)
                s[sp] = slope.lsq(s0, s1, mon.window) if mon.estimator == "lsq" else slope.endpoint(x[sp], old)
            a = classification.aux(fields, *mon.aux_signals)
            off = classification.compensate(a, mon.offsets)
            code = np.zeros(len(order), dtype=np.int64)
            ev = run >= mon.window
            code[ev] = classification.classify(slope.to_int32(s[ev] - off[ev]), x[ev], mon.classes,
                                               mon.default_class)
            traces.append(MonitorTrace(monitor=mon, run=run[unsort], slope=s[unsort], level=x[unsort],
                                       aux=a[unsort], offset=off[unsort], code=code[unsort]))
        return idx, traces

    def verdict_changes(self, messages: np.ndarray) -> list[notify.Change]:
        """Every verdict change (the switch's digests), in message order, monitors in order."""
        return self._changes(messages, *self.traces(messages))

    def run_with_changes(self, messages: np.ndarray) -> tuple[np.ndarray, list[notify.Change]]:
        """`run` and `verdict_changes` from one pass over the messages."""
        idx, traces = self.traces(messages)
        return self._verdicts(messages, idx, traces), self._changes(messages, idx, traces)

    def _changes(self, messages, idx, traces) -> list[notify.Change]:
        slots = plant_lookup.plant_slot(messages["src"][idx])
        out = []
        for m, tr in enumerate(traces):
            changed, prev = notify.changes(slots, tr.code)
            for j in np.flatnonzero(changed):
                i = int(idx[j])
                out.append(notify.Change(i, int(messages["src"][i]), m, int(prev[j]), int(tr.code[j]),
                                         int(messages["seq"][i]), int(tr.slope[j]), int(tr.level[j])))
        return sorted(out, key=lambda c: (c.index, c.monitor))

    def verdict_counts(self, messages: np.ndarray) -> np.ndarray:
        """The verdicts counters (monitors, plants, 4) after the messages."""
        idx, traces = self.traces(messages)
        slots = plant_lookup.plant_slot(messages["src"][idx])
        return np.array([notify.verdict_counts(slots, tr.code, self.plants) for tr in traces]).reshape(
            len(traces), self.plants, notify.CLASSES)

    def run(self, messages: np.ndarray) -> np.ndarray:
        """Verdict of every message (vectorized); non-plant messages keep their verdict field."""
        return self._verdicts(messages, *self.traces(messages))

    @staticmethod
    def _verdicts(messages, idx, traces) -> np.ndarray:
        out = messages["verdict"].copy()
        if len(idx):
            out[idx] = verdict_bits([t.code for t in traces])
        return out
