"""Sensor saturation: the reading clips at a maximum below the datasheet's range."""
from __future__ import annotations

from .base import Mechanism


class SensorSaturation(Mechanism):
    name = "sensor_saturation"

    def edit(self, model, p):
        model.find("sensor", self.component).max = float(p["max"])

    @classmethod
    def candidates(cls, model, loc):
        out = []
        for s in model.sensors:
            v = loc.sensor_plateaus.get(s.name)
            if v is not None and (s.max is None or v < s.max - max(s.resolution, 1e-9) * 1.5):
                out.append(cls(s.name, {}, {}, {"max": v}))
        return out

    def describe(self, p):
        return f"{self.component} clips at {p['max']:.4g}"
