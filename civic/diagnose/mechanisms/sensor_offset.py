"""Sensor offset: y = gain*quantity + offset with an offset the datasheet does not have."""
from __future__ import annotations

from ..compare import INVENTORY_BAND, INVENTORY_SPREAD
from .base import Mechanism, sensors_of, tanks_touching

OFFSET_FLOOR = 1e-3  # in the sensor's unit: below this no sensor without noise or resolution reads off


def drives_no_flow(model, tank: str) -> bool:
    """No link leaves the tank and none exchanges both ways with it (a reservoir): its
    level changes no flow, only the inventory sees an offset on its sensor."""
    return not any(lk.from_ == tank or (lk.law == "bidirectional" and lk.to == tank) for lk in model.links)


class SensorOffset(Mechanism):
    name = "sensor_offset"
    counted = False
    hidden = ("base",)  # the model's own offset, added to the fitted one

    def edit(self, model, p):
        s = model.find("sensor", self.component)
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
                    out.append(cls(s.name, {"offset": 0.0}, {"offset": (-0.25 * span, 0.25 * span)},
                                   {"base": s.offset}))
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
        return f"{self.component} reads {p['offset']:+.4g} off"
