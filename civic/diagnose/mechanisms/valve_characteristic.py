"""Valve characteristic: effective opening a**n instead of the linear a."""
from __future__ import annotations

from .base import Mechanism


class ValveCharacteristic(Mechanism):
    name = "valve_characteristic"

    def edit(self, model, p):
        n = float(p["n"])
        model.find("valve", self.component).characteristic = "linear" if abs(n - 1.0) < 1e-12 else n

    @classmethod
    def candidates(cls, model, loc):
        out = []
        for v in model.valves:
            tanks = {t for lk in model.links if lk.valve == v.name for t in (lk.from_, lk.to)}
            if tanks & set(loc.tanks):
                out.append(cls(v.name, {"n": 1.2}, {"n": (0.25, 4.0)}))
        return out

    def negligible(self, p, model):
        return abs(p["n"] - model.find("valve", self.component).exponent()) < 0.05

    def describe(self, p):
        return f"{self.component} passes opening**{p['n']:.3g} (linear = 1)"
