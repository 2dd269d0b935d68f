"""Overflow: a tank spills over a rim lower than its datasheet capacity (or spills at all).

Where the spilling tank is unmeasured and the tank below it is measured (e.g. the
Cascaded Tanks' upper tank over the lower one), the spill may also be split: a
`fraction` falls into the measured tank, the rest leaves the plant ("outside").
"""
from __future__ import annotations

from civic.plant.model import OUTSIDE, Overflow as OverflowSpec

from .base import Mechanism, lower_tanks


class Overflow(Mechanism):
    name = "overflow"

    def edit(self, model, p):
        tk = model.tank(self.component)
        tk.overflow = OverflowSpec(to=p["to"], volume=float(p["volume"]),
                                   fraction=float(p.get("fraction", 1.0)), rest=p.get("rest", OUTSIDE))

    @property
    def label(self) -> str:
        if "fraction" in self.params:
            return f"{self.name}({self.component}->{self.fixed['to']}|{self.fixed['rest']})"
        return super().label

    @classmethod
    def candidates(cls, model, loc):
        out = []
        dests = lower_tanks(model) + [OUTSIDE]
        measured = {model.find("sensor", s).tank for s in loc.signals_present}
        clipped = {}
        for s in model.sensors:
            v = loc.sensor_plateaus.get(s.name)
            if v is not None and s.max is not None and v >= s.max - 1.5 * max(s.resolution, 1e-9) and s.gain:
                q = (v - s.offset) / s.gain
                clipped.setdefault(s.tank, q * model.tank(s.tank).area if s.quantity == "level" else q)
        for tk in model.tanks:
            if tk.name in loc.plateaus:
                # measured tank sitting at a level it never exceeds: the rim is that level
                vol = loc.plateaus[tk.name]
                if vol < tk.rim_volume() - 0.02 * max(vol, 1e-9):
                    for d in dests:
                        if d != tk.name:
                            out.append(cls(tk.name, {}, {}, {"volume": round(vol, 4), "to": d}))
            elif tk.name in clipped:
                # its sensor sits at the clip value the model already has: is the tank spilling
                # there too (level held at the rim) rather than rising on unseen?
                vol = clipped[tk.name]
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
                # into a measured tank: the share that falls there is a free parameter too
                for d in dests:
                    if d != tk.name and d in measured:
                        out.append(cls(tk.name, {"volume": 0.8 * hi, "fraction": 0.6},
                                       {"volume": (lo, hi), "fraction": (0.0, 1.0)}, {"to": d, "rest": OUTSIDE}))
        return out

    def describe(self, p):
        if "fraction" in p:
            return (f"{self.component} spills above {p['volume']:.4g} L: {100 * p['fraction']:.0f} % into "
                    f"{p['to']}, the rest to {p['rest']}")
        return f"{self.component} spills above {p['volume']:.4g} L into {p['to']}"
