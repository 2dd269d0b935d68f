"""Sensor offset: y = gain*quantity + offset with an offset the datasheet does not have, from
the start or from a time on (a sensor knocked or re-zeroed mid-run: its reading steps)."""
from __future__ import annotations

from ..compare import INVENTORY_BAND, INVENTORY_SPREAD
from .base import Mechanism, dated, drives_no_flow, sensors_of, tanks_touching

OFFSET_FLOOR = 1e-3  # in the sensor's unit: below this no sensor without noise or resolution reads off


class SensorOffset(Mechanism):
    name = "sensor_offset"
    counted = False
    hidden = ("base",)  # the model's own offset, added to the fitted one

    @property
    def n_params(self) -> int:
        return super().n_params + (1 if "since" in self.fixed else 0)   # the time is the data's too

    def edit(self, model, p):
        s = model.find("sensor", self.component)
        if "since" in p:
            s.shift, s.since = float(p["offset"]), float(p["since"])
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
        return out

    def negligible(self, p, model):
        s = model.find("sensor", self.component)
        if model.total_volume is not None and drives_no_flow(model, s.tank):
            # seen through the inventory alone: within the fill's band it is the fill's error
            band = INVENTORY_BAND * INVENTORY_SPREAD * model.total_volume
            litres = abs(p["offset"]) / (s.gain or 1.0) * (model.tank(s.tank).area if s.quantity == "level" else 1.0)
            if litres <= band:
                return True
        return abs(p["offset"]) < max(2.0 * s.noise_sigma, 2.0 * s.resolution, OFFSET_FLOOR)

    def describe(self, p):
        when = f", {dated(p, 'since')}" if "since" in p else ""
        return f"{self.component} reads {p['offset']:+.4g} off{when}"
