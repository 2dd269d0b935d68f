"""Dead time of a pump or valve (command -> effect) longer or shorter than the datasheet's."""
from __future__ import annotations

from .base import Mechanism


class DeadTime(Mechanism):
    name = "dead_time"

    def edit(self, model, p):
        kind = "pump" if any(x.name == self.component for x in model.pumps) else "valve"
        model.find(kind, self.component).dead_time = max(0.0, float(p["dead_time"]))

    @classmethod
    def candidates(cls, model, loc):
        out = []
        hi = max(10.0, 20 * model.dt)
        for p in model.pumps:
            if {p.from_, p.to} & set(loc.tanks):
                out.append(cls(p.name, {"dead_time": p.dead_time + 2 * model.dt}, {"dead_time": (0.0, hi)}))
        for v in model.valves:
            tanks = {t for lk in model.links if lk.valve == v.name for t in (lk.from_, lk.to)}
            if tanks & set(loc.tanks):
                out.append(cls(v.name, {"dead_time": v.dead_time + 2 * model.dt}, {"dead_time": (0.0, hi)}))
        return out

    def negligible(self, p, model):
        # within 1.5 samples of the datasheet: the messages' own timing (a command recorded up to a
        # period before it acts) cannot tell it apart; the bundled clean case fits V1 0.1 s late at
        # held-out BIC -9.5, and with 1 % of its messages lost at -14.5
        kind = "pump" if any(x.name == self.component for x in model.pumps) else "valve"
        return abs(p["dead_time"] - model.find(kind, self.component).dead_time) < 1.5 * model.dt

    def describe(self, p):
        return f"{self.component} acts {p['dead_time']:.3g} s after its command"
