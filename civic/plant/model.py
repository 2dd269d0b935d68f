"""Plant model: a data description of tanks, pumps, valves, links and sensors.

The model file is TOML (see civic/plant/README.md for the schema). A model is
plain data: `civic diagnose` edits copies (adds a leak link, a dead time, a
sensor offset...) and re-simulates them with civic.plant.simulate.
"""
from __future__ import annotations

import copy
import math
from dataclasses import MISSING, dataclass, field, fields
from pathlib import Path
import numpy as np

from civic.errors import CivicError
from civic.files import read_toml

DATASHEET = Path(__file__).resolve().parents[2] / "configs" / "plant.toml"   # docs/plant.md as a model file
OUTSIDE = "outside"
LAWS = ("orifice", "bidirectional")
QUANTITIES = ("volume", "level")


@dataclass
class Input:
    name: str
    wire: str | None = None          # wire field (p1, v1, v2) or None
    wire_scale: float = 1.0          # wire units per physical unit
    min: float | None = None
    max: float | None = None


@dataclass
class Overflow:
    to: str = OUTSIDE                # tank name or "outside"
    level: float | None = None       # rim level, dm
    volume: float | None = None      # rim volume, L (neither: the tank's capacity)
    fraction: float = 1.0            # share of the spill that goes to `to`
    rest: str = OUTSIDE              # where the other 1 - fraction goes (tank or "outside")

    def targets(self) -> list[tuple[str, float]]:
        """(destination, share) of the spill; shares add up to 1."""
        if self.fraction >= 1.0:
            return [(self.to, 1.0)]
        return [(self.to, self.fraction), (self.rest, 1.0 - self.fraction)]


@dataclass
class Tank:
    name: str
    area: float
    capacity: float = math.inf
    overflow: Overflow | None = None

    def rim_volume(self) -> float:
        o = self.overflow
        if o is None:
            return math.inf
        if o.volume is not None:
            return float(o.volume)
        if o.level is not None:
            return float(o.level) * self.area
        return self.capacity


@dataclass
class Pump:
    name: str
    input: str
    from_: str
    to: str
    gain: float
    dead_time: float = 0.0
    closure: float = 0.0
    onset: float = 0.0               # the closure acts from this time on (s from the first sample)
    until: float = math.inf          # ... and up to this time (the valve opened again)
    min_source_volume: float = 0.0
    head_coeff: float = 0.0
    input_offset: float = 0.0


@dataclass
class Valve:
    name: str
    input: str
    tau: float = 0.0
    dead_time: float = 0.0
    characteristic: float | str = "linear"

    def exponent(self) -> float:
        c = self.characteristic
        if isinstance(c, str):
            if c == "linear":
                return 1.0
            raise CivicError(f"valve {self.name}: characteristic must be 'linear' or an exponent, not {c!r}")
        return float(c)


@dataclass
class Link:
    name: str
    from_: str
    to: str
    coeff: float
    law: str = "orifice"
    valve: str | None = None
    closure: float = 0.0
    onset: float = 0.0               # the closure acts from this time on (s from the first sample)
    since: float = 0.0               # the link passes nothing before this time (a leak that opened)
    until: float = math.inf          # a closure acts up to this time; without one, the link passes
                                     # nothing from then on (a leak repaired)
    exponent: float = 0.5
    min_level: float = 0.0


@dataclass
class Sensor:
    name: str
    tank: str
    quantity: str = "volume"
    gain: float = 1.0
    offset: float = 0.0
    noise_sigma: float = 0.0
    resolution: float = 0.0
    min: float | None = None
    max: float | None = None
    wire: str | None = None
    wire_scale: float = 1.0
    exponent: float = 1.0   # characteristic y = gain * quantity**exponent + offset (1: linear)
    shift: float = 0.0      # added to the offset from `since` on: a sensor knocked or re-zeroed mid-run
    drift: float = 0.0      # per second, added from `since` on: a sensor that drifts (fouling, ageing)
    since: float = 0.0      # s from the first sample
    until: float = math.inf  # a step ends here (a knocked sensor set right again, a glitch over)
    curvature: float = 0.0  # a quadratic term: y = gain*q + curvature*(q - pivot)**2 + offset (exponent 1)
    pivot: float = 0.0

    @property
    def moves(self) -> bool:
        """Its offset changes during the record (a step or a drift from `since` on)."""
        return bool(self.shift or self.drift)

    def offset_at(self, t=None):
        """The offset in force at times `t` (s; None: at the first sample)."""
        if not self.moves:
            return self.offset
        if t is None:
            return self.offset + (self.shift if self.since <= 0.0 < self.until else 0.0)
        t = np.asarray(t, float)
        stepped = (t >= self.since - 1e-9) & (t < self.until - 1e-9)
        return self.offset + np.where(stepped, self.shift, 0.0) + self.drift * np.maximum(t - self.since, 0.0)

    def read(self, q, t=None):
        """The reading for a quantity at times `t` (before noise, resolution and clip)."""
        if self.curvature:
            return self.gain * q + self.curvature * (np.asarray(q, float) - self.pivot) ** 2 + self.offset_at(t)
        if self.exponent == 1.0:
            return self.gain * q + self.offset_at(t)
        return self.gain * np.maximum(q, 0.0) ** self.exponent + self.offset_at(t)

    def invert(self, y):
        """The quantity a reading at the first sample stands for (inverse of `read`; 0 when the
        gain is 0)."""
        if not self.gain:
            return 0.0 * np.asarray(y, float)
        if self.curvature:
            # c u^2 + g u = r with u = q - pivot: the root on the rising branch (g + 2 c u > 0)
            g, c = self.gain, self.curvature
            r = np.asarray(y, float) - self.offset_at() - g * self.pivot
            return self.pivot + 2.0 * r / (g + np.sqrt(np.maximum(g * g + 4.0 * c * r, 0.0)))
        q = (np.asarray(y, float) - self.offset_at()) / self.gain
        if self.exponent == 1.0:
            return q
        return np.maximum(q, 0.0) ** (1.0 / self.exponent)


_SECTIONS = (("tank", "tanks", Tank), ("pump", "pumps", Pump), ("valve", "valves", Valve),
             ("link", "links", Link), ("sensor", "sensors", Sensor))
_FLOAT_FIELDS = {"area", "capacity", "gain", "dead_time", "closure", "min_source_volume", "head_coeff",
                 "input_offset", "tau", "coeff", "exponent", "min_level", "offset", "noise_sigma",
                 "resolution", "min", "max", "wire_scale", "level", "volume", "fraction", "onset", "since",
                 "until", "shift", "drift", "curvature", "pivot"}


def _key(name: str) -> str:
    return "from" if name == "from_" else name


def _build(cls, raw: dict, where: str):
    if not isinstance(raw, dict):
        raise CivicError(f"{where}: expected a table")
    known = {f.name: f for f in fields(cls)}
    kw = {}
    for k, v in raw.items():
        attr = "from_" if k == "from" else k
        if attr not in known:
            raise CivicError(f"{where}: unknown key {k!r} (known: {', '.join(_key(n) for n in known)})")
        if attr == "overflow":
            v = _build(Overflow, v, f"{where}.overflow")
        elif attr in _FLOAT_FIELDS and v is not None:
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                raise CivicError(f"{where}: {k} must be a number, not {v!r}")
            v = float(v)
        elif attr == "characteristic" and not isinstance(v, str):
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                raise CivicError(f"{where}: characteristic must be 'linear' or a number")
            v = float(v)
        kw[attr] = v
    missing = [f.name for f in fields(cls)
               if f.name not in kw and f.default is MISSING and f.default_factory is MISSING]
    if missing:
        raise CivicError(f"{where}: missing {', '.join(_key(m) for m in missing)}")
    return cls(**kw)


def _dump(obj) -> dict:
    out = {}
    for f in fields(obj):
        v = getattr(obj, f.name)
        if v is None or (isinstance(obj, Overflow) and f.name in ("fraction", "rest") and v == f.default) \
                or (isinstance(obj, Sensor) and f.name == "exponent" and v == f.default) \
                or (f.name in ("onset", "since", "until", "shift", "drift", "curvature", "pivot") and v == f.default):
            continue
        if isinstance(v, Overflow):
            v = _dump(v)
        out[_key(f.name)] = v
    return out


@dataclass
class PlantModel:
    name: str = "plant"
    dt: float = 0.1
    substeps: int = 2
    total_volume: float | None = None   # water the closed circuit holds (L), if the datasheet states it
    inputs: list[Input] = field(default_factory=list)
    tanks: list[Tank] = field(default_factory=list)
    pumps: list[Pump] = field(default_factory=list)
    valves: list[Valve] = field(default_factory=list)
    links: list[Link] = field(default_factory=list)
    sensors: list[Sensor] = field(default_factory=list)

    # ---- construction / serialisation -------------------------------------------------
    @classmethod
    def from_dict(cls, d: dict, where: str = "model") -> "PlantModel":
        m = d.get("model", {})
        unknown = set(d) - {"model", "inputs", "tank", "pump", "valve", "link", "sensor"}
        if unknown:
            raise CivicError(f"{where}: unknown section(s) {', '.join(sorted(unknown))}")
        bad = set(m) - {"name", "dt", "substeps", "total_volume"}
        if bad:
            raise CivicError(f"{where}: [model] unknown key(s) {', '.join(sorted(bad))}")
        try:
            total = m.get("total_volume")
            model = cls(name=str(m.get("name", "plant")), dt=float(m.get("dt", 0.1)),
                        substeps=int(m.get("substeps", 2)),
                        total_volume=None if total is None else float(total))
        except (TypeError, ValueError) as exc:
            raise CivicError(f"{where}: [model]: {exc}") from exc
        for name, spec in d.get("inputs", {}).items():
            spec = dict(spec) if isinstance(spec, dict) else {}
            spec["name"] = name
            model.inputs.append(_build(Input, spec, f"{where}: inputs.{name}"))
        for key, attr, klass in _SECTIONS:
            rows = d.get(key, [])
            if not isinstance(rows, list):
                raise CivicError(f"{where}: [[{key}]] must be an array of tables")
            for i, raw in enumerate(rows):
                getattr(model, attr).append(_build(klass, raw, f"{where}: {key}[{i}]"))
        # inputs referenced by actuators but not declared: plain physical inputs
        declared = {i.name for i in model.inputs}
        for a in model.pumps + model.valves:
            if a.input not in declared:
                model.inputs.append(Input(a.input))
                declared.add(a.input)
        model.validate(where)
        return model

    @classmethod
    def from_toml(cls, path: str | Path) -> "PlantModel":
        return cls.from_dict(read_toml(path, "model "), where=str(path))

    def to_dict(self) -> dict:
        d = {"model": {"name": self.name, "dt": self.dt, "substeps": self.substeps},
             "inputs": {}}
        if self.total_volume is not None:
            d["model"]["total_volume"] = self.total_volume
        for i in self.inputs:
            spec = _dump(i)
            spec.pop("name")
            d["inputs"][i.name] = spec
        for key, attr, _ in _SECTIONS:
            d[key] = [_dump(x) for x in getattr(self, attr)]
        return d

    def to_toml(self, path: str | Path | None = None) -> str:
        d = self.to_dict()
        lines = ["[model]"] + [f"{k} = {_toml_value(v)}" for k, v in d["model"].items()]
        lines += ["", "[inputs]"] + [f"{_toml_key(k)} = {_toml_value(v)}" for k, v in d["inputs"].items()]
        for key, _, _ in _SECTIONS:
            for row in d[key]:
                lines += ["", f"[[{key}]]"] + [f"{_toml_key(k)} = {_toml_value(v)}" for k, v in row.items()]
        text = "\n".join(lines) + "\n"
        if path is not None:
            Path(path).write_text(text)
        return text

    def copy(self) -> "PlantModel":
        return copy.deepcopy(self)

    def phases(self) -> list[tuple[float, "PlantModel"]]:
        """(start time, model in force) in time order: a closure with an onset acts from its onset
        on (a manual valve closed, a line clogged mid-record), a link with a `since` passes nothing
        before it (a leak that opened), and either ends at its `until` (the valve opened again,
        the leak repaired); one phase when there is none of these."""
        late = sorted({x.onset for x in self.pumps + self.links if x.closure and x.onset > 0}
                      | {lk.since for lk in self.links if lk.since > 0}
                      | {x.until for x in self.pumps + self.links if math.isfinite(x.until)})
        if not late:
            return [(0.0, self)]
        out = []
        for t0 in [0.0] + late:
            m = self.from_time(t0)
            for x in m.pumps + m.links:
                if x.onset > 0:             # not yet
                    x.closure, x.onset = 0.0, 0.0
            for lk in m.links:
                if lk.since > 0:            # not yet there
                    lk.closure, lk.onset, lk.since = 1.0, 0.0, 0.0
            for x in m.pumps + m.links:
                x.until = math.inf          # what ends later is another phase
            out.append((t0, m))
        return out

    def from_time(self, t0: float) -> "PlantModel":
        """The model as it stands `t0` seconds in: onsets and `since` times that have passed act
        from the start, later ones move t0 earlier (a record cut at t0); an `until` that has
        passed ends what it ended (a closure open again, a repaired leak passing nothing)."""
        m = copy.copy(self)
        m.pumps, m.links = [copy.copy(x) for x in self.pumps], [copy.copy(x) for x in self.links]
        m.sensors = [copy.copy(s) for s in self.sensors]
        for x in m.pumps + m.links:
            if x.until <= t0:
                # a closure ends (a pump's `until` ends nothing else); a link without one ends
                x.closure = 0.0 if x.closure or isinstance(x, Pump) else 1.0
                x.onset, x.until = 0.0, math.inf
            elif math.isfinite(x.until):
                x.until -= t0
            if x.closure and x.onset > 0:
                x.onset = max(x.onset - t0, 0.0)
        for x in m.sensors:
            if x.drift and x.since < t0:     # what it drifted by t0 stands from the start
                x.shift += x.drift * (t0 - x.since)
            if x.until <= t0:                # a step that ended is gone
                x.shift, x.until = 0.0, math.inf
            elif math.isfinite(x.until):
                x.until -= t0
        for x in m.links + m.sensors:
            x.since = max(x.since - t0, 0.0)
        return m

    # ---- names ------------------------------------------------------------------------
    @property
    def input_names(self) -> list[str]:
        return [i.name for i in self.inputs]

    @property
    def signal_names(self) -> list[str]:
        return [s.name for s in self.sensors]

    @property
    def state_names(self) -> list[str]:
        return [t.name for t in self.tanks] + [v.name for v in self.valves]

    @property
    def tank_names(self) -> list[str]:
        return [t.name for t in self.tanks]

    def tank(self, name: str) -> Tank:
        return self.find("tank", name)

    def find(self, kind: str, name: str):
        attr = {"tank": "tanks", "pump": "pumps", "valve": "valves", "link": "links",
                "sensor": "sensors", "input": "inputs"}.get(kind)
        if attr is None:
            raise CivicError(f"unknown component kind {kind!r}")
        for x in getattr(self, attr):
            if x.name == name:
                return x
        raise CivicError(f"model {self.name}: no {kind} named {name!r}")

    def get(self, path: str):
        """'link.pipe23.coeff' -> value; 'tank.T1.overflow.level' also works."""
        parts = path.split(".")
        if len(parts) < 3:
            raise CivicError(f"bad parameter path {path!r} (kind.name.attribute)")
        obj = self.find(parts[0], parts[1])
        for p in parts[2:]:
            p = "from_" if p == "from" else p
            if not hasattr(obj, p):
                raise CivicError(f"{path}: no attribute {p!r}")
            obj = getattr(obj, p)
        return obj

    def set(self, path: str, value) -> None:
        parts = path.split(".")
        if len(parts) < 3:
            raise CivicError(f"bad parameter path {path!r} (kind.name.attribute)")
        obj = self.find(parts[0], parts[1])
        for p in parts[2:-1]:
            obj = getattr(obj, p)
        last = "from_" if parts[-1] == "from" else parts[-1]
        if not hasattr(obj, last):
            raise CivicError(f"{path}: no attribute {last!r}")
        setattr(obj, last, value)

    # ---- checks -----------------------------------------------------------------------
    def validate(self, where: str = "model") -> None:
        if not (self.dt > 0):
            raise CivicError(f"{where}: dt must be > 0")
        if self.substeps < 1:
            raise CivicError(f"{where}: substeps must be >= 1")
        if self.total_volume is not None and not (self.total_volume > 0 and math.isfinite(self.total_volume)):
            raise CivicError(f"{where}: total_volume must be a positive number of litres")
        if not self.tanks:
            raise CivicError(f"{where}: no [[tank]]")
        for kind, items in (("input", self.inputs), ("tank", self.tanks), ("pump", self.pumps),
                            ("valve", self.valves), ("link", self.links), ("sensor", self.sensors)):
            names = [x.name for x in items]
            dup = {n for n in names if names.count(n) > 1}
            if dup:
                raise CivicError(f"{where}: duplicate {kind} name(s) {', '.join(sorted(dup))}")
        tanks = set(self.tank_names)
        if OUTSIDE in tanks:
            raise CivicError(f"{where}: a tank may not be called {OUTSIDE!r}")
        valves = {v.name for v in self.valves}
        inputs = set(self.input_names)
        for s in self.sensors:
            if not (s.exponent > 0 and math.isfinite(s.exponent)):
                raise CivicError(f"{where}: sensor {s.name}: exponent must be > 0")
            if not (math.isfinite(s.curvature) and math.isfinite(s.pivot)):
                raise CivicError(f"{where}: sensor {s.name}: curvature and pivot must be finite")
            if s.curvature and s.exponent != 1.0:
                raise CivicError(f"{where}: sensor {s.name}: a quadratic term (curvature) or an exponent, not both")
            if not (s.since >= 0 and math.isfinite(s.since)):
                raise CivicError(f"{where}: sensor {s.name}: since must be a time >= 0 s")
            if not math.isfinite(s.drift):
                raise CivicError(f"{where}: sensor {s.name}: drift must be a finite rate")
            if not s.until > s.since:
                raise CivicError(f"{where}: sensor {s.name}: until must be a time after since")
            if math.isfinite(s.until) and s.drift:
                raise CivicError(f"{where}: sensor {s.name}: until ends a step (shift), not a drift")
        for t in self.tanks:
            if not (t.area > 0):
                raise CivicError(f"{where}: tank {t.name}: area must be > 0")
            if t.overflow is not None:
                if not 0.0 <= t.overflow.fraction <= 1.0:
                    raise CivicError(f"{where}: tank {t.name}: overflow fraction must lie in [0, 1]")
                for dest in (t.overflow.to, t.overflow.rest):
                    if dest != OUTSIDE and dest not in tanks:
                        raise CivicError(f"{where}: tank {t.name}: overflow to unknown tank {dest!r}")
                    if dest == t.name:
                        raise CivicError(f"{where}: tank {t.name}: overflows into itself")
                if not math.isfinite(t.rim_volume()):
                    raise CivicError(f"{where}: tank {t.name}: overflow needs a level, volume or capacity")
        self._overflow_order(where)
        for p in self.pumps:
            for end in (p.from_, p.to):
                if end != OUTSIDE and end not in tanks:
                    raise CivicError(f"{where}: pump {p.name}: unknown tank {end!r}")
            if p.input not in inputs:
                raise CivicError(f"{where}: pump {p.name}: unknown input {p.input!r}")
            if p.dead_time < 0:
                raise CivicError(f"{where}: pump {p.name}: dead_time must be >= 0")
        for x in self.pumps + self.links:
            if not 0.0 <= x.closure <= 1.0:
                raise CivicError(f"{where}: {x.name}: closure must lie in [0, 1]")
            if not (x.onset >= 0 and math.isfinite(x.onset)):
                raise CivicError(f"{where}: {x.name}: onset must be a time >= 0 s")
            if not x.until > max(x.onset, getattr(x, "since", 0.0)):
                raise CivicError(f"{where}: {x.name}: until must be a time after onset and since")
        for lk in self.links:
            if not (lk.since >= 0 and math.isfinite(lk.since)):
                raise CivicError(f"{where}: {lk.name}: since must be a time >= 0 s")
        for v in self.valves:
            if v.input not in inputs:
                raise CivicError(f"{where}: valve {v.name}: unknown input {v.input!r}")
            if v.tau < 0 or v.dead_time < 0:
                raise CivicError(f"{where}: valve {v.name}: tau and dead_time must be >= 0")
            v.exponent()
        for link in self.links:
            if link.law not in LAWS:
                raise CivicError(f"{where}: link {link.name}: law must be one of {', '.join(LAWS)}")
            if link.from_ not in tanks:
                raise CivicError(f"{where}: link {link.name}: unknown tank {link.from_!r}")
            if link.to != OUTSIDE and link.to not in tanks:
                raise CivicError(f"{where}: link {link.name}: unknown tank {link.to!r}")
            if link.law == "bidirectional" and link.to == OUTSIDE:
                raise CivicError(f"{where}: link {link.name}: a bidirectional link needs two tanks")
            if link.valve is not None and link.valve not in valves:
                raise CivicError(f"{where}: link {link.name}: unknown valve {link.valve!r}")
            if not (link.exponent > 0):
                raise CivicError(f"{where}: link {link.name}: exponent must be > 0")
        for s in self.sensors:
            if s.tank not in tanks:
                raise CivicError(f"{where}: sensor {s.name}: unknown tank {s.tank!r}")
            if s.quantity not in QUANTITIES:
                raise CivicError(f"{where}: sensor {s.name}: quantity must be volume or level")
        wires = [x.wire for x in self.inputs + self.sensors if x.wire]
        dup = {w for w in wires if wires.count(w) > 1}
        if dup:
            raise CivicError(f"{where}: wire field(s) used twice: {', '.join(sorted(dup))}")

    def _overflow_order(self, where: str = "model") -> list[int]:
        """Tank indices ordered so that a tank spills before the tank it spills into."""
        order, state = [], {}

        def visit(i):
            if state.get(i) == 1:
                raise CivicError(f"{where}: overflow cycle through tank {self.tanks[i].name}")
            if state.get(i) == 2:
                return
            state[i] = 1
            t = self.tanks[i]
            # a tank must spill before its target: visit the sources first
            for j, s in enumerate(self.tanks):
                if s.overflow is not None and any(d == t.name for d, _ in s.overflow.targets()):
                    visit(j)
            state[i] = 2
            order.append(i)

        for i in range(len(self.tanks)):
            visit(i)
        return [i for i in order if self.tanks[i].overflow is not None]

    @property
    def wire_fields(self) -> list[str]:
        return [x.wire for x in self.sensors + self.inputs if x.wire]


def _toml_key(k: str) -> str:
    return k if k.replace("_", "").replace("-", "").isalnum() else '"' + k + '"'


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        if math.isnan(v):
            return "nan"
        return repr(v)
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{_toml_key(k)} = {_toml_value(x)}" for k, x in v.items()) + " }"
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise CivicError(f"cannot write {v!r} to TOML")
