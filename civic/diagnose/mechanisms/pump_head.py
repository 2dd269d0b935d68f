"""Pump head: the flow falls with the delivery tank's level, q *= 1 - k*h_to."""
from __future__ import annotations

from .base import Mechanism


class PumpHead(Mechanism):
    name = "pump_head"
    counted = False
    hidden = ("hmax",)  # highest delivery level seen: scales bounds and the negligible test

    def edit(self, model, p):
        model.find("pump", self.component).head_coeff = max(0.0, float(p["head_coeff"]))

    @classmethod
    def candidates(cls, model, loc):
        out = []
        for p in model.pumps:
            if p.to != "outside" and {p.from_, p.to} & set(loc.tanks):
                hmax = max(loc.max_level.get(p.to, 1.0), 1e-3)
                out.append(cls(p.name, {"head_coeff": 0.05 / hmax}, {"head_coeff": (0.0, 0.9 / hmax)},
                               {"hmax": round(hmax, 6)}))
        return out

    def negligible(self, p, model):
        return p["head_coeff"] * self.fixed.get("hmax", 1.0) < 0.02   # < 2 % flow change

    def describe(self, p):
        return f"{self.component} flow *= 1 - {p['head_coeff']:.3g}*h"
