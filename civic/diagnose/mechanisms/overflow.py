"""Overflow: a tank spills over a rim lower than its datasheet capacity (or spills at all)."""
from __future__ import annotations

from civic.plant.model import OUTSIDE, Overflow as OverflowSpec

from .base import Mechanism, lower_tanks


class Overflow(Mechanism):
    name = "overflow"

    def edit(self, model, p):
        tk = model.tank(self.component)
        tk.overflow = OverflowSpec(to=p["to"], volume=float(p["volume"]))

    @classmethod
    def candidates(cls, model, loc):
        out = []
        dests = lower_tanks(model) + [OUTSIDE]
        for tk in model.tanks:
            if tk.name in loc.plateaus:
                # measured tank sitting at a level it never exceeds: the rim is that level
                vol = loc.plateaus[tk.name]
                if vol < tk.rim_volume() - 0.02 * max(vol, 1e-9):
                    for d in dests:
                        if d != tk.name:
                            out.append(cls(tk.name, {}, {}, {"volume": round(vol, 4), "to": d}))
            elif tk.name in loc.unmeasured and tk.name in loc.tanks:
                # unmeasured tank: the rim is a free parameter
                hi = min(tk.rim_volume(), loc.max_volume.get(tk.name, tk.rim_volume()))
                if not hi < float("inf"):
                    hi = 10.0 * tk.area
                lo = 0.3 * hi
                for d in dests:
                    if d != tk.name:
                        out.append(cls(tk.name, {"volume": 0.8 * hi}, {"volume": (lo, hi)}, {"to": d}))
        return out

    def describe(self, p):
        return f"{self.component} spills above {p['volume']:.4g} L into {p['to']}"
