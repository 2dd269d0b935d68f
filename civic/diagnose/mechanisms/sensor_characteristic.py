"""Sensor characteristic: a non-linear level -> signal map, y = gain*q**exponent + offset.

Beyond `sensor_offset` (a shift of a linear map): a level sensor (pressure cell,
float, ultrasound) whose reading bends with the level. Offset, gain (a factor on the
model's) and exponent are fitted.
"""
from __future__ import annotations

import copy as _copy

import numpy as np

from ..compare import INVENTORY_BAND, INVENTORY_SPREAD
from .base import Mechanism
from .sensor_offset import drives_no_flow


class SensorCharacteristic(Mechanism):
    name = "sensor_characteristic"
    hidden = ("base", "base_gain", "range")  # the model's own offset and gain; the readings' range

    def edit(self, model, p):
        self.edit_sensor(model.find("sensor", self.component), p)

    def edit_sensor(self, s, p):
        s.exponent = float(p["exponent"])
        s.offset = float(self.fixed.get("base", 0.0)) + float(p["offset"])
        s.gain = float(self.fixed.get("base_gain", 1.0)) * float(p["gain"])

    @classmethod
    def candidates(cls, model, loc):
        out = []
        for s in model.sensors:
            if s.name not in loc.signals_present or s.tank not in loc.tanks or s.exponent != 1.0:
                continue
            span = max(loc.signal_span.get(s.name, 1.0), 1e-6)
            out.append(cls(s.name, {"exponent": 1.02, "offset": 0.0, "gain": 1.0},
                           {"exponent": (0.5, 2.0), "offset": (-0.25 * span, 0.25 * span), "gain": (0.2, 3.0)},
                           {"base": s.offset, "base_gain": s.gain,
                            "range": getattr(loc, "signal_range", {}).get(s.name)}))
        return out

    def negligible(self, p, model):
        s = model.find("sensor", self.component)
        rng = self.fixed.get("range")
        if model.total_volume is not None and drives_no_flow(model, s.tank) and rng is not None:
            # seen through the inventory alone (as an offset there): over the readings' range the
            # map must move the tank's volume beyond the fill's band, or it is the fill's error
            ys = np.linspace(rng[0], rng[1], 21)
            fitted = s.copy() if hasattr(s, "copy") else _copy.copy(s)
            self.edit_sensor(fitted, p)
            q0, q1 = s.invert(ys), fitted.invert(ys)
            scale = model.tank(s.tank).area if s.quantity == "level" else 1.0
            band = INVENTORY_BAND * INVENTORY_SPREAD * model.total_volume
            if float(np.max(np.abs(q1 - q0))) * scale <= band:
                return True
        return abs(p["exponent"] - 1.0) < 0.03 and abs(p["gain"] - 1.0) < 0.03 and \
            abs(p["offset"]) < max(2.0 * s.noise_sigma, 2.0 * s.resolution)

    def describe(self, p):
        return f"{self.component} = {p['gain']:.3g}*gain*level**{p['exponent']:.3g} {p['offset']:+.3g}"
