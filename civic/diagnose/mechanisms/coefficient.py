"""Coefficient: a link's flow coefficient or a pump's gain off by more than the calibration spread."""
from __future__ import annotations

from .base import Mechanism

CAL_SPREAD = 0.05   # datasheet spread: coefficients move this much as calibration, not as a finding


def coefficient_paths(model, tanks=None) -> list[tuple[str, str]]:
    """(component, parameter path) of the model's coefficients, optionally near some tanks."""
    out = []
    for p in model.pumps:
        if tanks is None or {p.from_, p.to} & set(tanks):
            out.append((p.name, f"pump.{p.name}.gain"))
    for lk in model.links:
        if tanks is None or {lk.from_, lk.to} & set(tanks):
            out.append((lk.name, f"link.{lk.name}.coeff"))
    return out


class Coefficient(Mechanism):
    name = "coefficient"
    counted = False     # path and nominal value are references, the factor is the parameter

    def edit(self, model, p):
        model.set(self.fixed["path"], float(self.fixed["nominal"]) * float(p["factor"]))

    def values(self, theta=None):
        v = super().values(theta)
        v["value"] = float(v["nominal"]) * float(v["factor"])
        return v

    @classmethod
    def candidates(cls, model, loc):
        out = []
        idle = set(getattr(loc, "idle_links", ()))
        for comp, path in coefficient_paths(model, loc.tanks):
            if path.startswith("link.") and comp in idle:
                continue   # no flow through it in this record: its coefficient is not identifiable
            nominal = float(model.get(path))
            if nominal > 0:
                out.append(cls(comp, {"factor": 1.0}, {"factor": (0.3, 3.0)},
                               {"path": path, "nominal": nominal}))
        return out

    def negligible(self, p, model):
        return abs(p["factor"] - 1.0) <= 1.5 * CAL_SPREAD   # within calibration territory

    def describe(self, p):
        change = (p["factor"] - 1) * 100
        text = f"{p['path']} = {p['value']:.4g} ({change:+.0f} % vs nominal)"
        if change < 0:
            # what a user meets on a test run with a hand valve partly closed (VM1, VM2): the same
            # coefficient as a worn or clogged part; one switched on mid-run is a dated `closure`
            verb = "delivers" if p["path"].startswith("pump.") else "passes"
            text += (f": {self.component} {verb} {-change:.0f} % less than its datasheet over the whole record, "
                     "as a manual valve partly closed on its line or a clog would")
        return text
