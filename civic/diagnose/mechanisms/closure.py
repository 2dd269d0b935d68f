"""Closure from a time on: a line that passes a share less from its onset (a manual valve partly
closed, a clog: the plant's VM1 on the drain, VM2 on the pump line) — a fault switched on mid-run,
and possibly off again (`until`: the valve opened again)."""
from __future__ import annotations

import math

from .base import ONSET_Z, Mechanism, dated, ended_times, spell_times
from .coefficient import CAL_SPREAD


class Closure(Mechanism):
    name = "closure"

    def edit(self, model, p):
        kind = "pump" if any(x.name == self.component for x in model.pumps) else "link"
        x = model.find(kind, self.component)
        x.closure, x.onset = float(p["closure"]), float(p.get("onset", 0.0))
        x.until = float(p.get("until", math.inf))

    @classmethod
    def candidates(cls, model, loc):
        """Where the localisation found a pump or link whose flow the residual follows by a
        larger share from a time on (`Localisation.onsets`), that share a loss; and, where it did so
        only for a while (`Localisation.spans`), one that ended."""
        out = []
        for comp, (t0, z, share, lo, hi) in getattr(loc, "onsets", {}).items():
            if z >= ONSET_Z and share > 1.5 * CAL_SPREAD:
                out.append(cls(comp, {"closure": float(min(share, 0.9))}, {"closure": (0.0, 0.95)},
                               {"onset": t0, "not_before": lo, "not_after": hi}))
            elif z >= ONSET_Z and share < -1.5 * CAL_SPREAD:   # passes more from then on: opened again
                out.append(cls(comp, {"closure": float(min(-share, 0.9))}, {"closure": (0.0, 0.95)},
                               ended_times(t0, lo, hi)))
        for comp, sp in getattr(loc, "spans", {}).items():
            if sp.z >= ONSET_Z and sp.share > 1.5 * CAL_SPREAD:
                out.append(cls(comp, {"closure": float(min(sp.share, 0.9))}, {"closure": (0.0, 0.95)},
                               spell_times("onset", sp)))
        return out

    def negligible(self, p, model):
        return p["closure"] <= 1.5 * CAL_SPREAD      # within calibration territory

    def describe(self, p):
        return (f"{self.component} passes {100 * p['closure']:.0f} % less {dated(p, 'onset')}, as a manual "
                "valve partly closed or a clog would (a fault switched on or off mid-run)")
