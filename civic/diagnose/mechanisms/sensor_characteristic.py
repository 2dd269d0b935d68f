"""Sensor characteristic: a non-linear level -> signal map, y = gain*q**exponent + offset.

Beyond `sensor_offset` (a shift of a linear map): a level sensor (pressure cell,
float, ultrasound) whose reading bends with the level. Offset, gain (a factor on the
model's) and exponent are fitted.
"""
from __future__ import annotations

from .base import Mechanism, free_run


class SensorCharacteristic(Mechanism):
    name = "sensor_characteristic"
    hidden = ("base", "base_gain")  # the model's own offset and gain

    def edit(self, model, p):
        s = model.find("sensor", self.component)
        s.exponent = float(p["exponent"])
        s.offset = float(self.fixed.get("base", 0.0)) + float(p["offset"])
        s.gain = float(self.fixed.get("base_gain", 1.0)) * float(p["gain"])

    @classmethod
    def candidates(cls, model, loc):
        out = []
        if not free_run(loc):
            return out
        for s in model.sensors:
            if s.name not in loc.signals_present or s.tank not in loc.tanks or s.exponent != 1.0:
                continue
            span = max(loc.signal_span.get(s.name, 1.0), 1e-6)
            out.append(cls(s.name, {"exponent": 1.02, "offset": 0.0, "gain": 1.0},
                           {"exponent": (0.5, 2.0), "offset": (-0.25 * span, 0.25 * span), "gain": (0.2, 3.0)},
                           {"base": s.offset, "base_gain": s.gain}))
        return out

    def negligible(self, p, model):
        s = model.find("sensor", self.component)
        return abs(p["exponent"] - 1.0) < 0.03 and abs(p["gain"] - 1.0) < 0.03 and \
            abs(p["offset"]) < max(2.0 * s.noise_sigma, 2.0 * s.resolution)

    def describe(self, p):
        return f"{self.component} = {p['gain']:.3g}*gain*level**{p['exponent']:.3g} {p['offset']:+.3g}"
