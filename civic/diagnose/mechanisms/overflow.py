"""Overflow: a tank spills over a rim lower than its datasheet capacity (or spills at all).

Where the spilling tank is unmeasured and the tank below it is measured (e.g. the
Cascaded Tanks' upper tank over the lower one), the spill may also be split: a
`fraction` falls into the measured tank, the rest leaves the plant ("outside").
"""
from __future__ import annotations

import numpy as np

from civic.plant.model import OUTSIDE, Link, Overflow as OverflowSpec

from .base import Mechanism, below_rim, free_run, lower_tanks, unmeasured_top


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
                clipped.setdefault(s.tank, (_volume_at(model, s, v), s.name, float(v)))
        for tk in model.tanks:
            if tk.name in loc.plateaus:
                # measured tank sitting at a level it never exceeds: the rim is that level
                vol = loc.plateaus[tk.name]
                if below_rim(tk, vol):
                    # a plateau at the sensor's clip: the rim follows a sensor map fitted with it
                    at_clip = tk.name in clipped and abs(clipped[tk.name][0] - vol) <= 0.02 * max(vol, 1e-9)
                    for d in dests:
                        if d != tk.name:
                            out.append(AtClip(tk.name, {}, {}, {"volume": round(vol, 4), "to": d,
                                                                 "sensor": clipped[tk.name][1],
                                                                 "reading": clipped[tk.name][2]}, model=model)
                                       if at_clip else cls(tk.name, {}, {}, {"volume": round(vol, 4), "to": d}))
                    if model.total_volume is not None:
                        # part of the spill leaves the circuit (splashes past the tank below):
                        # only the inventory can tell the share, so only with a stated total
                        for d in dests:
                            if d not in (tk.name, OUTSIDE):
                                out.append(cls(tk.name, {"fraction": 0.6}, {"fraction": (0.0, 1.0)},
                                               {"volume": round(vol, 4), "to": d, "rest": OUTSIDE}))
            elif tk.name in clipped:
                # its sensor sits at the clip value the model already has: is the tank spilling
                # there too (level held at the rim) rather than rising on unseen? The rim is
                # where the sensor clips, also under a sensor map fitted with it (`AtClip`)
                vol, sensor, reading = clipped[tk.name]
                if below_rim(tk, vol):
                    for d in dests:
                        if d != tk.name:
                            out.append(AtClip(tk.name, {}, {}, {"volume": round(vol, 4), "to": d,
                                                                 "sensor": sensor, "reading": reading}, model=model))
            elif tk.name in loc.unmeasured and tk.name in loc.tanks:
                # unmeasured tank: the rim is a free parameter
                hi = unmeasured_top(tk, loc)
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

    def onset_volume(self, model) -> float:
        """Litres above which it acts, in a model it has edited: its rim."""
        return float(model.tank(self.component).rim_volume())

    def active_rows(self, model, volumes):
        """Where the tank is at or above the volume where it acts."""
        return volumes[:, model.tank_names.index(self.component)] >= self.onset_volume(model) * (1 - 1e-6)


def _volume_at(model, s, reading: float) -> float:
    """The tank volume at which sensor `s` gives `reading` (e.g. its clip value)."""
    q = float(s.invert(reading))
    return q * model.tank(s.tank).area if s.quantity == "level" else q


class AtClip(Overflow):
    """A measured tank that spills where its sensor clips: the rim is the volume at which the
    sensor gives its clip reading, read from the model being edited (`late`: after a sensor map fitted
    jointly has moved that volume). With the rim fixed at the nominal map's clip instead, a
    refitted map put the clip far below the rim on half of the Cascaded Tanks record (the
    tank stored water above the sensor's range and drained too late after an overflow).
    `volume` is reported at the nominal map; the model file carries the fitted one."""

    late = True
    hidden = ("reading", "at_nominal")   # the clip reading (from the data), its volume under the nominal map

    def __init__(self, component, params=None, bounds=None, fixed=None, model=None):
        super().__init__(component, params or {}, bounds or {}, dict(fixed or {}))
        if model is not None and "at_nominal" not in self.fixed:
            self.fixed["at_nominal"] = _volume_at(model, model.find("sensor", self.fixed["sensor"]),
                                                  self.fixed["reading"])

    @property
    def n_params(self) -> int:
        return 1            # the rim, as for a fixed-rim overflow

    def edit(self, model, p):
        # the data's rim moved as the clip volume moves from the nominal map to the model's
        tk = model.tank(self.component)
        s = model.find("sensor", self.fixed["sensor"])
        nominal = max(float(self.fixed["at_nominal"]), 1e-12)
        clip = _volume_at(model, s, self.fixed["reading"])
        tk.overflow = OverflowSpec(to=p["to"], volume=float(p["volume"]) * clip / nominal)

    def describe(self, p):
        return f"{self.component} spills where {p['sensor']} clips (nominal map: {p['volume']:.4g} L) into {p['to']}"


def spill_onset(model, tank: str) -> float:
    """Litres above which the spill link of `tank` (the last one added) acts: its crest."""
    lk = next(x for x in reversed(model.links) if x.from_ == tank and x.name.startswith("spill_"))
    return lk.min_level * model.tank(tank).area


def spill_link_name(model, tank: str) -> str:
    """A free link name for a spill from `tank`: spill_T1, spill_T1_, ..."""
    name = f"spill_{tank}"
    while any(lk.name == name for lk in model.links):
        name += "_"
    return name


SPILL_HEADROOM = 0.05   # the instant overflow moves this fraction of the rim volume up


class Spill(Overflow):
    """A finite spill over the rim: q = c*(h - h_rim)**n to the overflow's destination.

    The datasheet overflow is instantaneous (the level never exceeds the rim). A real
    weir needs a head above its crest to pass a flow: the level sits above the rim by
    (q_in / c)**(1/n). Expressed with the existing schema, mass exact: an orifice link
    `{from=tank, to=dest, law="orifice", min_level=rim level, coeff=c, exponent=n}` and
    the instant overflow moved `SPILL_HEADROOM` x the rim volume up (the wall above the
    crest: still a hard top, reached only if c is far too small for the inflow). The
    rim stays the model's (a reference, not counted); c is fitted, n fixed at 1 (one
    inflow level in a record cannot separate n from c). Candidate for a measured tank
    whose level reaches the rim (at or above it).
    """

    counted = False
    hidden = ("rim_level", "exponent")

    def edit(self, model, p):
        tk = model.tank(self.component)
        rim_level = float(p["rim_level"])
        name = spill_link_name(model, self.component)
        model.links.append(Link(name=name, from_=self.component, to=p["to"], coeff=float(p["c"]),
                                law="orifice", exponent=float(p.get("exponent", 1.0)),
                                min_level=rim_level))
        tk.overflow = OverflowSpec(to=tk.overflow.to, volume=rim_level * tk.area * (1 + SPILL_HEADROOM),
                                   fraction=tk.overflow.fraction, rest=tk.overflow.rest)

    def onset_volume(self, model) -> float:
        return spill_onset(model, self.component)

    @property
    def label(self) -> str:
        return f"{self.name}({self.component}->{self.fixed['to']}, finite spill)"

    def values(self, theta=None) -> dict:
        out = super().values(theta)
        out["rim_level"] = self.fixed["rim_level"]
        out["exponent"] = self.fixed.get("exponent", 1.0)
        return out

    def report_parameters(self, theta=None) -> dict:
        p = super().report_parameters(theta)
        return {"c": p["c"], "rim_level": p["rim_level"], "exponent": p["exponent"], "to": p["to"]}

    @classmethod
    def candidates(cls, model, loc):
        out = []
        measured = {model.find("sensor", s).tank for s in loc.signals_present}
        for tk in model.tanks:
            o = tk.overflow
            if tk.name not in measured or tk.name not in loc.tanks or o is None or o.fraction < 1.0:
                continue
            rim = tk.rim_volume()
            if not np.isfinite(rim) or tk.name not in loc.at_rim:
                continue
            if any(lk.from_ == tk.name and lk.law == "orifice" and lk.min_level > 0 for lk in model.links):
                continue   # a spill link already there: its coefficient is a `coefficient` finding
            cmax = 100.0 * max([lk.coeff for lk in model.links] + [p.gain for p in model.pumps] + [0.1])
            out.append(cls(tk.name, {"c": 0.1 * cmax}, {"c": (1e-3 * cmax, cmax)},
                           {"to": o.to, "rim_level": rim / tk.area, "exponent": 1.0}))
        return out

    def describe(self, p):
        return (f"{self.component} spills to {p['to']} as q = {p['c']:.4g}*(h - {p['rim_level']:.4g} dm)"
                f"^{p['exponent']:.3g} (finite, not instantaneous)")


class Weir(Spill):
    """A finite spill over a crest below the datasheet rim, the crest fitted: a measured tank
    whose level plateaus below its rim (an overflow pipe, a notch). q = c*(h - crest) to the
    destination (an orifice link with min_level = crest, exponent 1); the datasheet rim stays
    the wall's hard top. Two free parameters, c and the crest (below the plateau)."""

    counted = True
    hidden = ("exponent", "area")

    @property
    def n_params(self) -> int:
        return 2

    def report_parameters(self, theta=None) -> dict:
        p = super().report_parameters(theta)
        area = self.fixed["area"]
        # the same law per litre: q = c_volume*(V - volume)
        return {**p, "volume": round(p["rim_level"] * area, 6), "c_volume": round(p["c"] / area, 6)}

    def edit(self, model, p):
        name = spill_link_name(model, self.component)
        model.links.append(Link(name=name, from_=self.component, to=p["to"], coeff=float(p["c"]),
                                law="orifice", exponent=1.0, min_level=float(p["rim_level"])))

    @property
    def label(self) -> str:
        return f"{self.name}({self.component}->{self.fixed['to']}, weir)"

    def values(self, theta=None) -> dict:
        out = Mechanism.values(self, theta)
        out["exponent"] = 1.0
        return out

    @classmethod
    def candidates(cls, model, loc):
        out = []
        measured = {model.find("sensor", s).tank for s in loc.signals_present}
        cmax = 100.0 * max([lk.coeff for lk in model.links] + [p.gain for p in model.pumps] + [0.1])
        for tk in model.tanks:
            vol = loc.plateaus.get(tk.name)
            if vol is None or tk.name not in measured or not below_rim(tk, vol):
                continue
            top = vol / tk.area
            # over the wall the spill goes where the datasheet overflow goes (if it has one)
            dests = [tk.overflow.to] if tk.overflow is not None else lower_tanks(model) + [OUTSIDE]
            for d in dests:
                if d != tk.name:
                    out.append(cls(tk.name, {"c": 0.01 * cmax, "rim_level": 0.97 * top},
                                   {"c": (1e-4 * cmax, cmax), "rim_level": (0.85 * top, top)},
                                   {"to": d, "area": tk.area}))
        return out


class SpillOut(Overflow):
    """An unmeasured tank that loses water to outside above a crest just below its rim (free run):
    q = c*(h - crest) out of the plant, an orifice link with min_level = crest and exponent 1
    (existing schema), next to the tank's split overflow at the rim. On Cascaded Tanks the
    upper tank's water partly leaves the rig before its level reaches the rim that holds it
    (the outflow jet missing the lower tank at high head, or a slow spill over an uneven rim:
    one record cannot tell which); a finite loss *into* the tank below, or this loss instead of
    the split spill, did not explain the record (docs/diagnose.md). Free: c and `crest`, the
    crest as a fraction of the rim the model has when this edits (`late`: after a split spill
    fitted with it; a crest fitted as a level of its own sat above the fitted rim on half the
    record, the loss never active). Without an
    overflow on the tank the rim is the candidate's range top. The exponent is fixed at 1 (1.5
    and a free exponent fitted and transferred alike). Its own slot in the free-run joint fit
    (`general_key`), beside the split spill."""

    late = True
    general_key = "spill_out"
    hidden = ("top",)     # litres: the rim when the tank has none

    def edit(self, model, p):
        model.links.append(Link(name=spill_link_name(model, self.component), from_=self.component, to=p["to"],
                                coeff=float(p["c"]), law="orifice", exponent=1.0,
                                min_level=self.crest_level(model, p)))

    def crest_level(self, model, p) -> float:
        tk = model.tank(self.component)
        rim = tk.rim_volume() if tk.overflow is not None else float("inf")
        if not np.isfinite(rim):
            rim = float(self.fixed["top"])
        return float(p["crest"]) * rim / tk.area

    def onset_volume(self, model) -> float:
        """Litres above which it acts, in a model it has edited: its link's crest."""
        return spill_onset(model, self.component)

    @property
    def label(self) -> str:
        return f"{self.name}({self.component}->{self.fixed['to']}, below the rim)"

    @classmethod
    def candidates(cls, model, loc):
        out = []
        if not free_run(loc):
            return out
        for tk in model.tanks:
            if tk.name not in loc.unmeasured or tk.name not in loc.tanks:
                continue
            top = unmeasured_top(tk, loc)
            c0 = _outflow_scale(model, tk.name)
            out.append(cls(tk.name, {"c": 0.2 * c0, "crest": 0.9}, {"c": (1e-3 * c0, 10.0 * c0), "crest": (0.5, 1.0)},
                           {"to": OUTSIDE, "top": top}))
        return out

    def negligible(self, p, model):
        # under 1 % of the tank's outflow coefficient per level unit above the crest
        return float(p["c"]) < 0.01 * _outflow_scale(model, self.component)

    def describe(self, p):
        return (f"{self.component} loses q = {p['c']:.4g}*(h - crest) to {p['to']} above a crest at "
                f"{100 * p['crest']:.0f} % of its rim")


def _outflow_scale(model, tank: str) -> float:
    """The largest coefficient of the links draining `tank` (a scale for a spill's c)."""
    return max([lk.coeff for lk in model.links if lk.from_ == tank] + [1e-3])
