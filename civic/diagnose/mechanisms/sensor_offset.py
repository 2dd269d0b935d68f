"""Sensor offset: y = gain*quantity + offset with an offset the datasheet does not have, from
the start or from a time on (a sensor knocked or re-zeroed mid-run: its reading steps), for a
spell only (a glitch over, a knocked sensor set right: its reading steps back), or one that
grows from a time on (a sensor drifting: fouling, ageing, a warming transmitter)."""
from __future__ import annotations

from ..compare import INVENTORY_BAND, INVENTORY_SPREAD
from .base import Mechanism, dated, drives_no_flow, ended_times, sensors_of, spell_times, tanks_touching

OFFSET_FLOOR = 1e-3  # in the sensor's unit: below this no sensor without noise or resolution reads off
DRIFT_STARTS = 4     # start times tried for a drift, from the record's start to its balance's change


class SensorOffset(Mechanism):
    name = "sensor_offset"
    counted = False
    hidden = ("base", "end", "guessed")  # the model's own offset (added to the fitted one); the
                                         # record's end (s); a start guessed on a grid

    @property
    def n_params(self) -> int:
        return super().n_params + ("since" in self.fixed) + ("until" in self.fixed)   # the times are the data's too

    @property
    def label(self) -> str:
        base = super().label
        return base.replace(f"({self.component}", f"({self.component} drift", 1) if "drift" in self.params else base

    def edit(self, model, p):
        s = model.find("sensor", self.component)
        if "drift" in p:
            s.drift, s.since = float(p["drift"]), float(p["since"])
        elif "since" in p or "until" in p:
            s.shift, s.since = float(p["offset"]), float(p.get("since", 0.0))
            s.until = float(p.get("until", s.until))
        else:
            s.offset = float(self.fixed.get("base", 0.0)) + float(p["offset"])

    @classmethod
    def candidates(cls, model, loc):
        out, seen = [], set()
        near = set()
        for t in loc.tanks:
            near |= tanks_touching(model, t)
        for t in model.tank_names:
            if t not in near:
                continue
            for s in sensors_of(model, t):
                if s.name in loc.signals_present and s.name not in seen:
                    seen.add(s.name)
                    span = max(loc.signal_span.get(s.name, 1.0), 1e-6)
                    bounds = {"offset": (-0.25 * span, 0.25 * span)}
                    out.append(cls(s.name, {"offset": 0.0}, bounds, {"base": s.offset}))
                    # a reading that stepped (`Localisation.reading_steps`): from then on
                    # (from the step's size: a step in the last held-out block leaves the
                    # training blocks nothing to fit it on, and its held-out evidence is the start's)
                    if s.name in getattr(loc, "reading_steps", {}):
                        t0, _, step, lo, hi = loc.reading_steps[s.name]
                        step = min(max(step, bounds["offset"][0]), bounds["offset"][1])
                        out.append(cls(s.name, {"offset": step}, dict(bounds),
                                       {"base": s.offset, "since": t0, "not_before": lo, "not_after": hi}))
                        # ... or off from the start until then (set right at the step)
                        out.append(cls(s.name, {"offset": -step}, dict(bounds),
                                       {"base": s.offset, **ended_times(t0, lo, hi)}))
                    # a reading that stepped and stepped back: off for that spell only
                    if s.name in getattr(loc, "reading_spells", {}):
                        sp = loc.reading_spells[s.name]
                        step = min(max(sp.share, bounds["offset"][0]), bounds["offset"][1])
                        out.append(cls(s.name, {"offset": step}, dict(bounds),
                                       {"base": s.offset, **spell_times("since", sp)}))
                    # its tank's balance changed from a time on: a reading drifting from then or
                    # before (a ramp grows out of the noise late: the change point of a drift of
                    # 0.3 L in 400 s from 200 s fell at 285 s), from DRIFT_STARTS times between
                    # the record's start and that change, each bracketing its share of the span
                    if s.name in getattr(loc, "reading_changes", {}):
                        t0, _, lo, hi, end = loc.reading_changes[s.name]
                        cell = t0 / (DRIFT_STARTS - 1)
                        for k in range(DRIFT_STARTS):
                            since = float(round(k * cell))
                            first, last = max(since - cell / 2, 0.0), since + cell / 2
                            if k == DRIFT_STARTS - 1:
                                first, last = min(first, lo), hi
                            reach = bounds["offset"][1] / max(end - since, 1.0)
                            out.append(cls(s.name, {"drift": 0.0}, {"drift": (-reach, reach)},
                                           {"base": s.offset, "since": since, "not_before": first,
                                            "not_after": last, "end": end, "guessed": True}))
        return out

    def _drifted(self, p) -> float:
        """What a drifting reading drifted by the record's end."""
        return p["drift"] * max(self.fixed["end"] - p["since"], 0.0)

    def negligible(self, p, model):
        s = model.find("sensor", self.component)
        if "drift" in p:      # judged by what it drifted by the record's end
            p = {"offset": self._drifted(p)}
        if model.total_volume is not None and drives_no_flow(model, s.tank):
            # seen through the inventory alone: within the fill's band it is the fill's error
            band = INVENTORY_BAND * INVENTORY_SPREAD * model.total_volume
            litres = abs(p["offset"]) / (s.gain or 1.0) * (model.tank(s.tank).area if s.quantity == "level" else 1.0)
            if litres <= band:
                return True
        return abs(p["offset"]) < max(2.0 * s.noise_sigma, 2.0 * s.resolution, OFFSET_FLOOR)

    def describe(self, p):
        when = f", {dated(p, 'since')}" if "since" in p or "until" in p else ""
        if "drift" in p:
            return f"{self.component} drifts {p['drift']:+.3g} per s ({self._drifted(p):+.4g} by the end){when}"
        return f"{self.component} reads {p['offset']:+.4g} off{when}"
