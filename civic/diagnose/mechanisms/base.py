"""Base class of the mechanism catalogue (one small subclass per family).

A `Mechanism` is one hypothesis about what the nominal model leaves out: a
family name (`leak`, `dead_time`...), the component it sits on (model names:
T3, P1, V2, pipe23, L1...), a vector of free parameters with bounds, and
`apply(model, theta) -> model` that edits a *copy* of the model so that it
contains the mechanism. `candidates(model, loc)` proposes the instances worth
fitting given a localisation (`civic.diagnose.locate.Localisation`).
Parameters in `fixed` are set from the data (e.g. a plateau level) and not
optimised; they still count in the information criterion.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from civic.plant.model import PlantModel


@dataclass
class Mechanism:
    component: str | None
    params: dict = field(default_factory=dict)       # name -> initial value (optimised)
    bounds: dict = field(default_factory=dict)       # name -> (lo, hi)
    fixed: dict = field(default_factory=dict)        # name -> value (not optimised, reported)
    name = "mechanism"
    counted = True      # fixed numbers set from the data count in the BIC; False: they are references
    late = False        # edits after the others (it reads what they set, e.g. a fitted sensor map)
    hidden = ()         # fixed entries for the edit only (not in values() nor the report)
    # fixed entries that bracket a switch-on or switch-off time: not parameters
    BRACKET = ("not_before", "not_after", "until_not_before", "until_not_after")

    # ---- parameter vector ---------------------------------------------------------------
    @property
    def names(self) -> list[str]:
        return list(self.params)

    @property
    def x0(self) -> np.ndarray:
        return np.array([float(self.params[k]) for k in self.names])

    @property
    def lower(self) -> np.ndarray:
        return np.array([self.bounds[k][0] for k in self.names], float)

    @property
    def upper(self) -> np.ndarray:
        return np.array([self.bounds[k][1] for k in self.names], float)

    @property
    def n_params(self) -> int:
        n = len(self.params)
        if self.counted:
            n += sum(1 for k, v in self.fixed.items()
                     if k not in self.BRACKET and isinstance(v, (int, float)) and not isinstance(v, bool))
        return n

    @property
    def switched_on(self) -> float | None:
        """The time it acts from, when it was switched on mid-run (a closure's `onset`, a leak's
        `since`); None: from the start."""
        key = self.switch_key
        return None if key is None else float(self.fixed[key])

    @property
    def switch_key(self) -> str | None:
        """The fixed value that holds the time it was switched on (`onset`, `since`), if any."""
        return next((k for k in ("onset", "since") if k in self.fixed), None)

    @property
    def switched_off(self) -> float | None:
        """The time it stops acting, when it was switched off again mid-run (`until`: a closure
        opened again, a leak repaired); None: to the end."""
        return float(self.fixed["until"]) if "until" in self.fixed else None

    def values(self, theta=None) -> dict:
        out = dict(self.params) if theta is None else {k: float(v) for k, v in zip(self.names, theta)}
        out.update({k: v for k, v in self.fixed.items() if k not in self.hidden})
        return out

    def with_values(self, theta) -> "Mechanism":
        m = type(self)(self.component, {k: float(v) for k, v in zip(self.names, theta)},
                       dict(self.bounds), dict(self.fixed))
        return m

    def with_fixed(self, **fixed) -> "Mechanism":
        """A copy with some fixed values changed (e.g. the time it was switched on)."""
        return type(self)(self.component, dict(self.params), dict(self.bounds), {**self.fixed, **fixed})

    # ---- model edit -----------------------------------------------------------------------
    def apply(self, model: PlantModel, theta=None) -> PlantModel:
        """A copy of `model` that contains this mechanism (parameters `theta` or the current ones)."""
        m = model.copy()
        self.edit(m, self.values(theta))
        return m

    def edit(self, model: PlantModel, p: dict) -> None:  # in place, on a copy
        raise NotImplementedError

    @classmethod
    def candidates(cls, model: PlantModel, loc) -> list["Mechanism"]:
        return []

    def active_rows(self, model: PlantModel, volumes: np.ndarray):
        """Rows of a simulation of `model` (tank volumes, one row per sample) where it acts;
        None: everywhere (a flow law, a sensor map, a coefficient)."""
        return self.acting_at(np.arange(len(volumes)) * model.dt)

    @property
    def standing(self) -> bool:
        """Acting over the whole record: switched neither on nor off mid-run."""
        return self.switched_on is None and self.switched_off is None

    def acting_at(self, t: np.ndarray):
        """Which of the times `t` (s) fall between its switch-on and switch-off; None when it is
        `standing`."""
        if self.standing:
            return None
        t0, t1 = self.switched_on, self.switched_off
        return (t >= (t0 or 0.0)) & (t < (np.inf if t1 is None else t1))

    def negligible(self, p: dict, model: PlantModel) -> bool:
        """True when the fitted effect is too small to matter physically (not a finding,
        however significant statistically): e.g. an offset below the sensor noise."""
        return False

    def variant_of(self, other: "Mechanism") -> bool:
        """The same mechanism on the same component (another form of it, or switched on or off
        at other times): never an alternative explanation of the other."""
        return (self.name, self.component) == (other.name, other.component)

    # ---- reporting ------------------------------------------------------------------------
    @property
    def label(self) -> str:
        extra = f"->{self.fixed['to']}" if "to" in self.fixed else ""
        if self.switch_key:             # switched on mid-run: a variant beside the standing one
            extra += f" from {self.switched_on:g} s"
        if self.switched_off is not None:   # ... and off again
            extra += f" until {self.switched_off:g} s"
        return f"{self.name}({self.component}{extra})"

    def describe(self, p: dict) -> str:
        return ", ".join(f"{k}={_fmt(v)}" for k, v in p.items())

    def report_parameters(self, theta=None) -> dict:
        return {k: (round(float(v), 6) if isinstance(v, (int, float)) and not isinstance(v, bool) else v)
                for k, v in self.values(theta).items()}


def _fmt(v) -> str:
    return f"{v:.4g}" if isinstance(v, float) else str(v)


def tanks_touching(model: PlantModel, tank: str) -> set[str]:
    """The tank and every tank a link, pump or overflow connects it to."""
    out = {tank}
    for lk in model.links:
        if tank in (lk.from_, lk.to):
            out |= {lk.from_, lk.to}
    for p in model.pumps:
        if tank in (p.from_, p.to):
            out |= {p.from_, p.to}
    for t in model.tanks:
        if t.overflow is not None:
            ends = {t.name} | {d for d, _ in t.overflow.targets()}
            if tank in ends:
                out |= ends
    out.discard("outside")
    return out


def tanks_of(model: PlantModel, component: str) -> set[str]:
    """The tanks a component acts on: a tank itself, a pump's or a link's two ends (a valve's:
    those of the links it sets), a sensor's tank."""
    if component in model.tank_names:
        return {component}
    out = set()
    for x in model.pumps + model.links:
        if component in (x.name, getattr(x, "valve", None)):
            out |= {x.from_, x.to}
    out |= {s.tank for s in model.sensors if s.name == component}
    return out & set(model.tank_names)


def spell_times(key: str, span) -> dict:
    """The fixed times of a variant switched on (at `key`: `onset`, `since`) at a
    `locate.Span`'s start and off at its end, each with the bracket the data give it."""
    return {key: span.on, "not_before": span.on_lo, "not_after": span.on_hi,
            **ended_times(span.off, span.off_lo, span.off_hi)}


def ended_times(t: float, lo: float, hi: float) -> dict:
    """The fixed times of a variant acting from the start until `t`, bracketed by `lo`, `hi`."""
    return {"until": t, "until_not_before": lo, "until_not_after": hi}


RIM_SHARE = 0.02   # a plateau within 2 % below a tank's rim is at the rim
ONSET_Z = 5.0      # a change point (Localisation.onsets) this many standard errors: worth a fit


def dated(p: dict, key: str) -> str:
    """'from T s on' for a mechanism switched on at p[key], with the bracket the data give that
    time (`not_before`, `not_after`) when it is not a point, and 'until T s' for one switched off
    again (`until`, its bracket `until_not_before`, `until_not_after`)."""
    text = ""
    if key in p:
        lo, hi = p.get("not_before", p[key]), p.get("not_after", p[key])
        text = f"from {p[key]:g} s on"
        if hi - lo > 1e-9:
            text += f" (the change came between {lo:g} and {hi:g} s)"
    if "until" in p:
        lo, hi = p.get("until_not_before", p["until"]), p.get("until_not_after", p["until"])
        text = f"{text} until {p['until']:g} s".lstrip()
        if hi - lo > 1e-9:
            text += f" (it ended between {lo:g} and {hi:g} s)"
    return text


def below_rim(tank, vol: float) -> bool:
    """A plateau at `vol` litres sits below `tank`'s rim (beyond RIM_SHARE): a lower rim's, an
    overflow candidate's; at or above it the tank is at its rim."""
    return vol < tank.rim_volume() - RIM_SHARE * max(vol, 1e-9)


def unmeasured_top(tank, loc) -> float:
    """The highest volume an unmeasured tank's rim can have: its rim, or the most it holds in the
    simulation, or 10 level units when neither is finite."""
    top = min(tank.rim_volume(), loc.max_volume.get(tank.name, tank.rim_volume()))
    return top if top < float("inf") else 10.0 * tank.area


def free_run(loc) -> bool:
    """A real rig seen through a free-run simulation (some tank unmeasured): where the shape of
    the physics (flow laws, sensor maps, actuator thresholds) is a candidate, refitted jointly
    with the nominal coefficients."""
    return loc.kind == "simulation" and bool(loc.unmeasured)


def drives_no_flow(model: PlantModel, tank: str) -> bool:
    """No link leaves the tank and none exchanges both ways with it (a reservoir): its
    level changes no flow, only the inventory sees an offset on its sensor."""
    return not any(lk.from_ == tank or (lk.law == "bidirectional" and lk.to == tank) for lk in model.links)


def sensors_of(model: PlantModel, tank: str) -> list:
    return [s for s in model.sensors if s.tank == tank]


def lower_tanks(model: PlantModel) -> list[str]:
    """Tanks that receive water by gravity (orifice links, overflows): where leaks can end."""
    out = []
    for lk in model.links:
        if lk.law == "orifice" and lk.to != "outside" and lk.to not in out:
            out.append(lk.to)
    for t in model.tanks:
        for d, _ in t.overflow.targets() if t.overflow is not None else ():
            if d != "outside" and d not in out:
                out.append(d)
    for p in model.pumps:
        if p.from_ != "outside" and p.from_ not in out:
            out.append(p.from_)
    return out
