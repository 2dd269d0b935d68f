"""The whole switch: plant lookup -> balance -> data collection -> slope -> classification -> notify -> verdict.

`SwitchModel.step` is the plain per-message model (state kept between calls,
exactly the P4 registers and counters; verdict changes collected in
`.changes`, counts in `.counts`); `SwitchModel.run` / `.verdict_changes` /
`.verdict_counts` are the vectorized model of a freshly reset switch.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from civic.config import PRECONDITION_FIELDS
from civic.entries import Entries, MonitorEntries
from civic.pipeline import balance, classification, data_collection, notify, plant_lookup, slope
from civic.pipeline.verdict import verdict_bits
from civic.wire import SIGNALS


@dataclass
class MonitorTrace:
    """What one monitor computed for each plant message (arrays aligned with them)."""

    monitor: MonitorEntries
    run: np.ndarray       # qualifying-run counter after the message
    slope: np.ndarray     # raw estimator value (signed; a balance monitor's residual)
    level: np.ndarray     # the monitored signal's current value
    aux: np.ndarray       # compensate table key
    offset: np.ndarray    # compensate table result (the expected inflow, raw units)
    band: np.ndarray      # class table's second key: the level, or a balance monitor's band
    raw: np.ndarray       # class table result (0 where not evaluated)
    code: np.ndarray      # the verdict: 0 not evaluated (or not held yet), 1..3 class

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
        self.last_cmd = {c: np.zeros(self.plants, dtype=np.int64) for c in plant_lookup.COMMANDS}
        n = len(self.entries.monitors)
        self.acc = np.zeros((n, self.plants), dtype=np.int64)
        self.accb = np.zeros((n, self.plants), dtype=np.int64)
        self.ringb = [np.zeros((self.plants, m.ring_len), dtype=np.int64) for m in self.entries.monitors]
        self.cand = np.zeros((n, self.plants), dtype=np.int64)
        self.hold = np.zeros((n, self.plants), dtype=np.int64)
        self.rings = [data_collection.RingState(self.plants, m.ring_len) for m in self.entries.monitors]
        self.last_class = np.zeros((n, self.plants), dtype=np.int64)
        self.counts = np.zeros((n, self.plants, notify.CLASSES), dtype=np.int64)
        self.changes: list[notify.Change] = []

    # -- plain per-message model: one call per plant message, mirrors the P4 control flow
    def step(self, src: int, seq: int, fields: dict, index: int = -1) -> int:
        slot = int(plant_lookup.plant_slot(src))
        gap = plant_lookup.seq_gap(seq, int(self.last_seq[slot]))
        self.last_seq[slot] = seq
        fields = {**fields, **plant_lookup.command_steps(fields, {c: v[slot] for c, v in self.last_cmd.items()})}
        for c in plant_lookup.COMMANDS:
            self.last_cmd[c][slot] = fields[c]
        verdict = 0
        for m, (mon, ring) in enumerate(zip(self.entries.monitors, self.rings)):
            q = all(lo <= fields[name] <= hi for name, (lo, hi) in zip(PRECONDITION_FIELDS, mon.ranges()))
            ring.run[slot] = data_collection.next_run(int(ring.run[slot]), q, gap)
            x = fields[mon.signal]
            key2 = x
            z = x
            if mon.kind == "balance":                 # balance: expected flows, accumulator
                e, band = balance.expected(fields, mon.terms)
                self.acc[m, slot] = (int(self.acc[m, slot]) + int(e)) & data_collection.U32
                z = int(balance.pushed(x, self.acc[m, slot]))
                self.accb[m, slot] = (int(self.accb[m, slot]) + int(band)) & data_collection.U32
                p = int(ring.ptr[slot])                       # the ring's cell, before the push moves it
                oldb = int(self.ringb[m][slot, p])
                self.ringb[m][slot, p] = self.accb[m, slot]
                key2 = int(balance.window_band(self.accb[m, slot], oldb))
            old = ring.push(slot, z)
            s = int(slope.estimate(mon.estimator, z, old, ring.s0[slot], ring.s1[slot], mon.window))
            a = classification.aux(fields, *mon.aux_signals)
            resid = int(slope.to_int32(s - int(classification.compensate(a, mon.offsets))))
            c_raw = 0
            if ring.run[slot] >= mon.window:
                c_raw = int(classification.classify(np.array([resid]), np.array([key2]), mon.classes,
                                                    mon.default_class)[0])
            self.cand[m, slot], self.hold[m, slot] = classification.next_hold(
                int(self.cand[m, slot]), int(self.hold[m, slot]), c_raw)
            code = int(classification.held(c_raw, self.hold[m, slot], mon.hold))
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
        fields.update({d: np.zeros(len(order), np.int64) for d in plant_lookup.STEPS})
        for sp in spans:
            for d, v in plant_lookup.command_steps_stream({c: fields[c][sp] for c in plant_lookup.COMMANDS}).items():
                fields[d][sp] = v
        traces = []
        for mon in self.entries.monitors:
            q = classification.qualified(fields, mon.ranges())
            x = fields[mon.signal]
            z, key2 = x, x
            if mon.kind == "balance":
                e, band = balance.expected(fields, mon.terms)
                z = np.zeros(len(order), dtype=np.int64)
                key2 = np.zeros(len(order), dtype=np.int64)
                for sp in spans:
                    z[sp] = balance.pushed(x[sp], balance.accumulate(e[sp]))
                    key2[sp] = balance.window_bands(band[sp], mon.ring_len)
            run = np.zeros(len(order), dtype=np.int64)
            s = np.zeros(len(order), dtype=np.int64)
            for sp in spans:
                run[sp] = data_collection.runs(q[sp], gap[sp])
                old, s0, s1 = data_collection.window_sums(z[sp], mon.ring_len)
                s[sp] = slope.estimate(mon.estimator, z[sp], old, s0, s1, mon.window)
            a = classification.aux(fields, *mon.aux_signals)
            off = classification.compensate(a, mon.offsets)
            raw = np.zeros(len(order), dtype=np.int64)
            ev = run >= mon.window
            raw[ev] = classification.classify(slope.to_int32(s[ev] - off[ev]), key2[ev], mon.classes,
                                              mon.default_class)
            code = raw
            if mon.hold > 1:
                hold = np.zeros(len(order), dtype=np.int64)
                for sp in spans:
                    hold[sp] = classification.holds(raw[sp])
                code = classification.held(raw, hold, mon.hold)
            traces.append(MonitorTrace(monitor=mon, run=run[unsort], slope=s[unsort], level=x[unsort],
                                       aux=a[unsort], offset=off[unsort], band=key2[unsort], raw=raw[unsort],
                                       code=code[unsort]))
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
