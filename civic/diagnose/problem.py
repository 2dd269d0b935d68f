"""The fitting problem: candidates' edits of the model -> weighted residual rows of an engine
(equation error or free-run simulation), fitted by least squares with the calibration and the
unmeasured initial volumes, and judged on held-out rows; and the `Diagnosis` the steps fill in."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import partial

import numpy as np
from scipy.optimize import least_squares

from civic.plant.model import PlantModel
from civic.plant.simulate import Recording

from .compare import EquationError, SimulationError, fully_measured
from .locate import Localisation
from .mechanisms import Mechanism, coefficient_paths
from .mechanisms.coefficient import CAL_SPREAD
from .parallel import run_all

# a candidate counts if it lowers the held-out BIC by MIN_DBIC and the held-out SSE by MIN_GAIN
# (`significant`; the forward selection's first finding needs less, forward.MIN_GAIN_FIRST)
MIN_DBIC = 10.0
MIN_GAIN = 0.10
FREE_RUN_FOLDS = 3      # blocked k-fold CV in time (two-fold without unmeasured tanks)


def fast_copy(model: PlantModel) -> PlantModel:
    """Copy of a model deep enough for parameter edits (its parts are flat dataclasses)."""
    def shallow(x):
        y = object.__new__(type(x))     # copy.copy's result, without its reduce protocol's cost
        y.__dict__.update(x.__dict__)
        return y

    def cp(x):
        y = shallow(x)
        if getattr(y, "overflow", None) is not None:
            y.overflow = shallow(y.overflow)
        return y
    return PlantModel(model.name, model.dt, model.substeps, model.total_volume, [cp(x) for x in model.inputs],
                      [cp(x) for x in model.tanks], [cp(x) for x in model.pumps],
                      [cp(x) for x in model.valves], [cp(x) for x in model.links],
                      [cp(x) for x in model.sensors])


@dataclass
class Calibration:
    """Coefficients allowed to move within the datasheet spread, as multiplicative factors."""
    paths: list[tuple[str, str]]
    nominal: list[float]
    spread: float = CAL_SPREAD
    bounds: tuple[float, float] | None = None   # factor range; None: 1 -+ spread

    @classmethod
    def of(cls, model: PlantModel, spread: float = CAL_SPREAD, bounds=None) -> "Calibration":
        paths = [(c, p) for c, p in coefficient_paths(model) if float(model.get(p)) > 0]
        return cls(paths, [float(model.get(p)) for _, p in paths], spread, bounds)

    @property
    def lo(self) -> float:
        return self.bounds[0] if self.bounds else 1 - self.spread

    @property
    def hi(self) -> float:
        return self.bounds[1] if self.bounds else 1 + self.spread

    def __len__(self):
        return len(self.paths)

    def apply(self, model: PlantModel, factors, copy=True) -> PlantModel:
        m = fast_copy(model) if copy else model
        for (_, path), nom, f in zip(self.paths, self.nominal, factors):
            if float(m.get(path)) == nom:   # a Coefficient finding on the same path wins
                m.set(path, nom * float(f))
        return m

    def pinned(self, factors) -> list[str]:
        """Components whose factor sits at a bound of the spread."""
        tol = 1e-6 * (self.hi - self.lo)
        return [c for (c, _), f in zip(self.paths, factors) if f <= self.lo + tol or f >= self.hi - tol]

    def report(self, factors) -> dict:
        edge = set(self.pinned(factors))
        return {path: {"nominal": nom, "value": round(nom * float(f), 6), "change_pct": round((f - 1) * 100, 2),
                       "at_spread_edge": c in edge}
                for (c, path), nom, f in zip(self.paths, self.nominal, factors)}


@dataclass
class FitResult:
    mechanisms: list[Mechanism]             # with fitted values
    cal: np.ndarray                         # calibration factors
    x0_extra: dict                          # fitted unmeasured initial volumes (free run)
    train_sse: float
    val_sse: float
    val_bic: float
    k: int
    model: PlantModel                       # the resulting model
    ok: bool = True
    fold_sse: list = field(default_factory=list)
    fold_tol: float | None = 0.0            # a fold's held-out SSE may rise by this fraction (None: pooled only)
    val_rmse: float = float("nan")          # held-out RMSE in signal units (all folds)
    fold_params: list = field(default_factory=list)  # per fold: [mechanism.values()] of its fit
    held_out: np.ndarray | None = None      # `model`'s residuals on the held-out rows (default single fold)


def significant(res: FitResult, ref: FitResult, min_gain: float = MIN_GAIN) -> tuple[bool, float, float]:
    """A candidate counts if it lowers the held-out BIC by MIN_DBIC, the held-out SSE by
    `min_gain`, and the held-out SSE of every fold (short equation-error records: no fold's
    held-out SSE may rise by more than MIN_GAIN; see `Problem.folds`)."""
    dbic = res.val_bic - ref.val_bic
    gain = 1 - res.val_sse / max(ref.val_sse, 1e-300)
    folds = res.fold_tol is None or all(a < b * (1 + res.fold_tol) for a, b in zip(res.fold_sse, ref.fold_sse))
    return (dbic < -MIN_DBIC and gain > min_gain and folds), dbic, gain


def fold_gains(res: FitResult, ref: FitResult) -> list[float]:
    """Each fold's fall of the held-out SSE against the reference's."""
    return [1 - a / max(b, 1e-300) for a, b in zip(res.fold_sse, ref.fold_sse)]


def tried_record(label: str, res: FitResult, ref: FitResult, mech: Mechanism, **extra) -> dict:
    """A `Diagnosis.tried` record: `res` (with `mech`) judged on held-out data against `ref`."""
    return {"candidate": label, "val_bic": res.val_bic, "dbic": res.val_bic - ref.val_bic,
            "val_gain": 1 - res.val_sse / max(ref.val_sse, 1e-300), "fold_sse": list(res.fold_sse),
            "base_fold_sse": list(ref.fold_sse), "parameters": mech.report_parameters(), **extra}


def extra_starts(cand: Mechanism) -> list:
    """Extra starting points for parameters whose objective is flat away from the truth."""
    if cand.name == "overflow" and "volume" in cand.params and cand.bounds["volume"][1] > 1.1 * cand.bounds["volume"][0]:
        lo, hi = cand.bounds["volume"]     # a free rim (a plateau's split spill: narrow, one start)
        rest = [cand.params[k] for k in cand.names if k != "volume"]   # e.g. the split fraction
        return [[lo + f * (hi - lo)] + rest for f in (0.1, 0.3, 0.55)]
    if "rim_level" in cand.params:       # a weir: c spans decades
        lo, hi = cand.bounds["c"]
        return [[lo * 100.0, cand.params["rim_level"]]]
    if cand.name == "dead_time":
        lo, hi = cand.bounds["dead_time"]
        return [[lo + f * (hi - lo)] for f in (0.25, 0.6)]
    return []


class Problem:
    """Objective plumbing: model edits -> weighted residual rows of an engine. `sigma`: the
    weights, per column or per row and column."""

    def __init__(self, model: PlantModel, rec: Recording, engine, cal: Calibration, sigma: np.ndarray,
                 jobs: int = 1):
        self.model = model
        self.jobs = jobs            # worker processes for independent fits (`parallel.run_all`)
        self.rec = rec
        self.engine = engine
        self.cal = cal
        self.sigma = sigma
        self.unmeasured = engine.unmeasured(model) if isinstance(engine, SimulationError) else []
        # unmeasured initial volumes start from the simulator's own estimate (least squares on
        # the first samples): from a blind guess the free-run fit can settle far from them
        self.x0_guess = {}
        if self.unmeasured:
            engine.x0_extra = {}
            self.x0_guess = {t: v for t, v in engine.x0(model).items() if t in self.unmeasured}
        self.val = ~engine.train
        # free-run fits are 100x dearer per evaluation: parameters to 1e-4 are plenty there
        self.xtol = 1e-4 if isinstance(engine, SimulationError) else 1e-6

    def build(self, mechs: list[Mechanism], thetas: list, cal_f) -> PlantModel:
        m = self.cal.apply(self.model, cal_f)
        pairs = list(zip(mechs, thetas))
        # a mechanism that reads another's result (a spill at the fitted sensor's clip) edits last
        for mech, th in [x for x in pairs if not x[0].late] + [x for x in pairs if x[0].late]:
            mech.edit(m, mech.values(th))
        return m

    def residuals(self, model: PlantModel, x0_extra: dict | None = None) -> np.ndarray:
        if self.unmeasured:
            self.engine.x0_extra = dict(x0_extra or {})
        R = self.engine.residuals(model)
        if not np.all(np.isfinite(R)):
            R = np.where(np.isfinite(R), R, 1e3)
        return R / self.sigma

    def fit(self, mechs: list[Mechanism], rows=None, start_cal=None, start_x0=None,
            starts: list | None = None, budget: int = 40) -> FitResult:
        """Fit calibration + the free parameters of `mechs` (+ unmeasured initial volumes) on `rows`.

        `starts`: extra starting values of the last mechanism's parameters (multi-start);
        `budget`: evaluations per parameter (and start)."""
        rows = self.engine.train if rows is None else rows
        # calibration factors of coefficients a Coefficient candidate owns are not free
        owned = {m.fixed.get("path") for m in mechs if m.name == "coefficient"}
        free = np.array([p not in owned for _, p in self.cal.paths], bool)
        cal_start = np.ones(len(self.cal)) if start_cal is None else np.asarray(start_cal, float).copy()
        cal_start[~free] = 1.0
        nc = int(free.sum())
        sizes = [len(m.names) for m in mechs]
        lo = [np.full(nc, self.cal.lo)] + [m.lower for m in mechs]
        hi = [np.full(nc, self.cal.hi)] + [m.upper for m in mechs]
        x_init = [cal_start[free]] + [m.x0 for m in mechs]
        xu_names = list(self.unmeasured)
        if xu_names:
            caps = []
            for t in xu_names:
                tk = self.model.tank(t)
                cap = tk.rim_volume() if math.isfinite(tk.rim_volume()) else (
                    tk.capacity if math.isfinite(tk.capacity) else 20.0 * tk.area)
                caps.append(cap)
            lo.append(np.zeros(len(xu_names)))
            hi.append(np.array(caps) * 1.5)
            x_init.append(np.array([(start_x0 or {}).get(t, self.x0_guess.get(t, 0.5 * c))
                                    for t, c in zip(xu_names, caps)]))
        lo, hi = np.concatenate(lo), np.concatenate(hi)
        x0 = np.clip(np.concatenate(x_init), lo, hi)
        span = np.where(np.isfinite(hi - lo), hi - lo, np.maximum(np.abs(x0), 1.0))

        def split(x):
            cal_f = cal_start.copy()
            cal_f[free] = x[:nc]
            th, pos = [], nc
            for s in sizes:
                th.append(x[pos:pos + s])
                pos += s
            xu = {t: float(v) for t, v in zip(xu_names, x[pos:])}
            return cal_f, th, xu

        def fun(x):
            cal_f, th, xu = split(x)
            R = self.residuals(self.build(mechs, th, cal_f), xu)
            return R[rows].ravel()

        starts_x = [x0]
        last = nc + sum(sizes[:-1])          # extra starts move the last mechanism's parameters
        for s in (starts or []):
            if sizes and len(s) == sizes[-1]:
                xs = x0.copy()
                xs[last:last + len(s)] = s
                starts_x.append(np.clip(xs, lo, hi))
        best = None
        for xs in starts_x:
            # keep the start strictly inside the bounds (least_squares requirement)
            xs = np.clip(xs, lo + 1e-9 * span, hi - 1e-9 * span)
            try:
                sol = least_squares(fun, xs, bounds=(lo, hi), x_scale=span, diff_step=1e-4,
                                    max_nfev=budget * (len(xs) + 1), xtol=self.xtol, ftol=self.xtol)
            except (ValueError, FloatingPointError):
                continue
            if best is None or sol.cost < best.cost:
                best = sol
        if best is None:
            raise RuntimeError("no start converged")
        cal_f, th, xu = split(best.x)
        fitted = [m.with_values(t) for m, t in zip(mechs, th)]
        model = self.build(mechs, th, cal_f)
        R = self.residuals(model, xu)
        k = sum(m.n_params for m in mechs)
        train_sse = float(np.sum(R[self.engine.train] ** 2))
        val_sse = float(np.sum(R[self.val] ** 2))
        return FitResult(fitted, cal_f, xu, train_sse, val_sse, self.bic(R[self.val], k), k, model)

    def both_orders(self) -> list[np.ndarray]:
        """The equation error's interleaved split used both ways (training masks): each order's
        training blocks fitted, the other's held out."""
        return [self.engine.train, ~self.engine.train]

    def folds(self) -> list[np.ndarray]:
        """Training masks; each fold's complement is held out. Equation error: interleaved blocks
        (one split). Free-run simulation: two halves, each held out once (blocked 2-fold CV),
        so every part of a short record serves as validation. With unmeasured tanks, the first
        n_init samples (which fix their initial volumes, as in the benchmark protocol) are
        always fitted, never held out: otherwise the fold that holds out the start scores
        initial volumes guessed from the later half instead of the candidate."""
        if isinstance(self.engine, EquationError):
            if getattr(self.engine, "short", False):
                # a short record (a 40 s test run): an effect may sit in a few windows of one
                # block (a tank reaching its rim), so the interleaved split is used both ways,
                # each block held out once. The fold that holds out only the blocks without
                # the effect cannot improve there (a model with the effect is at best as good
                # as one without): it may not get worse by more than MIN_GAIN
                return self.both_orders()
            return self.both_orders()[:1]
        n = len(self.engine.train)
        init = np.arange(n) < (max(1, self.engine.n_init) if self.unmeasured else 0)
        k = FREE_RUN_FOLDS if self.unmeasured else 2
        block = np.minimum(np.arange(n) * k // n, k - 1)
        # the fold that holds out the last block trains on the start (the representative fit)
        return [(block != b) | init for b in range(k - 1, -1, -1)]

    def evaluate(self, mechs: list[Mechanism], start_cal=None, start_x0=None, starts=None,
                 budget: int = 40, folds: list | None = None) -> FitResult:
        """Fit on each fold's training rows; held-out SSE/BIC over all folds' held-out rows
        (`folds`: training masks, default `self.folds()`)."""
        return self.evaluate_many([mechs], [starts], folds, start_cal=start_cal, start_x0=start_x0,
                                  budget=budget)[0]

    def evaluate_many(self, mech_lists: list[list[Mechanism]], starts: list | None = None,
                      folds: list | None = None, progress=None, **start) -> list[FitResult]:
        """`evaluate` of each list of mechanisms (`starts`: each list's extra starts; `start`: the
        start and budget they share), every fold of every list a task of its own (`run_all`;
        `progress(done, total)` as the folds' fits come in)."""
        masks = self.folds() if folds is None else folds
        starts = starts or [None] * len(mech_lists)

        def fold(mechs, extra, mask):
            res = self.fit(mechs, rows=mask, starts=extra, **start)
            return res, self.residuals(res.model, res.x0_extra)
        tasks = [partial(fold, mechs, extra, mask) for mechs, extra in zip(mech_lists, starts) for mask in masks]
        fits = run_all(tasks, self.jobs, progress and (lambda done: progress(done, len(tasks))))
        k = len(masks)
        return [self._pooled(masks, fits[i * k:(i + 1) * k], folds is None) for i in range(len(mech_lists))]

    def _pooled(self, masks: list[np.ndarray], fits: list, default_folds: bool) -> FitResult:
        """The first fold's fit, judged on every fold's held-out rows (`fits`: per fold, the fit
        and its residuals)."""
        first, held, held_sigma, params = None, [], [], []
        for mask, (res, R) in zip(masks, fits):
            held.append(R[~mask])
            held_sigma.append(np.broadcast_to(self.sigma, R.shape)[~mask])
            params.append([m.values() for m in res.mechanisms])
            if first is None:
                first = res
        first.fold_params = params
        if default_folds and len(held) == 1:
            first.held_out = held[0]          # the rows of self.val (unseen_held_out compares there)
        Rv = np.concatenate(held)
        first.fold_sse = [float(np.sum(h ** 2)) for h in held]
        first.fold_tol = MIN_GAIN if len(held) > 1 and isinstance(self.engine, EquationError) else 0.0
        if self.unmeasured:
            first.fold_tol = None     # free run: the pooled held-out error decides (one block may hold no event)
        first.val_sse = float(np.sum(Rv ** 2))
        first.val_rmse = float(np.sqrt(np.mean((Rv * np.concatenate(held_sigma)) ** 2)))
        first.val_bic = self.bic(Rv, first.k)
        return first

    def unseen_held_out(self, res: FitResult) -> bool:
        """True when the last mechanism of `res` (one `evaluate`d fold) changes no held-out row
        of a long equation-error record (it acts in training blocks only): its held-out
        evidence is void there."""
        if not isinstance(self.engine, EquationError) or self.engine.short or not res.mechanisms \
                or res.held_out is None:
            return False
        others = res.mechanisms[:-1]
        without = self.build(others, [m.x0 for m in others], res.cal)
        return bool(np.allclose(res.held_out, self.residuals(without)[self.val], rtol=0.0, atol=1e-9))

    def bic(self, Rv: np.ndarray, k: int) -> float:
        N = self.n_eff(Rv)
        sse = float(np.sum(Rv ** 2))
        return N * math.log(max(sse / Rv.size, 1e-300)) + k * math.log(max(N, 2))

    def n_eff(self, Rv: np.ndarray) -> float:
        """Effective number of independent held-out residuals.

        Every held-out row counts. For the equation error the rows are close to white;
        free-run simulation errors are autocorrelated, so there the BIC alone overstates
        the evidence: `diagnose` also requires the held-out SSE to fall in *every* fold
        and by at least MIN_GAIN (see `significant`)."""
        return float(Rv.size)


def make_engine(model: PlantModel, rec: Recording, window_s: float = 5.0, n_init: int = 1):
    if fully_measured(model, rec):
        return EquationError(model, rec, window_s=window_s)
    return SimulationError(model, rec, horizon_s=None, n_init=n_init)


@dataclass
class Diagnosis:
    model_nominal: PlantModel
    model_calibrated: PlantModel
    model_improved: PlantModel
    engine: object
    loc: Localisation
    base: FitResult                         # calibrated nominal
    final: FitResult                        # calibrated + findings (fitted on training rows)
    findings: list[dict] = field(default_factory=list)
    tried: list[dict] = field(default_factory=list)
    sigma: np.ndarray | None = None
    cal_report: dict = field(default_factory=dict)
    mismatch: bool = False
    verdict: str = ""
    final_all: FitResult | None = None       # final model refitted on all rows
    ablation: dict = field(default_factory=dict)   # free run: held-out RMSE with each finding removed
    integrator: dict = field(default_factory=dict)  # free run: integrator accuracy check
    uncertainty: list = field(default_factory=list)  # per finding: jackknife standard errors
    joint: FitResult | None = None          # free run: the joint multi-start fit before elimination
    replay: dict = field(default_factory=dict)  # the replay stage's check, where it ran
    negligible: dict = field(default_factory=dict)  # a negligible effect that explained the rest best
