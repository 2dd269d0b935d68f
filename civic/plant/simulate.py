"""Fast fixed-step simulation of a PlantModel.

The model is compiled once (per structure) into generated straight-line Python:
states are local floats, RK4 is unrolled, valve positioners are integrated
exactly (first order under a held command), dead times are exact (each sample
interval is split where a delayed command switches), overflow is an
instantaneous spill that keeps the tank at its rim (split between two
destinations when a fraction is given). Every flow moves water
between two tanks (or "outside", tracked as an accumulator), so the total is
conserved to rounding (1e-12 L).

The same generator emits a numpy variant that runs B simulations at once
(different parameters and/or initial states), for Jacobians in fitting.
"""
from __future__ import annotations

import math
import re
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from civic.errors import CivicError
from civic.plant.model import OUTSIDE, PlantModel
from civic.plant.noise import robust_sigma

__all__ = ["CompiledModel", "compile_model", "simulate", "flows", "Flows", "measure", "to_wire", "from_wire",
           "load_recording", "initial_state", "measured_state", "Recording", "inputs_matrix"]


# ---------------------------------------------------------------------------------------
# compilation
# ---------------------------------------------------------------------------------------
def _delay_split(d: float, dt: float) -> tuple[int, float]:
    r = d / dt
    m = math.floor(r + 1e-9)
    f = r - m
    if f < 1e-9:
        f = 0.0
    return m, f


@dataclass
class _Actuator:
    kind: str      # "pump" or "valve"
    index: int     # index in model.pumps / model.valves
    input: int     # column in U
    m: int         # whole samples of dead time
    f: float       # fractional part (0 <= f < 1), switch point inside the interval


class CompiledModel:
    """A model compiled to a specialised integrator. See civic/plant/README.md."""

    def __init__(self, model: PlantModel):
        model.validate()
        self.model = model.copy()
        m = self.model
        self.dt = m.dt
        self.state_names = m.state_names
        self.input_names = m.input_names
        self.ntanks = len(m.tanks)
        self.nvalves = len(m.valves)
        tidx = {t.name: i for i, t in enumerate(m.tanks)}
        self._tidx = tidx
        iidx = {n: i for i, n in enumerate(m.input_names)}
        # ---- parameters -----------------------------------------------------------
        names, values = [], []

        def par(path, value):
            names.append(path)
            values.append(float(value))
            return f"P[{len(names) - 1}]"

        self._area = [par(f"tank.{t.name}.area", t.area) for t in m.tanks]
        self._rim = {i: par(f"tank.{m.tanks[i].name}.overflow.volume", m.tanks[i].rim_volume())
                     for i in m._overflow_order()}
        self._frac = {i: par(f"tank.{m.tanks[i].name}.overflow.fraction", m.tanks[i].overflow.fraction)
                      for i in self._rim}
        self._pump = []
        for p in m.pumps:
            self._pump.append(dict(
                gain=par(f"pump.{p.name}.gain", p.gain), closure=par(f"pump.{p.name}.closure", p.closure),
                ms=par(f"pump.{p.name}.min_source_volume", p.min_source_volume),
                hc=par(f"pump.{p.name}.head_coeff", p.head_coeff),
                off=par(f"pump.{p.name}.input_offset", p.input_offset)))
        self._valve = []
        for v in m.valves:
            self._valve.append(dict(
                tau=par(f"valve.{v.name}.tau", v.tau) if v.tau > 0 else None,
                n=par(f"valve.{v.name}.characteristic", v.exponent()) if v.exponent() != 1.0 else None))
        self._link = []
        for lk in m.links:
            self._link.append(dict(
                coeff=par(f"link.{lk.name}.coeff", lk.coeff), closure=par(f"link.{lk.name}.closure", lk.closure),
                ex=par(f"link.{lk.name}.exponent", lk.exponent) if lk.exponent != 0.5 else None,
                ml=par(f"link.{lk.name}.min_level", lk.min_level) if lk.law == "orifice" else None))
        self.param_names = names
        self.params = np.array(values, dtype=float)
        # ---- actuators and interval segments ---------------------------------------
        acts = []
        for i, p in enumerate(m.pumps):
            acts.append(_Actuator("pump", i, iidx[p.input], *_delay_split(p.dead_time, m.dt)))
        for i, v in enumerate(m.valves):
            acts.append(_Actuator("valve", i, iidx[v.input], *_delay_split(v.dead_time, m.dt)))
        self._acts = acts
        fr = sorted({0.0} | {a.f for a in acts})
        bounds = fr + [1.0]
        segs = []
        for j in range(len(fr)):
            length = bounds[j + 1] - bounds[j]
            nsteps = max(1, math.ceil(m.substeps * length - 1e-9))
            segs.append((bounds[j], length * m.dt / nsteps, nsteps))
        self._segs = segs
        self._fn = {}

    # ---- code generation --------------------------------------------------------------
    def _source(self, batch: bool) -> str:
        nt, nv = self.ntanks, self.nvalves
        L = []
        emit = L.append
        emit("def _run(n, UA, UB, X0, P, rec, SW=()):")
        ind = "    "
        self._emit_constants(emit, ind, batch)
        for i in range(nt):
            emit(f"{ind}x{i} = X0[{i}]")
        for i in range(nv):
            emit(f"{ind}a{i} = X0[{nt + i}]")
        emit(f"{ind}out = X0[{nt + nv}]")
        state = [f"x{i}" for i in range(nt)] + [f"a{i}" for i in range(nv)] + ["out"]
        emit(f"{ind}rec(({', '.join(state)},))")
        # SW: (sample, parameters) switches in time order (a closure from its onset on)
        emit(f"{ind}sw = iter(SW)")
        emit(f"{ind}kn, Pn = next(sw, (-1, None))")
        emit(f"{ind}for k in range(n - 1):")
        ind2 = ind * 2
        emit(f"{ind2}if k == kn:")
        emit(f"{ind2}{ind}P = Pn")
        self._emit_constants(emit, ind2 + ind, batch)
        emit(f"{ind2}{ind}kn, Pn = next(sw, (-1, None))")
        for j, (f0, h, nsteps) in enumerate(self._segs):
            # held (delayed) commands in this segment
            for ai, a in enumerate(self._acts):
                src = "UA" if (a.f > 0 and f0 < a.f) else "UB"
                var = f"up{a.index}" if a.kind == "pump" else f"uv{a.index}"
                emit(f"{ind2}{var} = {src}[{ai}][k]")
            self._emit_pump_commands(emit, ind2, batch)
            for i, v in enumerate(self._valve):
                if v["tau"] is None:
                    emit(f"{ind2}a{i} = uv{i}")
            body_ind = ind2
            if nsteps > 1:
                emit(f"{ind2}for _s in range({nsteps}):")
                body_ind = ind2 + ind
            self._emit_rk4(emit, body_ind, h, j, batch)
        emit(f"{ind2}rec(({', '.join(state)},))")
        return "\n".join(L) + "\n"

    def _flows_source(self) -> str:
        """Vectorised right-hand side: flows(X tanks, A openings, C pump commands, P)."""
        nt = self.ntanks
        L = []
        emit = L.append
        ind = "    "
        emit("def _flows(X, A, C, P):")
        self._emit_constants(emit, ind, True, lags=False)
        for i in range(nt):
            emit(f"{ind}x{i} = X[{i}]")
        for i, v in enumerate(self._valve):
            emit(f"{ind}e{i} = np.maximum(A[{i}], 0.0) ** NV{i}" if v["n"] is not None else f"{ind}e{i} = A[{i}]")
        for i in range(len(self._pump)):
            emit(f"{ind}up{i} = C[{i}]")
        self._emit_pump_commands(emit, ind, True)
        terms = self._emit_flows(emit, ind, [f"x{i}" for i in range(nt)], True)
        net = [(" ".join(t) or "0.0").removeprefix("+ ") for t in terms]
        pumps = ", ".join(f"q{i}p" for i in range(len(self._pump)))
        links = ", ".join(f"q{i}l" for i in range(len(self._link)))
        emit(f"{ind}return [{pumps}], [{links}], [{', '.join(net)}]")
        return "\n".join(L) + "\n"

    def _emit_pump_commands(self, emit, ind, batch):
        for i in range(len(self._pump)):
            if batch:
                emit(f"{ind}c{i} = G{i} * np.maximum(up{i} - OF{i}, 0.0)")
            else:
                emit(f"{ind}c{i} = G{i} * (up{i} - OF{i} if up{i} > OF{i} else 0.0)")

    def _emit_constants(self, emit, ind, batch, lags=True):
        nt = self.ntanks
        exp = "np.exp" if batch else "exp"
        for i, v in enumerate(self._valve if lags else ()):
            if v["tau"] is not None:
                for j, (_, h, _) in enumerate(self._segs):
                    emit(f"{ind}EH{i}_{j} = {exp}(-{h!r} / {v['tau']})")
                    emit(f"{ind}EM{i}_{j} = {exp}(-{h / 2!r} / {v['tau']})")
        for i in range(nt):
            emit(f"{ind}iA{i} = 1.0 / {self._area[i]}")
        for i, r in self._rim.items():
            emit(f"{ind}R{i} = {r}")
            emit(f"{ind}FR{i} = {self._frac[i]}")
        for i, p in enumerate(self._pump):
            emit(f"{ind}G{i} = {p['gain']} * (1.0 - {p['closure']})")
            emit(f"{ind}MS{i} = {p['ms']}")
            emit(f"{ind}HC{i} = {p['hc']}")
            emit(f"{ind}OF{i} = {p['off']}")
        for i, lk in enumerate(self._link):
            emit(f"{ind}K{i} = {lk['coeff']} * (1.0 - {lk['closure']})")
            if lk["ml"] is not None:
                emit(f"{ind}ML{i} = {lk['ml']}")
            if lk["ex"] is not None:
                emit(f"{ind}EX{i} = {lk['ex']}")
        for i, v in enumerate(self._valve):
            if v["n"] is not None:
                emit(f"{ind}NV{i} = {v['n']}")

    def _emit_rk4(self, emit, ind, h, j, batch):
        nt = self.ntanks
        for s in range(4):
            if s == 0:
                ys = [f"x{i}" for i in range(nt)]
            else:
                c = {1: h / 2, 2: h / 2, 3: h}[s]
                for i in range(nt):
                    emit(f"{ind}y{i} = x{i} + {c!r} * k{s}_{i}")
                ys = [f"y{i}" for i in range(nt)]
            # valve openings at the stage time
            for i, v in enumerate(self._valve):
                if v["tau"] is None or s == 0:
                    base = f"a{i}"
                elif s in (1, 2):
                    base = f"(uv{i} + (a{i} - uv{i}) * EM{i}_{j})"
                else:
                    base = f"(uv{i} + (a{i} - uv{i}) * EH{i}_{j})"
                if s == 2 and v["tau"] is not None:
                    continue  # same as stage 1
                if v["n"] is not None:
                    if batch:
                        emit(f"{ind}e{i} = np.maximum({base}, 0.0) ** NV{i}")
                    else:
                        emit(f"{ind}_o = {base}")
                        emit(f"{ind}e{i} = _o ** NV{i} if _o > 0.0 else 0.0")
                else:
                    emit(f"{ind}e{i} = {base}")
            terms = self._emit_flows(emit, ind, ys, batch)
            for i in range(nt):
                t = " ".join(terms[i]) or "0.0"
                if t.startswith("+ "):
                    t = t[2:]
                emit(f"{ind}k{s + 1}_{i} = {t}")
            t = " ".join(terms[nt]) or "0.0"
            if t.startswith("+ "):
                t = t[2:]
            emit(f"{ind}ko{s + 1} = {t}")
        h6 = h / 6
        for i in range(nt):
            emit(f"{ind}x{i} = x{i} + {h6!r} * (k1_{i} + 2.0 * (k2_{i} + k3_{i}) + k4_{i})")
        emit(f"{ind}out = out + {h6!r} * (ko1 + 2.0 * (ko2 + ko3) + ko4)")
        for i, v in enumerate(self._valve):
            if v["tau"] is not None:
                emit(f"{ind}a{i} = uv{i} + (a{i} - uv{i}) * EH{i}_{j}")
        # overflow: instantaneous spill, sources before their targets; a fraction FR goes
        # to `to`, the rest (computed as spill - share: mass exact) to `rest`
        for i in self._rim:
            ov = self.model.tanks[i].overflow
            dst, rest = ("out" if d == OUTSIDE else f"x{self._tidx[d]}" for d in (ov.to, ov.rest))
            if batch:
                emit(f"{ind}_s = np.maximum(x{i} - R{i}, 0.0)")
                emit(f"{ind}x{i} = x{i} - _s")
            else:
                emit(f"{ind}if x{i} > R{i}:")
                ind, outer = ind + "    ", ind
                emit(f"{ind}_s = x{i} - R{i}")
                emit(f"{ind}x{i} = R{i}")
            emit(f"{ind}_f = FR{i} * _s")
            emit(f"{ind}{dst} = {dst} + _f")
            emit(f"{ind}{rest} = {rest} + (_s - _f)")
            if not batch:
                ind = outer

    def _emit_flows(self, emit, ind, ys, batch) -> list[list[str]]:
        """Emit every pump and link flow (q{i}p, q{i}l) for tank volumes `ys`, pump commands
        c{i} and effective valve openings e{i}; return per tank (last: outside) its terms.
        The integrator's right-hand side and `flows()` are both generated from here."""
        m = self.model
        nt = self.ntanks
        terms = [[] for _ in range(nt + 1)]  # last: outside
        tid = lambda name: nt if name == OUTSIDE else self._tidx[name]  # noqa: E731
        for i, p in enumerate(m.pumps):
            src, dst = tid(p.from_), tid(p.to)
            q = f"q{i}p"
            expr = f"c{i}"
            if batch:
                if dst < nt:
                    expr += f" * np.maximum(1.0 - HC{i} * {ys[dst]} * iA{dst}, 0.0)"
                if src < nt:
                    expr = f"np.where({ys[src]} >= MS{i}, {expr}, 0.0)"
                emit(f"{ind}{q} = {expr}")
            else:
                if dst < nt:
                    emit(f"{ind}_t = 1.0 - HC{i} * {ys[dst]} * iA{dst}")
                    expr = f"(c{i} * _t if _t > 0.0 else 0.0)"
                if src < nt:
                    expr = f"({expr} if {ys[src]} >= MS{i} else 0.0)"
                emit(f"{ind}{q} = {expr}")
            terms[src].append(f"- {q}")
            terms[dst].append(f"+ {q}")
        for i, lk in enumerate(m.links):
            src, dst = tid(lk.from_), tid(lk.to)
            q = f"q{i}l"
            kk = f"K{i}"
            if lk.valve is not None:
                vi = [v.name for v in m.valves].index(lk.valve)
                kk += f" * e{vi}"
            ex = self._link[i]["ex"]
            if lk.law == "orifice":
                emit(f"{ind}_h = {ys[src]} * iA{src} - ML{i}")
                if batch:
                    root = f"np.maximum(_h, 0.0) ** EX{i}" if ex else "np.sqrt(np.maximum(_h, 0.0))"
                    emit(f"{ind}{q} = {kk} * {root}")
                else:
                    root = f"_h ** EX{i}" if ex else "sqrt(_h)"
                    emit(f"{ind}{q} = {kk} * {root} if _h > 0.0 else 0.0")
            else:
                emit(f"{ind}_d = {ys[src]} * iA{src} - {ys[dst]} * iA{dst}")
                if batch:
                    root = f"np.abs(_d) ** EX{i}" if ex else "np.sqrt(np.abs(_d))"
                    emit(f"{ind}{q} = {kk} * np.sign(_d) * {root}")
                else:
                    if ex:
                        emit(f"{ind}{q} = {kk} * _d ** EX{i} if _d >= 0.0 else -{kk} * (-_d) ** EX{i}")
                    else:
                        emit(f"{ind}{q} = {kk} * sqrt(_d) if _d >= 0.0 else -{kk} * sqrt(-_d)")
            terms[src].append(f"- {q}")
            terms[dst].append(f"+ {q}")
        return terms

    def _function(self, batch: bool):
        if batch not in self._fn:
            src = self._source(batch)
            ns = {"np": np, "sqrt": math.sqrt, "exp": math.exp}
            exec(compile(src, f"<plant {self.model.name} {'batch' if batch else 'scalar'}>", "exec"), ns)
            self._fn[batch] = ns["_run"]
        return self._fn[batch]

    def flows_function(self):
        """The generated vectorised right-hand side `_flows(X, A, C, P)` (see `flows`)."""
        if "flows" not in self._fn:
            ns = {"np": np}
            exec(compile(self._flows_source(), f"<plant {self.model.name} flows>", "exec"), ns)
            self._fn["flows"] = ns["_flows"]
        return self._fn["flows"]

    # ---- running ----------------------------------------------------------------------
    def _delayed(self, U: np.ndarray):
        n = U.shape[0]
        UA, UB = [], []
        k = np.arange(n)
        for a in self._acts:
            col = U[:, a.input]
            UA.append(col[np.maximum(k - a.m - 1, 0)])
            UB.append(col[np.maximum(k - a.m, 0)])
        return UA, UB

    def run(self, U, x0, params=None, outside0: float = 0.0, switches=()) -> np.ndarray:
        """States at every sample: (n, nstates) or, batched, (n, nstates, B).

        U: (n, ninputs) held commands (physical units, already limited).
        x0: (nstates,) or (nstates, B). params: None, (nparams,) or (nparams, B).
        switches: (sample k, params) in time order: those parameters from the interval
        [t_k, t_k+1) on (a closure from its onset). Column nstates (the last) of the internal
        record is the cumulative volume sent outside; it is available as `self.last_outside`.
        """
        U = np.asarray(U, dtype=float)
        if U.ndim != 2 or U.shape[1] != len(self.input_names):
            raise CivicError(f"inputs: expected shape (n, {len(self.input_names)}), got {U.shape}")
        n = U.shape[0]
        x0 = np.asarray(x0, dtype=float)
        P = self.params if params is None else np.asarray(params, dtype=float)
        ns = len(self.state_names)
        if x0.shape[0] != ns:
            raise CivicError(f"x0: expected {ns} states ({', '.join(self.state_names)}), got {x0.shape[0]}")
        batch = x0.ndim == 2 or P.ndim == 2
        UA, UB = self._delayed(U)
        out = []
        if batch:
            B = x0.shape[1] if x0.ndim == 2 else P.shape[1]
            X0 = np.empty((ns + 1, B))
            X0[:ns] = x0 if x0.ndim == 2 else x0[:, None]
            X0[ns] = outside0

            def per_run(P):
                return [P[i] if P.ndim == 2 else np.full(B, P[i]) for i in range(P.shape[0])]

            Pl = per_run(P)
            SW = [(int(k), per_run(np.asarray(Pk, dtype=float))) for k, Pk in switches]
            X = np.empty((n, ns + 1, B))
            pos = [0]

            def rec(row):
                X[pos[0]] = row
                pos[0] += 1

            if n:
                self._function(True)(n, UA, UB, list(X0), Pl, rec, SW)
        else:
            UA = [u.tolist() for u in UA]
            UB = [u.tolist() for u in UB]
            X0 = [float(v) for v in x0] + [float(outside0)]
            if n:
                SW = [(int(k), np.asarray(Pk, dtype=float).tolist()) for k, Pk in switches]
                self._function(False)(n, UA, UB, X0, P.tolist(), out.append, SW)
            X = np.array(out, dtype=float).reshape(n, ns + 1)
        self.last_outside = X[:, ns]
        return X[:, :ns]


    def params_for(self, model: PlantModel) -> np.ndarray:
        """The parameter vector of a model with this structure (same param_names)."""
        comp = {}
        for kind, items in (("tank", model.tanks), ("pump", model.pumps), ("valve", model.valves),
                            ("link", model.links)):
            for x in items:
                comp[(kind, x.name)] = x
        out = np.empty(len(self.param_names))
        for i, name in enumerate(self.param_names):
            kind, cname, attr = name.split(".", 2)
            x = comp[(kind, cname)]
            if attr == "overflow.volume":
                out[i] = x.rim_volume()
            elif attr == "overflow.fraction":
                out[i] = x.overflow.fraction
            elif attr == "characteristic":
                out[i] = x.exponent()
            else:
                out[i] = getattr(x, attr)
        return out


def structure_key(model: PlantModel) -> tuple:
    """What the generated code depends on (everything but parameter values)."""
    dt = model.dt
    return (
        dt, model.substeps, tuple(i.name for i in model.inputs),
        tuple((t.name, None if t.overflow is None else (t.overflow.to, t.overflow.rest)) for t in model.tanks),
        tuple((p.name, p.input, p.from_, p.to, _delay_split(p.dead_time, dt)) for p in model.pumps),
        tuple((v.name, v.input, v.tau > 0, v.exponent() != 1.0, _delay_split(v.dead_time, dt))
              for v in model.valves),
        tuple((lk.name, lk.from_, lk.to, lk.law, lk.valve, lk.exponent != 0.5) for lk in model.links),
    )


_CACHE: dict = {}


def compile_model(model: PlantModel) -> CompiledModel:
    """Compile, cached on the model's structure; `cm.params` are the first model's values.

    For another model of the same structure use `cm.params_for(model)` (simulate does).
    """
    key = structure_key(model)
    cm = _CACHE.get(key)
    if cm is None:
        if len(_CACHE) > 256:
            _CACHE.clear()
        cm = _CACHE[key] = CompiledModel(model)
    return cm


@dataclass
class Flows:
    """Instantaneous flows (L/s) at given states; arrays over samples (first axis)."""
    pumps: np.ndarray      # (n, npumps) delivered by each pump (from -> to)
    links: np.ndarray      # (n, nlinks) through each link, positive from -> to
    net: np.ndarray        # (n, ntanks) net inflow of each tank (overflow spill not included)
    outside: np.ndarray    # (n,) net flow to "outside"


def flows(model: PlantModel, volumes, openings, commands, params=None) -> Flows:
    """The model's right-hand side, vectorised: the same generated code as the integrator's.

    volumes (n, ntanks) L; openings (n, nvalves) valve positions (before the
    characteristic); commands (n, npumps) the command each pump acts on now (already
    delayed by its dead time and limited). params: None (the model's values) or a
    vector in `compile_model(model).param_names` order. The instantaneous overflow
    spill is not a flow: it happens between integration steps (see `simulate`).
    """
    cm = compile_model(model)
    V = np.atleast_2d(np.asarray(volumes, float))
    n = V.shape[0]

    def cols(a, k, what):
        a = np.asarray(a, float).reshape(n, -1) if k else np.zeros((n, 0))
        if a.shape != (n, k):
            raise CivicError(f"flows: {what} must have shape ({n}, {k}), got {a.shape}")
        return list(np.asfortranarray(a).T)   # contiguous columns: the generated code runs 2x faster

    if V.shape[1] != cm.ntanks:
        raise CivicError(f"flows: volumes must have shape (n, {cm.ntanks})")
    P = cm.params_for(model) if params is None else np.asarray(params, float)
    qp, ql, net = cm.flows_function()(cols(V, cm.ntanks, "volumes"), cols(openings, cm.nvalves, "openings"),
                                      cols(commands, len(model.pumps), "commands"), list(P))

    def stack(qs):
        out = np.empty((n, len(qs)), order="F")
        for j, q in enumerate(qs):
            out[:, j] = q
        return out

    net = stack(net)
    return Flows(stack(qp), stack(ql), net[:, :cm.ntanks], net[:, cm.ntanks])


# ---------------------------------------------------------------------------------------
# inputs, states, sensors
# ---------------------------------------------------------------------------------------
def inputs_matrix(model: PlantModel, inputs: dict, n: int) -> np.ndarray:
    """(n, ninputs) held commands, limited to each input's min/max; missing inputs are 0."""
    U = np.zeros((n, len(model.inputs)))
    names = set(model.input_names)
    for k in inputs:
        if k not in names:
            raise CivicError(f"model {model.name} has no input {k!r} (inputs: {', '.join(model.input_names)})")
    for j, spec in enumerate(model.inputs):
        if spec.name in inputs:
            v = np.asarray(inputs[spec.name], dtype=float)
            if v.ndim == 0:
                v = np.full(n, float(v))
            if v.shape != (n,):
                raise CivicError(f"input {spec.name}: {v.shape[0]} values for {n} samples")
            U[:, j] = v
        lo = -np.inf if spec.min is None else spec.min
        hi = np.inf if spec.max is None else spec.max
        np.clip(U[:, j], lo, hi, out=U[:, j])
    return U


def _x0_vector(model: PlantModel, x0, U: np.ndarray) -> np.ndarray:
    names = model.state_names
    if isinstance(x0, dict):
        for k in x0:
            if k not in names:
                raise CivicError(f"x0: unknown state {k!r} (states: {', '.join(names)})")
        iidx = {n: i for i, n in enumerate(model.input_names)}
        v = np.zeros(len(names))
        for i, name in enumerate(names):
            if name in x0:
                v[i] = float(x0[name])
            elif i >= len(model.tanks):  # a valve: its first command
                valve = model.valves[i - len(model.tanks)]
                v[i] = U[0, iidx[valve.input]] if len(U) else 0.0
        return v
    v = np.asarray(x0, dtype=float)
    if v.shape[0] != len(names):
        raise CivicError(f"x0: expected {len(names)} values ({', '.join(names)})")
    return v


def measure(model: PlantModel, volumes: np.ndarray, noise: bool = False, rng=None,
            quantize: bool = False, t=None) -> dict:
    """Sensor signals from tank volumes (n, ntanks) (or (n, ntanks, B)) at times `t` (s from
    the first sample; None: the model's sample instants)."""
    idx = {t.name: i for i, t in enumerate(model.tanks)}
    out = {}
    if noise and rng is None:
        rng = np.random.default_rng()
    for s in model.sensors:
        i = idx[s.tank]
        q = volumes[:, i]
        if s.quantity == "level":
            q = q / model.tanks[i].area
        when = None if not s.moves else _column(np.arange(len(q)) * model.dt if t is None else t, q)
        y = s.read(q, when)
        if noise and s.noise_sigma > 0:
            y = y + rng.normal(0.0, s.noise_sigma, size=y.shape)
        if quantize and s.resolution > 0:
            y = np.round(y / s.resolution) * s.resolution
        if s.min is not None or s.max is not None:
            y = np.clip(y, -np.inf if s.min is None else s.min, np.inf if s.max is None else s.max)
        out[s.name] = y
    return out


def _column(t, q):
    """Times shaped to broadcast against a quantity of shape (n,) or (n, B)."""
    t = np.asarray(t, float)
    return t.reshape((-1,) + (1,) * (np.ndim(q) - 1))


def simulate(model: PlantModel, t, inputs: dict, x0, noise: bool = False, seed=None,
             quantize: bool | None = None, params=None) -> dict:
    """Simulate the model on the sample instants t (uniform, step model.dt).

    Returns {sensor: (n,), input: (n,) held command, "t", "volumes" (n, ntanks),
    "openings" (n, nvalves), "outside" (n,)}.
    """
    model.validate()
    t = np.asarray(t, dtype=float)
    n = len(t)
    if n >= 2:
        d = np.diff(t)
        if np.max(np.abs(d - model.dt)) > 1e-6 * max(1.0, model.dt) + 1e-9:
            raise CivicError(f"t must be uniform with step dt = {model.dt} s")
    U = inputs_matrix(model, inputs, n)
    x = _x0_vector(model, x0, U)
    cm = compile_model(model)
    if params is None:
        phases = model.phases()
        params = cm.params_for(phases[0][1])
        switches = [(int(round(t0 / model.dt)), cm.params_for(m)) for t0, m in phases[1:]]
    else:
        switches = ()
    X = cm.run(U, x, params, switches=switches)
    nt = len(model.tanks)
    vol = X[:, :nt]
    rng = np.random.default_rng(seed) if noise else None
    res = measure(model, vol, noise=noise, rng=rng, quantize=noise if quantize is None else quantize,
                  t=t - t[0] if n else t)
    for j, name in enumerate(model.input_names):
        res[name] = U[:, j]
    res["t"] = t
    res["volumes"] = vol
    res["openings"] = X[:, nt:]
    res["outside"] = cm.last_outside.copy()
    return res


# ---------------------------------------------------------------------------------------
# wire units and recordings
# ---------------------------------------------------------------------------------------
def to_wire(model: PlantModel, signals: dict) -> dict:
    """{wire field: int64 (n,)}: round(value * wire_scale), clipped to 0..65535."""
    out = {}
    for spec in model.sensors + model.inputs:
        if spec.wire and spec.name in signals:
            v = np.rint(np.asarray(signals[spec.name], dtype=float) * spec.wire_scale)
            out[spec.wire] = np.clip(np.nan_to_num(v, nan=0.0), 0, 65535).astype(np.int64)
    return out


def from_wire(model: PlantModel, fields) -> dict:
    """{signal: float (n,)} from wire fields (a dict or a structured array)."""
    names = fields.dtype.names if hasattr(fields, "dtype") and fields.dtype.names else list(fields)
    out = {}
    for spec in model.sensors + model.inputs:
        if spec.wire and spec.wire in names:
            out[spec.name] = np.asarray(fields[spec.wire], dtype=float) / spec.wire_scale
    return out


WIRE_COLUMNS = ("l1", "l2", "l3", "l4", "p1", "v1", "v2")   # the plant message's fields


@dataclass
class Recording:
    t: np.ndarray            # seconds from the first sample
    signals: dict            # {signal or input name: physical values}
    fields: dict             # {wire field: int values} (empty for physical CSVs)
    path: str = ""

    def part(self, sl: slice, path: str | None = None) -> "Recording":
        """The samples in `sl`, timed from the first of them (a stretch of a record judged on its
        own, e.g. one half of it)."""
        t = np.asarray(self.t)[sl]
        return Recording(t - t[0], {k: np.asarray(v)[sl] for k, v in self.signals.items()},
                         {k: np.asarray(v)[sl] for k, v in (self.fields or {}).items()},
                         self.path if path is None else path)


TIME_COLUMNS = ("t_s", "t", "time", "time_s")   # CSV time column names, in order of preference


def load_recording(path, model: PlantModel, plant: str | None = None) -> Recording:
    """A pcap (plant messages only) or a CSV (a time column + wire fields or model names).

    pcap: the messages of one plant, `plant` (its IPv4 source address) or the first
    one seen. CSV: a header with a time column (`t_s`, `t`, `time` or `time_s`) and
    either wire fields (l1..v2) or the model's signal/input names in physical units.
    """
    path = str(path)
    if not Path(path).exists():
        raise CivicError(f"{path}: no such file")
    if path.endswith(".csv"):
        if plant is not None:
            raise CivicError(f"{path}: a plant address selects messages in a pcap, not in a CSV")
        return _load_csv(path, model)
    from civic.wire import ip_to_int, read_pcap

    msgs = read_pcap(path).messages
    msgs = msgs[msgs["plant"]]
    if plant is not None:
        msgs = msgs[msgs["src"] == ip_to_int(plant)]
        if len(msgs) == 0:
            raise CivicError(f"{path}: no plant messages from {plant}")
    if len(msgs) == 0:
        raise CivicError(f"{path}: no plant messages")
    msgs = msgs[msgs["src"] == msgs["src"][0]]
    # a capture merged out of time order is put back in it; a message captured twice (the
    # same counter right after itself: a retransmitting tap, a mirrored port) counts once
    msgs = msgs[np.argsort(msgs["t"], kind="stable")]
    msgs = msgs[np.concatenate(([True], msgs["seq"][1:] != msgs["seq"][:-1]))]
    fields = {name: msgs[name].astype(np.int64) for name in WIRE_COLUMNS}
    return Recording(msgs["t"] - msgs["t"][0], from_wire(model, fields), fields, path)


SHORT_GAP = 2     # samples: a run of lost messages this short is interpolated, not a gap


def regularise(rec: Recording, dt: float) -> Recording:
    """Put the samples on the uniform grid k*dt. Missing samples (lost messages): a run of up to
    SHORT_GAP is interpolated linearly in the signals (the fields hold their last value); longer
    runs hold the last value and are flagged in `rec.gaps` (the comparisons ignore them). Every
    5 s balance window touching a flagged sample is left out: with 1 % of the messages lost one
    by one, that was 40 % of them."""
    k = np.rint(np.asarray(rec.t, float) / dt).astype(np.int64)
    k -= k[0]
    n = int(k[-1]) + 1
    if n == len(k) and np.all(np.diff(k) == 1):
        rec.gaps = np.zeros(n, bool)
        return rec
    keep = np.concatenate(([True], np.diff(k) > 0))      # duplicates: first one wins
    k = k[keep]
    if n > 4 * len(k):
        raise CivicError(f"{rec.path}: more than 3/4 of the samples are missing")
    src = np.searchsorted(k, np.arange(n), side="right") - 1  # last received sample
    grid = np.arange(n)
    run = np.diff(k)[np.minimum(src, len(k) - 2)] - 1          # length of the run a sample is in
    gaps = np.ones(n, bool)
    gaps[k] = False
    short = gaps & (run <= SHORT_GAP)
    gaps &= ~short
    signals = {}
    for name, v in rec.signals.items():
        v = np.asarray(v, float)[keep]
        signals[name] = np.where(short, np.interp(grid, k, v), v[src])
    fields = {name: np.asarray(v)[keep][src] for name, v in (rec.fields or {}).items()}
    out = Recording(grid * dt, signals, fields, rec.path)
    out.gaps = gaps
    return out


BEYOND_TANK = 1.5    # a reading this far beyond all the water its tank can hold is a fault code
BEYOND_RANGE = 0.05  # a command this share of its range beyond it is no command
# A noisy sensor repeats its exact reading in about 1 % of consecutive samples (four-tank
# rigs: 0.3-2.5 %, never more than 4 in a row). A run of one reading that its own noise makes
# this unlikely over the record is a frozen sensor (a gateway's stale value, a stuck
# transmitter), not a level: left out like a fault code.
FROZEN_CHANCE = 1e-6       # expected number of such runs by chance, at most
FROZEN_MIN_SAMPLES = 10
FROZEN_MAX_REPEAT = 0.2    # a signal repeating more often than this is too smooth to tell
FROZEN_MIN_NOISE = 3.0     # the noise, in resolution steps, below which repeats are ordinary


def frozen_runs(v: np.ndarray, readable: np.ndarray, resolution: float,
                floor: float | None = None) -> list[tuple[int, int]]:
    """Index ranges [i, j] over which a noisy signal repeats one exact reading far longer than
    its own noise allows, below the highest reading elsewhere (stuck at the record's top is a
    clip: sensor saturation) and not at the range's `floor` (an empty tank). `readable`: the
    samples to judge (lost messages are filled on the grid and say nothing). A sensor with no
    stated `resolution` (Cascaded Tanks' volts) is not judged."""
    idx = np.flatnonzero(readable)
    w = np.asarray(v, float)[idx]
    if resolution <= 0.0 or len(w) < 3 * FROZEN_MIN_SAMPLES:
        return []          # with no stated resolution, what an exact repeat means is unknown
    d2 = np.diff(w, 2)
    d2 = d2[d2 != 0.0]     # the noise where the reading moves: a long freeze would take it to 0
    if len(d2) < 3 * FROZEN_MIN_SAMPLES:
        return []
    noise = robust_sigma(d2) / math.sqrt(6.0)
    if noise < FROZEN_MIN_NOISE * resolution:
        return []
    starts = np.r_[0, np.flatnonzero(w[1:] != w[:-1]) + 1]
    lengths = np.diff(np.r_[starts, len(w)])
    repeats = int(np.sum(lengths - 1))
    out = []
    for a, n in zip(starts[lengths >= FROZEN_MIN_SAMPLES], lengths[lengths >= FROZEN_MIN_SAMPLES]):
        p = max((repeats - (n - 1)) / max(len(w) - n, 1), 1.0 / len(w))   # the repeat rate elsewhere
        others = np.r_[w[:a], w[a + n:]]
        at_floor = floor is not None and w[a] <= floor + 1.5 * resolution
        if p <= FROZEN_MAX_REPEAT and len(w) * p ** (n - 1) < FROZEN_CHANCE \
                and w[a] < others.max() and not at_floor:
            out.append((int(idx[a]), int(idx[a + n - 1])))
    return out


def with_unreadable_marked(rec: Recording, model: PlantModel) -> Recording:
    """Mark the samples in which a sensor reads what no tank can hold: the top of its wire range
    (0xFFFF, a sensor's fault code) or more than BEYOND_TANK times its tank's capacity (or the
    circuit's water), or as far below zero. The comparisons ignore them as they ignore lost
    messages (`rec.gaps`), and the sensor's value there is interpolated from its readable
    neighbours; the inputs were received, so unlike lost messages (`rec.lost`) they do not stop
    an open-loop replay. `rec.unreadable` says which sensor, how many samples, when and what it
    read. A command beyond its range by BEYOND_RANGE of it (6553.5 % is 0xFFFF) says nothing of
    what was applied: those samples count as lost messages, the last readable command held.
    A sensor frozen at one reading inside its range (`frozen_runs`) is left out the same way
    (`beyond` None). Errors when more than half of the samples of a signal are unreadable."""
    bad = np.zeros(len(rec.t), bool)
    rec.unreadable = []

    def note(name, mask, v, beyond):
        at = rec.t[mask]
        rec.unreadable.append({"signal": name, "samples": int(mask.sum()), "beyond": beyond,
                               "from_s": round(float(at[0]), 3), "to_s": round(float(at[-1]), 3),
                               "values": sorted({float(x) for x in v[mask]})[:5]})

    def leave_out(name, mask, v, beyond, what):
        """Note a sensor's samples in `mask`, interpolate them from the rest, mark them bad."""
        if mask.sum() > len(mask) // 2:
            raise CivicError(f"{rec.path}: sensor {name} {what} in more than half of the samples")
        note(name, mask, v, beyond)
        rec.signals[name] = np.where(mask, np.interp(rec.t, rec.t[~mask], v[~mask]), v)
        bad[mask] = True
    for s in model.sensors:
        if s.name not in rec.signals:
            continue
        v = np.asarray(rec.signals[s.name], float)
        fault = np.zeros(len(v), bool)
        if s.quantity == "volume":
            hold = min(model.tank(s.tank).capacity, model.total_volume or np.inf) * BEYOND_TANK * s.gain
            fault = np.abs(v - s.offset) > hold
            if s.wire and s.wire in (rec.fields or {}):
                fault |= np.asarray(rec.fields[s.wire]) >= 0xFFFF
            if fault.any():
                leave_out(s.name, fault, v, "its tank", "reads beyond its tank")
        frozen = np.zeros(len(v), bool)
        for i, j in frozen_runs(v, ~(rec.gaps | fault), s.resolution, s.min):
            frozen[i:j + 1] = True
        if frozen.any():
            leave_out(s.name, frozen, np.asarray(rec.signals[s.name], float), None, "is frozen at one reading")
    lost = rec.gaps.copy()
    for i in model.inputs:
        if i.name not in rec.signals or i.min is None or i.max is None:
            continue
        v = np.asarray(rec.signals[i.name], float)
        slack = BEYOND_RANGE * (i.max - i.min)
        mask = (v > i.max + slack) | (v < i.min - slack)
        if not mask.any():
            continue
        if mask.sum() > len(mask) // 2:
            raise CivicError(f"{rec.path}: input {i.name} is beyond its range in more than half of the samples")
        note(i.name, mask, v, "its range")
        last = np.maximum.accumulate(np.where(mask, -1, np.arange(len(v))))    # the last readable command
        rec.signals[i.name] = v[np.where(last < 0, np.argmin(mask), last)]
        lost |= mask
    rec.lost = lost
    rec.gaps = lost | bad
    return rec


def unreadable_lines(rec: Recording) -> list[str]:
    """One warning line per signal `with_unreadable_marked` left out."""
    def said(u):
        if u["beyond"] is None:
            return f"frozen at {', '.join(f'{v:g}' for v in u['values'])} (one reading repeated beyond its noise)"
        return f"read {', '.join(f'{v:g}' for v in u['values'])} (beyond {u['beyond']})"
    return [f"{u['signal']} {said(u)} in {u['samples']} samples, {u['from_s']:g}-{u['to_s']:g} s: "
            + ("counted as lost messages" if u["beyond"] == "its range" else "left out of the comparisons")
            for u in rec.unreadable]


def _load_csv(path: str, model: PlantModel) -> Recording:
    try:
        with open(path) as fh:
            header = [h.strip() for h in fh.readline().split(",")]
    except (OSError, UnicodeDecodeError) as exc:
        raise CivicError(f"cannot read {path}: {exc}") from None
    lower = [h.lower() for h in header]
    tcol = next((lower.index(c) for c in TIME_COLUMNS if c in lower), None)
    if tcol is None:
        raise CivicError(f"{path}: CSV needs a header with a time column ({', '.join(TIME_COLUMNS)})")
    try:
        with warnings.catch_warnings():   # a header without rows: said below as 'no data rows'
            warnings.simplefilter("ignore", UserWarning)
            raw = np.genfromtxt(path, delimiter=",", skip_header=1, dtype=float, ndmin=2)
    except ValueError as exc:
        # numpy lists every ragged row on lines of their own; the first says enough
        first = re.search(r"Line #(\d+) \(got (\d+) columns instead of (\d+)\)", str(exc))
        why = (f"line {first[1]} has {first[2]} columns instead of {first[3]}" if first
               else " ".join(str(exc).split()))
        raise CivicError(f"{path}: bad CSV: {why}") from None
    if raw.size and raw.shape[1] != len(header):
        raise CivicError(f"{path}: rows do not match the header's {len(header)} columns")
    if raw.shape[0] == 0:
        raise CivicError(f"{path}: no data rows")
    bad = np.argwhere(~np.isfinite(raw))
    if len(bad):
        # an empty or non-numeric cell would become NaN and poison every result downstream
        r, c = bad[0]
        raise CivicError(f"{path}: line {r + 2}, column {header[c]}: not a number")
    cols = {h: raw[:, i] for i, h in enumerate(header) if i != tcol}
    t = raw[:, tcol] - raw[0, tcol]
    wires = set(model.wire_fields)
    names = set(model.input_names) | set(model.signal_names)
    sensor_wires = {s.wire for s in model.sensors if s.wire}
    wire_mode = bool(set(cols) & sensor_wires) or bool(wires and wires <= set(cols))
    if set(cols) & names and not wire_mode:
        return Recording(t, {c: v for c, v in cols.items() if c in names}, {}, path)
    if set(cols) & wires:
        f = {c: v for c, v in cols.items() if c in wires}
        return Recording(t, from_wire(model, f), {k: v.astype(np.int64) for k, v in f.items()}, path)
    raise CivicError(f"{path}: no column matches the model's signals "
                     f"({', '.join(model.input_names + model.signal_names)})")


def outside_range(model: PlantModel, signals: dict) -> list[str]:
    """One line per input or sensor whose recorded values leave the model's min..max. Inputs
    are held at their limits when simulated; a sensor cannot read beyond its range, so such
    readings are a fault or the wrong model."""
    out = []
    for spec, what in [(i, "input") for i in model.inputs] + [(s, "sensor") for s in model.sensors]:
        if spec.name not in signals or (spec.min is None and spec.max is None):
            continue
        v = np.asarray(signals[spec.name], float)
        lo = -np.inf if spec.min is None else spec.min
        hi = np.inf if spec.max is None else spec.max
        k = int(np.count_nonzero((v < lo) | (v > hi)))
        if k:
            where = (f"outside {lo:g}..{hi:g}" if spec.min is not None and spec.max is not None
                     else f"above {hi:g}" if spec.min is None else f"below {lo:g}")
            held = ", held at the limits" if what == "input" else ""
            out.append(f"{what} {spec.name}: {k} of {len(v)} values {where} "
                       f"(from {np.min(v):.4g} to {np.max(v):.4g}){held}")
    return out


def initial_state(model: PlantModel, signals: dict, n_init: int = 1, total_volume: float | None = None,
                  average: int = 1) -> dict:
    """Initial state from the first samples of a recording.

    Measured tanks: the first sample (the mean of the first `average` samples),
    inverting gain/offset.
    Valves: their first command. Unmeasured tanks: when the total water is known
    (`total_volume`, default the model's) and exactly one tank is unmeasured, by mass
    balance; otherwise by least squares over the first n_init samples (a short
    simulation per candidate, scalar search).
    """
    n_init = max(1, int(n_init))
    if total_volume is None:
        total_volume = model.total_volume
    x0 = measured_state(model, signals, average)
    missing = unmeasured_tanks(model, signals, total_volume)
    if missing:
        x0.update(_fit_unmeasured(model, signals, x0, missing, n_init))
    else:
        for t in model.tanks:
            if t.name not in x0:       # the one tank the stated total water gives
                x0[t.name] = total_volume - sum(x0[k.name] for k in model.tanks if k.name in x0)
    return x0


def unmeasured_tanks(model: PlantModel, signals: dict, total_volume: float | None = None) -> list[str]:
    """Tanks `initial_state` must fit over the first samples: those no recorded sensor reads,
    unless it is one tank and the total water is known (`total_volume`, default the model's)."""
    if total_volume is None:
        total_volume = model.total_volume
    sensed = {s.tank for s in model.sensors if s.name in signals}
    missing = [t.name for t in model.tanks if t.name not in sensed]
    return [] if len(missing) == 1 and total_volume is not None else missing


def measured_state(model: PlantModel, signals: dict, average: int = 1) -> dict:
    """The measured part of the state: tanks with a sensor (mean of the first `average`
    samples, inverted through gain/offset; the first sensor of a tank wins) and valves
    (their first command)."""
    x0 = {}
    for s in model.sensors:
        if s.name in signals and s.tank not in x0:
            y = float(np.mean(np.asarray(signals[s.name], float)[:max(1, int(average))]))
            q = float(s.invert(y))
            x0[s.tank] = q * model.tank(s.tank).area if s.quantity == "level" else q
    for v in model.valves:
        if v.input in signals:
            x0[v.name] = float(np.clip(np.asarray(signals[v.input])[0], 0.0, 1.0))
    return x0


def _fit_unmeasured(model, signals, x0, missing, n_init):
    """Unmeasured tank volumes minimising the squared error over the first samples."""
    from scipy.optimize import least_squares

    n = max(n_init, 2)
    sens = [s for s in model.sensors if s.name in signals]
    if not sens:
        return {name: 0.0 for name in missing}
    inputs = {k: np.asarray(v, float)[:n] for k, v in signals.items() if k in model.input_names}
    t = np.arange(n) * model.dt
    ytrue = np.concatenate([np.asarray(signals[s.name], float)[:n] for s in sens])
    # measured tanks start at the first sample when we fit their neighbours
    base = {**x0, **measured_state(model, signals, 1)}

    def resid(z):
        x = dict(base)
        x.update({name: float(v) for name, v in zip(missing, z)})
        r = simulate(model, t, inputs, x)
        return np.concatenate([r[s.name] for s in sens]) - ytrue

    best = None
    caps = [model.tank(nm).capacity for nm in missing]
    for frac in (0.1, 0.3, 0.5, 0.8):
        z0 = np.array([frac * (c if math.isfinite(c) else 10.0) for c in caps])
        sol = least_squares(resid, z0, bounds=(0.0, np.inf))
        if best is None or sol.cost < best.cost:
            best = sol
    return {name: float(v) for name, v in zip(missing, best.x)}


EPOCH = 1767225600.0          # 2026-01-01T00:00:00Z, as in the recorded cases


def write_recording(path: str, model: PlantModel, t, signals: dict, src_ip: str = "10.0.0.1", seed=None) -> None:
    """A simulated run as a pcap or pcapng in the wire format (random first seq from seed) or a CSV."""
    fields = to_wire(model, signals)
    has_wire = all(c in fields for c in WIRE_COLUMNS)
    try:
        if str(path).endswith((".pcap", ".pcapng")):
            if not has_wire:
                raise CivicError(f"model {model.name} does not map to the plant message (l1..v2); write a .csv")
            from civic.wire import build_frames, write_pcap

            seq0 = int(np.random.default_rng(seed).integers(0, 2**32)) if seed is not None else 0
            frames = build_frames({c: fields[c] for c in WIRE_COLUMNS}, src_ip=src_ip, seq0=seq0)
            write_pcap(path, EPOCH + np.asarray(t), frames)
        elif has_wire:
            cols = np.column_stack([np.asarray(t)] + [fields[c] for c in WIRE_COLUMNS])
            with open(path, "w") as fh:
                fh.write("t_s," + ",".join(WIRE_COLUMNS) + "\n")
                for row in cols:
                    fh.write(f"{row[0]:.10g}," + ",".join(str(int(v)) for v in row[1:]) + "\n")
        else:
            names = [n for n in model.input_names + model.signal_names if n in signals]
            cols = np.column_stack([np.asarray(t)] + [signals[n] for n in names])
            np.savetxt(path, cols, delimiter=",", header="t_s," + ",".join(names), comments="", fmt="%.10g")
    except OSError as exc:
        raise CivicError(f"cannot write {path}: {exc.strerror}") from exc
