"""Closed-loop control of the four-tank plant: linear MPC (as in the CIVIC paper) or PI.

MPC: the model is linearised at an operating point (the first setpoint),
discretised at the sample time (zero-order hold), augmented with the pump's
dead time (a shift register) and the valves' first-order positioners, and
solved as a condensed box-constrained QP with OSQP every sample. The QP
matrices (and OSQP's factorisation) never change: each step updates only the
linear term q and the bounds l/u, and OSQP is warm-started. The steady-state
target for a setpoint comes from the nonlinear model (flows are linear in the
commands, so it is a bounded linear least-squares problem); a slow disturbance
estimate on each tank's net flow makes tracking offset-free under model error.

The supervisor reproduces the recorded closed-loop operation (truth.json
"operation"): setpoint changes, and embedded drain tests (prep -> hold -> run
-> end) and fill tests (drain_down -> hold -> run -> end).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg as sla
from scipy.optimize import lsq_linear

from civic.errors import CivicError
from civic.plant.model import PlantModel
from civic.plant.simulate import compile_model, measure, to_wire, _x0_vector

CONTROLLED = ("T1", "T2", "T3")
COMMANDS = ("p1", "v1", "v2")


class _Plant4:
    """Index bookkeeping for the controlled four-tank plant."""

    def __init__(self, model: PlantModel):
        missing = [n for n in CONTROLLED if n not in model.tank_names] + \
                  [n for n in COMMANDS if n not in model.input_names]
        if missing:
            raise CivicError(f"model {model.name}: closed loop needs tanks T1..T3 and inputs p1, v1, v2 "
                             f"(missing {', '.join(missing)})")
        self.model = model
        self.tidx = [model.tank_names.index(n) for n in CONTROLLED]

        # precomputed flow terms for rhs3 (civic.plant.simulate.flows is the reference)
        m = model
        idx = {t.name: i for i, t in enumerate(m.tanks)}
        self._area = [t.area for t in m.tanks]
        self._base = [30.0 if t.name == "T4" else 0.0 for t in m.tanks]
        cmd = {n: j for j, n in enumerate(COMMANDS)}
        self._pumps = [(p.gain * (1 - p.closure), cmd.get(p.input), p.input_offset, p.head_coeff,
                        idx.get(p.from_), idx.get(p.to)) for p in m.pumps]
        vin = {v.name: (cmd.get(v.input), v.exponent()) for v in m.valves}
        self._links = [(lk.coeff * (1 - lk.closure), vin.get(lk.valve) if lk.valve else None,
                        lk.law == "orifice", lk.exponent, lk.min_level, idx[lk.from_], idx.get(lk.to))
                       for lk in m.links]

    def rhs3(self, x3, u3):
        """dV/dt of T1..T3 (valves at their commands, no dead time); T4 held at 30 L (the reservoir barely moves the pump)."""
        V = list(self._base)
        for j, i in enumerate(self.tidx):
            V[i] = float(x3[j])
        h = [v / a for v, a in zip(V, self._area)]
        d = [0.0] * len(V)
        for g, ci, off, hc, src, dst in self._pumps:
            u = float(u3[ci]) if ci is not None else 0.0
            q = g * max(u - off, 0.0)
            if dst is not None:
                q *= max(1.0 - hc * h[dst], 0.0)
                d[dst] += q
            if src is not None:
                d[src] -= q
        for k, valve, orifice, ex, ml, src, dst in self._links:
            if valve is not None:
                ci, n = valve
                u = max(float(u3[ci]), 0.0) if ci is not None else 0.0
                k = k * (u if n == 1.0 else u ** n)
            if orifice:
                hh = h[src] - ml
                q = k * hh ** ex if hh > 0 else 0.0
            else:
                dh = h[src] - h[dst]
                q = k * abs(dh) ** ex if dh >= 0 else -k * (-dh) ** ex
            d[src] -= q
            if dst is not None:
                d[dst] += q
        return np.array([d[i] for i in self.tidx])

    def steady_input(self, x3, w=None, u_prev=None):
        """Commands in [0, 1] that hold x3 (least squares; exact when feasible)."""
        w = np.zeros(3) if w is None else w
        base = self.rhs3(x3, np.zeros(3))
        M = np.stack([self.rhs3(x3, np.eye(3)[j]) - base for j in range(3)], axis=1)
        sol = lsq_linear(M, -(base + w), bounds=(0.0, 1.0))
        return sol.x


# ---------------------------------------------------------------------------------------
# controllers
# ---------------------------------------------------------------------------------------
class LinearMPC:
    """Condensed linear MPC with OSQP; only q, l, u change between steps."""

    def __init__(self, model: PlantModel, setpoint, horizon: int = 10, q_weight=(1.0, 1.0, 1.0),
                 r_weight=(0.5, 0.5, 0.5), s_weight=(2.0, 2.0, 2.0), dist_gain: float = 0.02):
        import osqp
        import scipy.sparse as sp

        self.plant = _Plant4(model)
        self.dt = dt = model.dt
        self.N = N = int(horizon)
        x3 = np.asarray(setpoint, float)
        u3 = self.plant.steady_input(x3)
        u3 = np.clip(u3, 0.05, 0.95)
        # continuous Jacobians at the operating point
        eps = 1e-5
        Ac = np.zeros((3, 3))
        Bc = np.zeros((3, 3))
        for j in range(3):
            e = np.eye(3)[j] * eps
            Ac[:, j] = (self.plant.rhs3(x3 + e, u3) - self.plant.rhs3(x3 - e, u3)) / (2 * eps)
            Bc[:, j] = (self.plant.rhs3(x3, u3 + e) - self.plant.rhs3(x3, u3 - e)) / (2 * eps)
        M = np.zeros((6, 6))
        M[:3, :3], M[:3, 3:] = Ac * dt, Bc * dt
        E = sla.expm(M)
        Ad, Bd = E[:3, :3], E[:3, 3:]
        # actuator dynamics: pump dead time (shift register), valve positioners
        pump = model.pumps[0] if model.pumps else None
        self.nd = nd = int(round(pump.dead_time / dt)) if pump else 0
        taus = []
        for name in ("v1", "v2"):
            vs = [v for v in model.valves if v.input == name]
            taus.append(vs[0].tau if vs else 0.0)
        self.ev = np.array([math.exp(-dt / t) if t > 0 else 0.0 for t in taus])
        # augmented state z = [dx(3), pump queue (nd, oldest first), a1, a2] in deviation units
        nz = 3 + nd + 2
        A = np.zeros((nz, nz))
        B = np.zeros((nz, 3))
        A[:3, :3] = Ad
        if nd > 0:
            A[:3, 3] = Bd[:, 0]                     # the oldest queued pump command acts now
            for i in range(nd - 1):
                A[3 + i, 4 + i] = 1.0
            B[3 + nd - 1, 0] = 1.0
        else:
            B[:3, 0] = Bd[:, 0]
        for j in range(2):
            A[:3, 3 + nd + j] = Bd[:, 1 + j]
            A[3 + nd + j, 3 + nd + j] = self.ev[j]
            B[3 + nd + j, 1 + j] = 1 - self.ev[j]
        self.A, self.B, self.nz = A, B, nz
        Q = np.zeros((nz, nz))
        Q[:3, :3] = np.diag(q_weight)
        R = np.diag(r_weight)
        try:
            Pt = sla.solve_discrete_are(A, B, Q + 1e-9 * np.eye(nz), R)
        except (np.linalg.LinAlgError, ValueError):
            Pt = Q * 50
        # condensed prediction Z = Phi z0 + Gam U
        Phi = np.zeros((N * nz, nz))
        Gam = np.zeros((N * nz, 3 * N))
        Ak = np.eye(nz)
        for k in range(N):
            Ak = A @ Ak
            Phi[k * nz:(k + 1) * nz] = Ak
            for j in range(k + 1):
                Gam[k * nz:(k + 1) * nz, 3 * j:3 * j + 3] = np.linalg.matrix_power(A, k - j) @ B
        Qb = sla.block_diag(*([Q] * (N - 1) + [Pt]))
        Rb = sla.block_diag(*([R] * N))
        S = np.diag(s_weight)
        D = np.eye(3 * N) - np.eye(3 * N, k=-3)     # move differences, first vs previous command
        Sb = sla.block_diag(*([S] * N))
        H = Gam.T @ Qb @ Gam + Rb + D.T @ Sb @ D
        H = (H + H.T) / 2
        self.F = Gam.T @ Qb @ Phi                   # q = F z0 - Dprev
        self.G = -(D.T @ Sb)[:, :3]                 # q += G (u_prev - us)
        self.prob = osqp.OSQP()
        new_api = int(str(getattr(osqp, "__version__", "0")).split(".")[0]) >= 1
        opts = dict(warm_starting=True, polishing=False) if new_api else dict(warm_start=True, polish=False)
        self.prob.setup(P=sp.csc_matrix(np.triu(H)), q=np.zeros(3 * N), A=sp.identity(3 * N, format="csc"),
                        l=np.zeros(3 * N), u=np.ones(3 * N), verbose=False,
                        eps_abs=1e-4, eps_rel=1e-4, max_iter=200, **opts)
        self._solve = (lambda: self.prob.solve(raise_error=False)) if new_api else self.prob.solve
        # controller state
        self.queue = np.zeros(nd)        # applied pump commands not yet acting (absolute)
        self.a = np.zeros(2)             # predicted valve openings (absolute)
        self.u_prev = np.zeros(3)
        self.w = np.zeros(3)             # flow disturbance estimate (L/s per tank)
        self.dist_gain = dist_gain
        self._lo = np.zeros(3 * N)
        self._pred = None
        self._target = None

    def reset_actuators(self, u_applied):
        self.queue[:] = u_applied[0]
        self.a[:] = u_applied[1:]
        self.u_prev = np.array(u_applied, float)
        self._pred = None

    def _set_target(self, sp):
        # flows are linear in the commands: us = Minv @ -(base + w), cached per setpoint
        key = tuple(np.round(sp, 9))
        if self._target is None or key != self._target[0]:
            x3 = np.asarray(sp, float)
            base = self.plant.rhs3(x3, np.zeros(3))
            M = np.stack([self.plant.rhs3(x3, np.eye(3)[j]) - base for j in range(3)], axis=1)
            self._target = (key, base, np.linalg.pinv(M))
        _, base, Minv = self._target
        return np.clip(Minv @ -(base + self.w), 0.0, 1.0)

    def __call__(self, y3, sp):
        y3 = np.asarray(y3, float)
        sp = np.asarray(sp, float)
        # disturbance estimate from the one-step prediction error
        if self._pred is not None:
            self.w += self.dist_gain * (y3 - self._pred) / self.dt
            np.clip(self.w, -0.1, 0.1, out=self.w)
        us = self._set_target(sp)
        nd = self.nd
        z = np.empty(self.nz)
        z[:3] = y3 - sp
        z[3:3 + nd] = self.queue - us[0]
        z[3 + nd:] = self.a - us[1:]
        q = self.F @ z + self.G @ (self.u_prev - us)
        lo = self._lo
        lo.reshape(self.N, 3)[:] = -us
        self.prob.update(q=q, l=lo, u=lo + 1.0)
        res = self._solve()
        du = res.x[:3] if res.x is not None and np.all(np.isfinite(res.x[:3])) else np.zeros(3)
        u = np.clip(us + du, 0.0, 1.0)
        self.apply(u, y3)
        return u

    def apply(self, u, y3=None):
        """Record the command actually applied (also for open-loop phases)."""
        u = np.asarray(u, float)
        # one-step prediction of the tank volumes with the linear model + disturbance
        if y3 is not None:
            x3 = np.asarray(y3, float)
            act_p = self.queue[0] if self.nd else u[0]
            ua = np.array([act_p, *self.a])
            self._pred = x3 + self.dt * (self.plant.rhs3(x3, ua) + self.w)
        else:
            self._pred = None
        if self.nd:
            self.queue[:-1] = self.queue[1:]
            self.queue[-1] = u[0]
        self.a = self.ev * self.a + (1 - self.ev) * u[1:]
        self.u_prev = u


class PIController:
    """Decentralised PI with steady-state feed-forward: p1 <- T1, v1 <- T2, v2 <- T3."""

    def __init__(self, model: PlantModel, setpoint=None, kp=(0.4, 0.6, 0.6), ti=(20.0, 20.0, 20.0)):
        self.plant = _Plant4(model)
        self.dt = model.dt
        self.kp = np.array(kp)
        self.ki = np.array(kp) / np.array(ti)
        self.i = np.zeros(3)
        self._ff = None

    def reset_actuators(self, u_applied):
        self.i[:] = 0.0

    def __call__(self, y3, sp):
        sp = np.asarray(sp, float)
        if self._ff is None or not np.allclose(self._ff[0], sp):
            self._ff = (sp.copy(), self.plant.steady_input(sp))
        e = (sp - np.asarray(y3, float)) * np.array([1.0, 1.0, -1.0])
        u_raw = self._ff[1] + self.kp * e + self.i
        u = np.clip(u_raw, 0.0, 1.0)
        # integrate only when not saturated in the direction of the error (anti-windup)
        free = (u == u_raw) | (np.sign(e) != np.sign(u_raw - u))
        self.i += np.where(free, self.ki * e * self.dt, 0.0)
        return u

    def apply(self, u, y3=None):
        pass


# ---------------------------------------------------------------------------------------
# operation schedule (setpoints and embedded tests)
# ---------------------------------------------------------------------------------------
PREP_SETPOINT = (8.1, 7.6, 7.25)    # drain-test prep target (recorded cases end prep there)
DRAIN_DOWN_GAIN = 0.17               # fill-test drain-down: V2 = 0.17 sqrt(L3) (fits both recorded cases)


def random_setpoint(rng) -> list:
    s1 = rng.uniform(7.0, 9.3)
    s2 = s1 - rng.uniform(0.5, 1.05)
    s3 = s2 - rng.uniform(0.5, 1.3)
    return [round(s1, 3), round(s2, 3), round(s3, 3)]


def make_schedule(duration: float, rng, tests: bool = True) -> list:
    """[(t, 'setpoints', [s1, s2, s3]) | (t, 'drain_test' | 'fill_test', None)], sorted by time.

    Tests are requests: the supervisor runs their phases and resumes with the
    next setpoint entry. Setpoints change every 30..80 s; a drain and a fill
    test are embedded every ~250 s (as in the recorded 10-minute cases).
    """
    ops = [(0.0, "setpoints", random_setpoint(rng))]
    t = 0.0
    next_test = rng.uniform(40.0, 70.0)
    kinds = ["drain_test", "fill_test"]
    rng.shuffle(kinds)
    k = 0
    while True:
        t += rng.uniform(30.0, 80.0)
        if t >= duration:
            break
        if tests and t >= next_test and t < duration - 120:
            ops.append((round(t, 1), kinds[k % 2], None))
            k += 1
            next_test = t + rng.uniform(90.0, 180.0)
            t += 100.0
            continue
        ops.append((round(t, 1), "setpoints", random_setpoint(rng)))
    return ops


def operation_schedule(duration: float, rng, hold=(40.0, 90.0)) -> list:
    """Setpoints changing every `hold` s with one drain test and one fill test at random times
    (as in the recorded 15-minute closed-loop runs)."""
    ops = [(0.0, "setpoints", random_setpoint(rng))]
    kinds = ["drain_test", "fill_test"]
    rng.shuffle(kinds)
    first = rng.uniform(60.0, max(duration / 2 - 100.0, 61.0))
    tests = [first, rng.uniform(first + 180.0, max(duration - 150.0, first + 181.0))]
    t, k = 0.0, 0
    while True:
        t += rng.uniform(*hold)
        if t >= duration:
            break
        if k < 2 and t >= tests[k]:
            ops.append((round(t, 1), kinds[k], None))
            k += 1
            t += 100.0
            continue
        ops.append((round(t, 1), "setpoints", random_setpoint(rng)))
    return ops


def schedule_from_operation(operation: list) -> list:
    """A truth.json "operation" list -> a schedule for run_closed_loop.

    Setpoint entries are kept; a test starts where its first phase
    (drain_test:prep, fill_test:drain_down) starts; the supervisor then runs
    the phases by its own rules, so later phase times may differ slightly.
    """
    out = []
    try:
        for t, what, val in operation:
            if what == "setpoints":
                out.append((float(t), "setpoints", [float(v) for v in val]))
            elif what in ("drain_test:prep", "fill_test:drain_down"):
                out.append((float(t), what.split(":")[0], None))
    except (TypeError, ValueError) as exc:
        raise CivicError(f"bad operation list: {exc}") from exc
    if not out or out[0][1] != "setpoints":
        raise CivicError("operation list must start with a setpoints entry")
    return sorted(out, key=lambda e: e[0])


def schedule_from_truth(path) -> tuple[list, float | None]:
    """A case's truth.json -> (its operation as a schedule for run_closed_loop, its duration_s)."""
    from civic.files import read_json

    truth = read_json(path)
    if not isinstance(truth, dict) or "operation" not in truth:
        raise CivicError(f"{path}: no 'operation' list")
    return schedule_from_operation(truth["operation"]), truth.get("duration_s")


@dataclass
class ClosedLoopResult:
    t: np.ndarray
    signals: dict                 # physical signals (L1..L4 measured, p1/v1/v2 applied)
    fields: dict                  # wire fields
    volumes: np.ndarray
    operation: list = field(default_factory=list)   # (t, label, value) like truth.json


class Stepper:
    """Advance the compiled plant one sample at a time (exact dead time via a command history)."""

    def __init__(self, model: PlantModel, x0: np.ndarray, u0: np.ndarray):
        self.cm = compile_model(model)
        self.fn = self.cm._function(False)
        self.P = self.cm.params_for(model).tolist()
        self.x = [float(v) for v in x0] + [0.0]
        self.hist_len = max([a.m for a in self.cm._acts] + [0]) + 2
        self.hist = [list(map(float, u0))] * self.hist_len     # oldest first
        self.acts = [(a.input, a.m) for a in self.cm._acts]

    def step(self, u) -> list:
        """Apply command u over [t_k, t_k+1); returns the state at t_k+1."""
        self.hist = self.hist[1:] + [list(map(float, u))]
        L = self.hist_len - 1        # index of the current command
        UA = [[self.hist[L - m - 1][i]] for i, m in self.acts]
        UB = [[self.hist[L - m][i]] for i, m in self.acts]
        buf = []
        self.fn(2, UA, UB, self.x, self.P, buf.append)
        self.x = list(buf[1])
        return self.x


def run_closed_loop(model: PlantModel, duration: float, controller: str = "mpc", seed=None,
                    noise: bool = True, schedule=None, x0=None, progress=None,
                    controller_model: PlantModel | None = None,
                    onset: tuple[float, PlantModel] | None = None, pi_gains=None) -> ClosedLoopResult:
    """Simulate the plant under MPC/PI with the supervisor's setpoints and tests.

    `model` is the simulated plant (it may carry faults: leaks, offsets...);
    the controller is designed on `controller_model` (default: the same model),
    so a concealed fault is simulated by passing the nominal model here.
    `onset` = (t, faulted): from time t on the plant runs with `faulted`'s
    coefficients (same structure, e.g. a manual valve closed mid-run).
    `pi_gains` = (kp, ti) of the PI loops (default PIController's).
    """
    phases = model.phases()          # a closure with an onset in the model acts from then on
    plant = _Plant4(phases[0][1])
    rng = np.random.default_rng(seed)
    dt = model.dt
    n = int(round(duration / dt))
    if n < 1:
        raise CivicError("--duration must be at least one sample")
    ops = list(schedule) if schedule is not None else make_schedule(duration, rng)
    sp = np.array(ops[0][2] if ops[0][1] == "setpoints" else [7.0, 6.2, 5.4], float)
    nt = len(model.tanks)
    tidx = plant.tidx
    if x0 is None:
        x0v = np.zeros(nt)
        x0v[tidx] = sp
        rest = [i for i in range(nt) if i not in tidx]
        if rest:
            x0v[rest[0]] = 40.0 - sp.sum()
        us = plant.steady_input(sp)
        x0v = np.concatenate([x0v, [us[1], us[2]] if len(model.valves) == 2 else np.zeros(len(model.valves))])
    else:
        x0v = _x0_vector(model, x0, np.zeros((1, len(model.inputs))))
        us = plant.steady_input(x0v[tidx])
    if controller not in ("mpc", "pi"):
        raise CivicError(f"unknown controller {controller!r} (mpc, pi)")
    cmodel = controller_model if controller_model is not None else phases[0][1]
    ctrl = LinearMPC(cmodel, sp) if controller == "mpc" else PIController(cmodel, sp, *(pi_gains or ()))
    iin = [model.input_names.index(c) for c in COMMANDS]
    u_full = np.zeros(len(model.inputs))
    u_full[iin] = us
    ctrl.reset_actuators(us)
    stepper = Stepper(phases[0][1], x0v, u_full)
    switch = {int(round(t0 / dt)): stepper.cm.params_for(m).tolist() for t0, m in phases[1:]}
    if onset is not None:
        switch[int(round(onset[0] / dt))] = stepper.cm.params_for(onset[1]).tolist()
    ns = len(model.state_names)
    X = np.empty((n, ns))
    Ucmd = np.zeros((n, len(model.inputs)))
    # sensor noise drawn up front (the controller sees the same measurement as the wire)
    noise_rng = np.random.default_rng(None if seed is None else seed + 7919)
    sig = np.array([s.noise_sigma for s in model.sensors]) if noise else np.zeros(len(model.sensors))
    eps = noise_rng.normal(0.0, 1.0, size=(n, len(model.sensors))) * sig
    sens_of = {s.tank: j for j, s in enumerate(model.sensors)}
    sidx = [sens_of.get(n_) for n_ in CONTROLLED]
    qsens = [model.sensors[j] for j in sidx] if None not in sidx else None
    if qsens is not None:       # the controlled sensors' clip (the wire's reading saturates)
        lo3 = [-np.inf if s.min is None else s.min for s in qsens]
        hi3 = [np.inf if s.max is None else s.max for s in qsens]
    op_i = 1
    phase, phase_t0, test = "setpoints", 0.0, None
    log = [(0.0, "setpoints", [float(v) for v in sp])]
    x = np.array(x0v, float)
    last_u = np.asarray(us, float)
    for k in range(n):
        t = k * dt
        if k in switch:
            stepper.P = switch[k]
        X[k] = x
        # measurement as the controller sees it: the reading the wire carries (the sensor's
        # characteristic, noise, wire resolution and clip), so a bent or clipped sensor is in the loop
        if qsens is not None:
            y3 = np.array([s.read(x[tidx[i]] if s.quantity == "volume" else x[tidx[i]] / model.tanks[tidx[i]].area, t)
                           + eps[k, sidx[i]] for i, s in enumerate(qsens)])
            y3 = np.clip(np.round(y3 * 1000.0) / 1000.0, lo3, hi3)
        else:
            y3 = x[tidx]
        # supervisor
        while phase == "setpoints" and op_i < len(ops) and t >= ops[op_i][0] - 1e-9:
            _, what, val = ops[op_i]
            op_i += 1
            if what == "setpoints":
                sp = np.array(val, float)
                log.append((round(t, 1), "setpoints", [float(v) for v in sp]))
            else:
                test = what
                phase = "prep" if what == "drain_test" else "drain_down"
                phase_t0 = t
                log.append((round(t, 1), f"{test}:{phase}", None))
        if phase != "setpoints":
            el = t - phase_t0
            nxt = None
            if phase == "prep" and el >= 45.0:
                nxt = "hold"
            elif phase == "drain_down" and ((y3[0] <= 4.5 and y3[2] <= 3.1) or el >= 90.0):
                nxt = "hold"
            elif phase == "hold" and el >= (6.0 if test == "drain_test" else 5.0) - 1e-9:
                nxt = "run"
            elif phase == "run" and ((test == "drain_test" and el >= 15.0 - 1e-9) or
                                     (test == "fill_test" and (y3[0] >= 8.4 or el >= 20.0))):
                nxt = "end"
            if nxt:
                phase, phase_t0 = nxt, t
                log.append((round(t, 1), f"{test}:{phase}", None))
                if phase == "end":
                    phase, test = "setpoints", None
                    # resume with the next setpoint entry (or a fresh one)
                    if op_i < len(ops) and ops[op_i][1] == "setpoints" and ops[op_i][0] <= t + 60:
                        sp = np.array(ops[op_i][2], float)
                        op_i += 1
                    else:
                        sp = np.array(random_setpoint(rng), float)
                    log.append((round(t, 1), "setpoints", [float(v) for v in sp]))
        # commands
        if phase == "setpoints":
            u = ctrl(y3, sp)
        elif phase == "prep":
            u = ctrl(y3, np.array(PREP_SETPOINT))
        elif phase == "drain_down":
            # as recorded: pump off, V1 open, V2 opened ~ 0.17 sqrt(L3) (outflow ~ proportional to L3)
            a2 = DRAIN_DOWN_GAIN * math.sqrt(max(y3[2], 0.0))
            a2 = float(np.clip(a2, last_u[2] - 0.005, last_u[2] + 0.005))     # positioner rate limit
            u = np.array([0.0, 1.0, float(np.clip(a2, 0.0, 1.0))])
            ctrl.apply(u)
        elif phase == "hold":
            u = np.zeros(3)
            ctrl.apply(u)
        else:  # run
            u = np.array([0.0, 0.0, 1.0]) if test == "drain_test" else np.array([1.0, 0.0, 0.0])
            ctrl.apply(u)
        u = np.round(np.asarray(u) * 1000.0) / 1000.0       # 0.1 % command resolution
        last_u = u
        u_full[iin] = u
        Ucmd[k] = u_full
        if k + 1 < n:
            x = np.array(stepper.step(u_full)[:ns])
        if progress is not None and k % 200 == 0:
            progress(k, n)
    if progress is not None:
        progress(n, n)
    vol = X[:, :nt]
    sigs = measure(model, vol, noise=False, t=np.arange(n) * dt)
    for j, s in enumerate(model.sensors):
        sigs[s.name] = sigs[s.name] + eps[:, j]
        if s.resolution > 0:
            sigs[s.name] = np.round(sigs[s.name] / s.resolution) * s.resolution
        if s.min is not None or s.max is not None:
            sigs[s.name] = np.clip(sigs[s.name], -np.inf if s.min is None else s.min,
                                   np.inf if s.max is None else s.max)
    for j, name in enumerate(model.input_names):
        sigs[name] = Ucmd[:, j]
    t = np.arange(n) * dt
    return ClosedLoopResult(t, sigs, to_wire(model, sigs), vol, log)
