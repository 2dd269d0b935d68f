"""Pump dead zone: no flow below an input threshold, q = gain*max(u - u0, 0)."""
from __future__ import annotations

from .base import Mechanism


class PumpDeadZone(Mechanism):
    name = "pump_dead_zone"
    hidden = ("umax",)  # the input's range: scales bounds and the negligible test

    def edit(self, model, p):
        model.find("pump", self.component).input_offset = max(0.0, float(p["threshold"]))

    @classmethod
    def candidates(cls, model, loc):
        out = []
        for p in model.pumps:
            if p.to not in loc.tanks or p.input_offset > 0:
                continue
            umax = next((i.max for i in model.inputs if i.name == p.input and i.max is not None), 1.0)
            out.append(cls(p.name, {"threshold": 0.01 * umax}, {"threshold": (0.0, 0.5 * umax)},
                           {"umax": umax}))
        return out

    def negligible(self, p, model):
        return p["threshold"] < 0.01 * self.fixed.get("umax", 1.0)

    def describe(self, p):
        return f"{self.component} delivers nothing below {p['threshold']:.3g} (input units)"
