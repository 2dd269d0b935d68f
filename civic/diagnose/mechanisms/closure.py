"""Closure from a time on: a line that passes a share less from its onset (a manual valve partly
closed, a clog: the plant's VM1 on the drain, VM2 on the pump line) — a fault switched on mid-run."""
from __future__ import annotations

from .base import ONSET_Z, Mechanism, dated
from .coefficient import CAL_SPREAD


class Closure(Mechanism):
    name = "closure"

    def edit(self, model, p):
        kind = "pump" if any(x.name == self.component for x in model.pumps) else "link"
        x = model.find(kind, self.component)
        x.closure, x.onset = float(p["closure"]), float(p["onset"])

    @classmethod
    def candidates(cls, model, loc):
        """Where the localisation found a pump or link whose flow the residual follows by a
        larger share from a time on (`Localisation.onsets`), that share a loss."""
        out = []
        for comp, (t0, z, share, lo, hi) in getattr(loc, "onsets", {}).items():
            if z >= ONSET_Z and share > 1.5 * CAL_SPREAD:
                out.append(cls(comp, {"closure": float(min(share, 0.9))}, {"closure": (0.0, 0.95)},
                               {"onset": t0, "not_before": lo, "not_after": hi}))
        return out

    def negligible(self, p, model):
        return p["closure"] <= 1.5 * CAL_SPREAD      # within calibration territory

    def describe(self, p):
        return (f"{self.component} passes {100 * p['closure']:.0f} % less {dated(p, 'onset')}, as a manual "
                "valve partly closed or a clog would (a fault switched on mid-run)")
