"""Fit the catalogue's candidates and select on held-out data.

1. **Calibration** (not a finding): the model's coefficients (pump gains, link
   coefficients) may each move within +-5 % (datasheet spread); fitted by
   `scipy.optimize.least_squares` on the training rows.
2. **Localisation** of what the calibrated nominal model still misses
   (`civic.diagnose.locate`). No flagged component: no significant mismatch.
3. **Candidates** of every catalogue family where the localisation points.
4. **Selection** on held-out rows. Equation error (every tank measured): forward
   selection (`_forward`), each candidate fitted jointly with the calibration; it joins
   if it lowers the held-out BIC (`N log(SSE/N) + k log N`) by `MIN_DBIC` and the
   held-out SSE by `MIN_GAIN_FIRST` (the first) or `MIN_GAIN` (up to `MAX_FINDINGS`); one the
   held-out blocks never see act (a sensor stuck, a rim reached, in training blocks only) is
   judged with the blocks swapped, against the reference refitted the same way. Where the
   balances leave no finding, the replay stage (`_replay`) judges the candidates on the open-loop
   replay instead, if some level replays REPLAY_BAR noise sigmas off. Free run (a rig with unmeasured
   tanks): the coefficients are refitted jointly (factors `FREE_RUN_CAL`), every family's
   most general candidate is fitted together (multi-start), then backward elimination
   on blocked k-fold cross-validation in time (`_backward`; a finding acting in some rows
   only is judged by the folds that see it act in training and held out), whose last
   pass is the ablation table.
5. The selected model is refitted on all rows: the improved model (free run: multi-start,
   integrator checked).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.optimize import least_squares

from civic.plant.model import PlantModel
from civic.plant.simulate import Recording

from .compare import INVENTORY, INVENTORY_SPREAD, EquationError, SimulationError, fully_measured
from .locate import ONSET_LR, Localisation, localise, still_flagged, suspect_everywhere
from .noise import noise_sigma, robust_sigma
from .mechanisms import CATALOGUE, Coefficient, Mechanism, coefficient_paths
from .mechanisms.base import tanks_of
from .mechanisms.coefficient import CAL_SPREAD
MIN_DBIC = 10.0
MIN_GAIN = 0.10
# the first finding: the held-out SSE must fall by this much (further ones: MIN_GAIN, since they
# must beat a model that already explains the mismatch, and a second one that only trades with
# the first gains a few %). With every tank forced suspect, the best candidate on clean runs
# (seeds 1-10) gained at most 2 % (held-out BIC -0.3 at best); a V2 flow exponent of 0.45 largely
# averaged into V2's coefficient gained 7.5 % at BIC -17 (exponent 0.443)
MIN_GAIN_FIRST = 0.05
MAX_FINDINGS = 3
UNEXPLAINED_BAR = 2.0   # a balance the findings so far leave flagged at this many times the bar:
                        # later rounds try every candidate acting on it (at 1x, or flagged by
                        # the localisation, only the standing ones)
REDATE_REACH = 30.0     # s: a finding switched on mid-run is dated again this far outside its bracket
ORDER_AGREEMENT = 0.25  # a later finding: each block order's held-out gain at least this share of the other's
# a candidate whose held-out BIC is within this of the chosen one's (and significant on its own)
# is an indistinguishable alternative: reported next to the finding, never a finding itself
ALT_DBIC = 10.0
MAX_ALTERNATIVES = 3
# a rig seen through a free run (some tank unmeasured): the nominal coefficients are refitted
# jointly with the candidates (no datasheet spread to hold them), more findings may join, the
# final joint refit is multi-start and every kept finding must survive its ablation
FREE_RUN_CAL = (0.1, 5.0)
MIN_ABLATION = 0.01     # a finding stays if removing it raises the held-out RMSE by 1 %
FIXED_ABLATION = 0.05   # one without free parameters goes only if removing it lowers that RMSE by 5 %
                        # (the blocked CV's run-to-run spread on Cascaded Tanks: 0.160-0.178 V)
SWAP_WINDOW = 1.10      # free run: a finding whose removal raises the held-out RMSE by less is swap-tested
CV_BUDGET = 15          # evaluations per parameter of a warm per-fold refit
FREE_RUN_FOLDS = 3      # blocked k-fold CV in time (two-fold without unmeasured tanks)
# the replay stage: a fully measured plant whose balances leave no finding may still replay away
# from its recording. An effect close to a common factor on the chain's flows closes every balance
# in regulation (dV/dt ~ 0) and shows in transients only, under the balances' noise; the open-loop
# replay integrates it: a pump head of 0.02 (flow 4-9 % lower over T1's levels) gave no balance
# finding and replayed at 1.2-1.8 noise sigmas, where 40 clean runs (both loops) replay at 1.06 at most
REPLAY_BAR = 1.15       # replay RMS over a level's noise: below it on every level, nothing is sought
REPLAY_MIN_GAIN = 0.10  # held-out SSE fall a replay finding needs, both halves pooled, and in each half
REPLAY_FOLD_GAIN = 0.05 # (clean runs: 0.9 % and 1.2 % at best; a pump head of 0.02 on seed 33: 17 %, 21 / 12 %)
REPLAY_AVERAGE = 20     # samples averaged for the measured initial state: from one noisy first sample
                        # the reservoir's replay stood 2 sigmas off for the whole run


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


class Problem:
    """Objective plumbing: model edits -> weighted residual rows of an engine."""

    def __init__(self, model: PlantModel, rec: Recording, engine, cal: Calibration, sigma: np.ndarray):
        self.model = model
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
        first, held, params = None, [], []
        for mask in (self.folds() if folds is None else folds):
            res = self.fit(mechs, rows=mask, start_cal=start_cal, start_x0=start_x0, starts=starts, budget=budget)
            R = self.residuals(res.model, res.x0_extra)
            held.append(R[~mask])
            params.append([m.values() for m in res.mechanisms])
            if first is None:
                first = res
        first.fold_params = params
        if folds is None and len(held) == 1:
            first.held_out = held[0]          # the rows of self.val (unseen_held_out compares there)
        Rv = np.concatenate(held)
        first.fold_sse = [float(np.sum(h ** 2)) for h in held]
        first.fold_tol = MIN_GAIN if len(held) > 1 and isinstance(self.engine, EquationError) else 0.0
        if self.unmeasured:
            first.fold_tol = None     # free run: the pooled held-out error decides (one block may hold no event)
        first.val_sse = float(np.sum(Rv ** 2))
        first.val_rmse = float(np.sqrt(np.mean((Rv * self.sigma) ** 2)))
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


def _informative(r: np.ndarray) -> np.ndarray:
    """A balance's residuals less the windows it hides (exactly 0: a lost message, a clipped
    reading): with 1 % of the messages lost, 40 % of the 5 s windows touch a gap, and their zeros
    took the robust spread down to a fraction of the noise (every balance flagged)."""
    kept = r[r != 0.0]
    return kept if kept.size >= 10 else r


def make_engine(model: PlantModel, rec: Recording, window_s: float = 5.0, n_init: int = 1):
    if fully_measured(model, rec):
        return EquationError(model, rec, window_s=window_s)
    return SimulationError(model, rec, horizon_s=None, n_init=n_init)


def diagnose(model: PlantModel, rec: Recording, progress=None, window_s: float = 5.0,
             n_init: int = 1) -> Diagnosis:
    """Calibrate, localise, fit candidates, select on held-out data. See the module doc."""
    engine = make_engine(model, rec, window_s=window_s, n_init=n_init)
    free = isinstance(engine, SimulationError) and bool(engine.unmeasured(model))
    cal = Calibration.of(model, bounds=FREE_RUN_CAL if free else None)
    prob = Problem(model, rec, engine, cal, np.ones(len(engine.columns)))
    # noise weights: equation error -> robust spread of the raw nominal residual; simulation -> sensor noise
    if isinstance(engine, EquationError):
        first = prob.fit([])
        R0 = prob.residuals(first.model, first.x0_extra)
        rows = [_informative(R0[engine.train, j]) for j in range(R0.shape[1])]
        sigma = np.array([robust_sigma(r - np.median(r)) for r in rows])
        # the residual spread cannot be below what sensor noise alone gives
        sigma = np.maximum(sigma, 1e-6)
        if INVENTORY in engine.columns:
            # the inventory's spread is how well the fill is known, not its (tiny) noise
            sigma[engine.columns.index(INVENTORY)] = INVENTORY_SPREAD * model.total_volume
    else:
        sigma = np.array([max(noise_sigma(engine.Y[:, j]), 1e-3 * (np.ptp(engine.Y[:, j]) or 1.0))
                          for j in range(engine.Y.shape[1])])
    prob.sigma = sigma
    base = prob.evaluate([])
    Rb = prob.residuals(base.model, base.x0_extra)
    loc = localise(model, rec, engine, Rb * sigma, sigma, pinned=cal.pinned(base.cal))
    if isinstance(engine, EquationError) and not engine.short and not loc.flagged:
        # not on a short test run: its few held-out windows gave false findings before
        suspect_everywhere(loc, model)
    diag = Diagnosis(model, base.model, base.model, engine, loc, base, base, sigma=sigma)
    diag.cal_report = cal.report(base.cal)
    if not loc.flagged and not loc.suspect:
        diag.mismatch = False
        diag.verdict = "no significant mismatch: the calibrated nominal model explains the recording"
        diag.model_improved = _refit_all(prob, [], base).model
        return diag
    candidates = []
    for fam in CATALOGUE:
        if free and fam is Coefficient:
            continue     # the joint refit moves every coefficient already
        candidates.extend(fam.candidates(model, loc))
    if free:
        chosen, current = _backward(prob, diag, candidates, base, progress)
    else:
        # equation error: interleaved held-out blocks visit levels the training blocks may not,
        # so a sensor map is fitted with its gain tied at the readings' middle (bend and offset
        # free) and, as a variant, through the model's zero (bend and gain free: a sensor
        # calibrated far from the readings' middle): the three-parameter map slid along its flat
        # valley and extrapolated wildly there (held-out +200 BIC on a bent L2). The free run
        # keeps the general map
        candidates = [v for c in candidates
                      # a link's flow law as an exponent only: the added-linear-term form named
                      # the same links on every case tried, and doubled the flow-law fits
                      if not (c.name == "flow_law" and c.fixed.get("form") == "linear")
                      for v in ([c.tied(), c.through_zero()] if c.name == "sensor_characteristic" and
                                "offset" in c.params else [c])]
        chosen, current = _forward(prob, diag, candidates, base, progress)
        if not chosen and not engine.short and not diag.negligible:   # the balances' rest is negligible
            found = _replay(model, rec, diag, candidates, progress)
            if found:
                prob, chosen, current = found
    if progress:
        progress(1, 1, "done")
    diag.final = current
    diag.mismatch = bool(chosen) or bool(loc.flagged)
    if not diag.mismatch:
        # only suspect bursts, and nothing in the catalogue explains them on held-out data
        diag.verdict = "no significant mismatch: the calibrated nominal model explains the recording"
        diag.model_improved = _refit_all(prob, [], base).model
    elif chosen:
        start, mechs = current, chosen
        if free and diag.joint is not None:
            # two starts, the better on all rows refitted: the per-fold optimum (trained without
            # the last block) and the joint multi-start optimum of the same findings; from the
            # first alone the final refit of half the Cascaded Tanks record stopped at 0.175 V
            # where the joint optimum's values led to 0.138 V
            by_label = {m.label: m for m in diag.joint.mechanisms}
            if all(m.label in by_label for m in chosen):
                warm = [by_label[m.label] for m in chosen]
                if _all_rows_sse(prob, warm, diag.joint) < _all_rows_sse(prob, chosen, current):
                    start, mechs = diag.joint, warm
        if not free:
            mechs = _redate(prob, diag, mechs, start)
        final_all = _refit_all(prob, mechs, start)
        # a finding the fit on all rows makes negligible beside the others was a patch for them:
        # a V1 closure for 75 s (0.39 where the blocks it was judged on saw it) took the local
        # trace of an L1 offset and fell to 0.016 once the offset joined
        kept = [] if free else [i for i, m in enumerate(final_all.mechanisms)
                                if not m.negligible(m.values(), model)]
        if kept and len(kept) < len(mechs):
            mechs, diag.findings = [mechs[i] for i in kept], [diag.findings[i] for i in kept]
            final_all = _refit_all(prob, mechs, start)
        diag.model_improved = final_all.model
        diag.final_all = final_all
        if free:
            diag.integrator = check_integrator(diag.model_improved, prob, final_all)
        diag.uncertainty = uncertainty(prob, final_all, current.fold_params if free else None)
        diag.verdict = f"{len(mechs)} finding(s) significant on held-out data"
    else:
        diag.model_improved = _refit_all(prob, [], base).model
        diag.verdict = ("mismatch, but no mechanism of the catalogue explains it significantly "
                        "on held-out data" if not diag.negligible else
                        f"mismatch, best explained by a physically negligible {diag.negligible['candidate']}")
    return diag


def _forward(prob: Problem, diag: Diagnosis, candidates: list[Mechanism], base: FitResult, progress=None):
    """Forward selection on held-out data (up to MAX_FINDINGS): each round the candidate with
    the lowest held-out BIC (relative to its reference) joins if `significant`; later rounds
    try what helped on its own in the first and what acts where the findings so far leave a
    balance flagged (at UNEXPLAINED_BAR; a standing candidate at the bar or where the
    localisation flagged). A candidate the held-out blocks never see
    act is judged with the blocks swapped, against the current model refitted the same way."""
    model = prob.model
    current, chosen = base, []
    all_candidates = list(candidates)
    planned = len(candidates)
    if progress:
        progress(0, planned, "candidates")
    done = 0
    for round_ in range(MAX_FINDINGS):
        results = []          # (candidate, its fit, (fit judged, reference judged, how))
        swapped = None        # the current model evaluated with the blocks swapped (lazily)
        for cand in candidates:
            if any(c.component == cand.component for c in chosen):
                continue     # one finding per component: a second one on it (an offset on top of a
                             # sensor map, a weir on top of a spill) only trades with the first
            try:
                res = prob.evaluate(chosen + [cand], start_cal=current.cal, start_x0=current.x0_extra,
                                    starts=_starts(cand))
                judged = (res, current, "")
                if prob.unseen_held_out(res):
                    flip = prob.both_orders()[1:]
                    swapped = swapped or prob.evaluate(chosen, start_cal=current.cal, folds=flip)
                    # from the swapped reference's calibration: the candidate's optimum is near it
                    judged = (prob.evaluate(chosen + [cand], start_cal=swapped.cal, starts=_starts(cand),
                                            folds=flip), swapped, "blocks swapped")
            except RuntimeError:
                continue
            finally:
                done += 1
                if progress:
                    progress(done, planned, cand.label)
            results.append((cand, res, judged))
            if round_ == 0:
                r, ref, how = judged
                diag.tried.append(_tried(cand.label, r, ref, res.mechanisms[-1],
                                         **({"held_out": how} if how else {})))
        # physically negligible effects are not findings, however significant statistically; nor is
        # a larger effect the held-out data rank clearly below a negligible one (`_outranked`)
        tiny = [x[1].mechanisms[-1].negligible(x[1].mechanisms[-1].values(), model) for x in results]
        small = [x for x, t in zip(results, tiny) if t]
        results = [x for x, t in zip(results, tiny) if not t]
        if not results:
            break
        best = min(results, key=_heldout_dbic)
        min_gain = MIN_GAIN if chosen else MIN_GAIN_FIRST
        judged_best, ref_best, _ = best[2]
        if not significant(judged_best, ref_best, min_gain)[0] or _outranked(diag, best, small):
            break
        best = _fair_swapped(prob, chosen, results, best, min_gain)
        (cand, res, (r, ref, how)), both, both_fits = _decide_on_both_orders(prob, chosen, current, results, best,
                                                                             min_gain)
        if chosen and not how and not _holds_on_both_orders(prob, chosen, current, cand, min_gain, both_fits):
            break
        _, dbic, gain = significant(r, ref, min_gain)      # a candidate returned is significant too
        # what both orders separated from the chosen one is no longer indistinguishable from it
        pooled = {v["candidate"]: v["dbic"] for v in both}
        separated = {c for c, d in pooled.items() if d - pooled[cand.label] >= ALT_DBIC}
        # alternatives judged on the chosen one's held-out rows (a candidate judged with the blocks
        # swapped has another reference: its BIC change is no evidence against this one's)
        alternatives = _alternatives([x for x in results if x[0].label not in separated and x[2][2] == how],
                                     cand, dbic, min_gain, pooled)
        chosen.append(res.mechanisms[-1])
        chosen[:-1] = res.mechanisms[:-1]
        diag.findings.append({"mechanism": cand, "fit": res, "dbic": dbic, "gain": gain,
                              "prev": current, "alternatives": alternatives,
                              **({"held_out": how} if how else {}),
                              **({"both_orders": both, "dbic_both_orders": pooled[cand.label]} if both else {})})
        current = res
        # later rounds: what helped on its own in the first round, and what acts on a tank whose
        # balance the findings so far leave clearly flagged (a second fault's own candidates may not
        # help on their own while the first one's mismatch dominates: a T1 leak beside a V2 closure
        # fitted +3 alone, and left T1's balance at 7x the bar; with both in, T2's stood at 1.2x,
        # and a 75 s pipe23 closure re-admitted there patched it); on a tank flagged at all, now
        # or by the localisation, what acts over the whole record: with an L3 step in, T2's
        # balance stood at 1.2x the bar on one seed and 0.9x on another, and a pipe23 flow law
        # beside the step gained held-out dBIC -93 there
        helped = {t["candidate"] for t in diag.tried if t["dbic"] < 0}
        residuals, columns = prob.residuals(res.model, res.x0_extra), list(prob.engine.columns)
        unexplained = set(still_flagged(residuals, columns, UNEXPLAINED_BAR)) & set(model.tank_names)
        flagged = (set(still_flagged(residuals, columns)) | set(diag.loc.flagged)) & set(model.tank_names)
        candidates = [c for c in all_candidates if all(c.component != m.component for m in chosen)
                      and (c.label in helped or tanks_of(model, c.component) & unexplained
                           or (c.standing and tanks_of(model, c.component) & flagged))]
        planned += len(candidates)
    return chosen, current


def _replay(model: PlantModel, rec: Recording, diag: Diagnosis, candidates: list[Mechanism], progress=None):
    """The replay stage (after a forward selection that found nothing on the balances): the
    calibrated model replayed open loop from the recorded inputs; where some level departs from
    its recording by REPLAY_BAR noise sigmas (RMS), the candidates acting over the whole record
    are judged on the replay's blocked 2-fold CV in time (each half held out once) and the best
    one joins if it lowers the held-out SSE by REPLAY_MIN_GAIN, and by REPLAY_FOLD_GAIN in each
    half. Dead times are left to the balances, which see their timing directly (and each value
    costs a recompile). On a finding, `diag` takes the replay's engine, calibration and noise
    weights, and the return is
    (its Problem, [finding], its fit); otherwise None (`diag.replay` records the check). Not on a
    record with lost stretches: a replay through unknown inputs drifts (a clean run with 10 s lost
    replayed 1.27 sigmas off, and a T3 rim took the drift)."""
    gaps = getattr(rec, "gaps", None)
    if gaps is not None and gaps.any():
        diag.replay = {"skipped": "the recording has lost stretches: the inputs there are unknown"}
        return None
    engine = SimulationError(model, rec, average=REPLAY_AVERAGE)
    sigma = np.array([max(noise_sigma(engine.Y[:, j]), 1e-6) for j in range(engine.Y.shape[1])])
    prob = Problem(model, rec, engine, Calibration.of(model), sigma)
    base = prob.evaluate([])
    ratio = np.sqrt(np.mean(prob.residuals(base.model, base.x0_extra) ** 2, axis=0))
    diag.replay = {"rms_over_noise": {s: round(float(r), 3) for s, r in zip(engine.columns, ratio)},
                   "bar": REPLAY_BAR}
    if ratio.max() < REPLAY_BAR:
        return None
    pool = [c for c in candidates if c.name != "dead_time" and c.switch_key is None and c.switched_off is None]
    # screened on the first half's fold (trained on the first half, the second held out): a candidate
    # that falls short of REPLAY_FOLD_GAIN there cannot meet the rule, which asks it of each half
    first = prob.folds()[:1]
    ref_first = prob.evaluate([], start_cal=base.cal, folds=first)
    results, small = [], []
    for i, cand in enumerate(pool):
        if progress:
            progress(i, len(pool), f"replay: {cand.label}")
        try:
            res = prob.evaluate([cand], start_cal=base.cal, starts=_starts(cand), folds=first)
            if _fold_gains(res, ref_first)[0] >= REPLAY_FOLD_GAIN:
                res = prob.evaluate([cand], start_cal=base.cal, starts=_starts(cand))
        except RuntimeError:
            continue
        fitted = res.mechanisms[-1]
        ref = base if len(res.fold_sse) == len(base.fold_sse) else ref_first
        diag.tried.append(_tried(cand.label, res, ref, fitted, error=engine.kind))
        if ref is base:
            (small if fitted.negligible(fitted.values(), model) else results).append((cand, res, (res, base, "")))
    good = [x for x in results if significant(x[1], base, REPLAY_MIN_GAIN)[0]
            and min(_fold_gains(x[1], base)) >= REPLAY_FOLD_GAIN]
    if not good:
        return None
    best = min(good, key=lambda x: x[1].val_bic)
    if _outranked(diag, best, small):
        return None
    cand, res, _ = best
    _, dbic, gain = significant(res, base, REPLAY_MIN_GAIN)
    diag.engine, diag.sigma, diag.base = engine, sigma, base
    diag.model_calibrated = base.model
    diag.cal_report = prob.cal.report(base.cal)
    diag.findings.append({"mechanism": cand, "fit": res, "dbic": dbic, "gain": gain, "prev": base,
                          "alternatives": _alternatives(results, cand, dbic, REPLAY_MIN_GAIN),
                          "replay": diag.replay["rms_over_noise"]})
    return prob, [res.mechanisms[-1]], res


def _outranked(diag: Diagnosis, best: tuple, small: list) -> bool:
    """True (and noted in `diag.negligible`) when a physically negligible candidate explains the
    held-out data better than `best`, the best of the others, by ALT_DBIC: the mismatch is then
    negligible, and `best` would only be the largest effect that fits it somewhat. A pump dead
    zone of 0.5 % of the command (negligible below 1 %) replayed best, held-out BIC -6864, and a
    T1 rim at the record's peak level (-2667) was named."""
    if not small:
        return False
    top = min(small, key=_heldout_dbic)
    if _heldout_dbic(top) > _heldout_dbic(best) - ALT_DBIC:
        return False
    diag.negligible = {"candidate": top[0].label, "heldout_dbic": round(float(_heldout_dbic(top)), 1),
                       "parameters": top[1].mechanisms[-1].report_parameters(),
                       "outranked": best[0].label, "outranked_dbic": round(float(_heldout_dbic(best)), 1)}
    return True


def _heldout_dbic(x: tuple) -> float:
    """A round's result (candidate, fit, (judged, reference, how)): the judged fit's held-out BIC
    less its reference's, the figure candidates are ranked by."""
    return x[2][0].val_bic - x[2][1].val_bic


def _fair_swapped(prob: Problem, chosen: list, results: list, best: tuple, min_gain: float) -> tuple:
    """A candidate judged with the blocks swapped leads the round on another reference than the
    candidates judged on the held-out blocks: the best of those, where significant, is judged with
    the blocks swapped too, against the same reference, and leads if it does as well there. An L1
    offset of 0.1 (held-out BIC -89) lost to a T2 leak from 205 to 260 s judged swapped (-97.5),
    and a V1 closure over the same spell followed it."""
    ref, how = best[2][1], best[2][2]
    plain = [x for x in results if not x[2][2] and significant(x[2][0], x[2][1], min_gain)[0]]
    if not how or not plain:
        return best
    other = min(plain, key=_heldout_dbic)
    flipped = prob.evaluate(chosen + [other[0]], start_cal=ref.cal, starts=_starts(other[0]),
                            folds=prob.both_orders()[1:])
    if flipped.val_bic - ref.val_bic <= _heldout_dbic(best) and significant(flipped, ref, min_gain)[0]:
        return other
    return best


def _tried(label: str, res: FitResult, ref: FitResult, mech: Mechanism, **extra) -> dict:
    """A `Diagnosis.tried` record: `res` (with `mech`) judged on held-out data against `ref`."""
    return {"candidate": label, "val_bic": res.val_bic, "dbic": res.val_bic - ref.val_bic,
            "val_gain": 1 - res.val_sse / max(ref.val_sse, 1e-300), "fold_sse": list(res.fold_sse),
            "base_fold_sse": list(ref.fold_sse), "parameters": mech.report_parameters(), **extra}


def _fold_gains(res: FitResult, ref: FitResult) -> list[float]:
    """Each fold's fall of the held-out SSE against the reference's."""
    return [1 - a / max(b, 1e-300) for a, b in zip(res.fold_sse, ref.fold_sse)]


def _decide_on_both_orders(prob: Problem, chosen: list, current: FitResult, results: list, best: tuple,
                           min_gain: float):
    """The (candidate, fit, judged) of `results` to adopt among `best` and the candidates one block order
    does not separate from it, all significant on the held-out blocks: the variants of its mechanism on
    its component (a sensor map tied at the readings' middle, or bent through the rim: they fit the
    training blocks alike, yet may extrapolate differently) and the contenders within ALT_DBIC of its
    held-out BIC. They are decided on both block orders (each order's training blocks fitted, the
    other's judged; pooled held-out BIC): twice the held-out evidence. On PI seed 43 the tied L1 map won
    on one order (n = 1.15, an offset) and missed the other by 9x; the map through the rim holds on
    both. On 5 min records a V2 valve characteristic led a V2 flow exponent of 0.7 by 1.9 on one order
    and lost by 283 on both. Also returns, when that decision was taken, each one's pooled held-out BIC
    change against the model without it (best first)."""
    cand, how = best[0], best[2][2]
    top = _heldout_dbic(best)
    pool = [x for x in results if not x[2][2] and significant(x[2][0], x[2][1], min_gain)[0]
            and ((x[0].name, x[0].component) == (cand.name, cand.component) or _heldout_dbic(x) - top < ALT_DBIC)]
    if len(pool) < 2 or how or prob.engine.short or not isinstance(prob.engine, EquationError):
        return best, [], {}
    both = prob.both_orders()
    ref = prob.evaluate(chosen, start_cal=current.cal, folds=both)
    fits = {x[0].label: prob.evaluate(chosen + [x[0]], start_cal=current.cal, starts=_starts(x[0]), folds=both)
            for x in pool}
    scored = [fits[x[0].label].val_bic - ref.val_bic for x in pool]
    i = int(np.argmin(scored))
    decided = sorted(({"candidate": x[0].label, "dbic": d} for x, d in zip(pool, scored)), key=lambda v: v["dbic"])
    return (pool[i] if scored[i] < 0 else best), decided, {"reference": ref, **fits}


def _holds_on_both_orders(prob: Problem, chosen: list, current: FitResult, cand: Mechanism,
                          min_gain: float, fits: dict) -> bool:
    """A finding after the first must hold on both block orders of an equation-error record
    (each order's training blocks fitted, the other's judged): significant pooled, and each
    order's held-out SSE falling by at least ORDER_AGREEMENT of the other's. A real second effect
    shows in both; a patch for the first finding's imperfect fit shows in one: an L3 map
    (n = 0.85) took a T2 leak of c = 0.0017 on one order (held-out SSE -19 %) that the other
    fitted at 0.0003 (-0.7 %). Short test runs too (their folds are both orders): on three 40 s
    fill tests with VM2 closed a fifth, after `coefficient P1`, an L1 map or offset took the one
    window where T1 reaches its rim (one order -41 to -70 %, the other -1.5 to +3 %).
    `fits`: the both-order fits _decide_on_both_orders made already ("reference" and candidate
    labels), reused rather than refitted."""
    if not isinstance(prob.engine, EquationError):
        return True
    both = prob.both_orders()
    ref = fits.get("reference") or prob.evaluate(chosen, start_cal=current.cal, folds=both)
    res = fits.get(cand.label) or prob.evaluate(chosen + [cand], start_cal=current.cal, starts=_starts(cand),
                                                folds=both)
    gains = _fold_gains(res, ref)
    return significant(res, ref, min_gain)[0] and min(gains) >= ORDER_AGREEMENT * max(gains)


def _alternatives(results, cand: Mechanism, dbic: float, min_gain: float = MIN_GAIN,
                  pooled: dict | None = None) -> list[dict]:
    """Candidates the held-out data does not separate from the chosen one: significant on their
    own against their reference, and within ALT_DBIC of the chosen one's held-out BIC gain
    (`dbic`; best first). They are reported, never added as findings; a variant of the chosen
    mechanism on the same component is not an alternative explanation. Where the choice was
    decided on both block orders (`pooled`: candidate label -> pooled held-out BIC change), an
    alternative decided with it is compared with the chosen one on that pooled evidence."""
    pooled = pooled or {}
    out = []
    for c, res, (r, ref, _) in results:
        ok, d, gain = significant(r, ref, min_gain)
        if (c.name, c.component) == (cand.name, cand.component) or d - dbic >= ALT_DBIC:
            continue
        if ok:
            alt = {"mechanism": c, "fit": res, "dbic": d, "gain": gain, "dbic_vs_chosen": d - dbic}
            if c.label in pooled and cand.label in pooled:
                alt["dbic_both_orders"] = pooled[c.label]
                alt["dbic_vs_chosen"] = pooled[c.label] - pooled[cand.label]
            out.append(alt)
    return sorted(out, key=lambda a: a["dbic_vs_chosen"])[:MAX_ALTERNATIVES]


def uncertainty(prob: Problem, res: FitResult, fold_params: list | None = None) -> list[dict]:
    """Per finding of `res` (fitted on all rows): the standard error of each free parameter from a
    delete-one-block jackknife. Equation error: N_BLOCKS contiguous blocks, each left out once, the
    model refitted from `res` (cheap: vectorised residuals). Free run: the per-fold fits of the
    blocked cross-validation (`fold_params`, each fold leaves one block out), no extra fits."""
    from .compare import N_BLOCKS

    mechs = res.mechanisms
    if not mechs:
        return []
    method = (f"spread of the {len(fold_params)} per-fold refits of the blocked cross-validation (each leaves one "
              "block out; warm-started with a short budget, so a lower bound)") if fold_params is not None else None
    if fold_params is None:
        n = len(prob.engine.train)
        block = np.minimum(np.arange(n) * N_BLOCKS // max(n, 1), N_BLOCKS - 1)
        fold_params = []
        for b in range(N_BLOCKS):
            try:
                r = prob.fit(mechs, rows=block != b, start_cal=res.cal, start_x0=res.x0_extra, budget=6)
            except RuntimeError:
                continue
            fold_params.append([m.values() for m in r.mechanisms])
    k = len(fold_params)
    out = []
    for i, m in enumerate(mechs):
        se = {}
        for name in m.names:
            vals = np.array([fp[i][name] for fp in fold_params if i < len(fp) and name in fp[i]], float)
            if len(vals) >= 2:
                se[name] = float(np.sqrt((len(vals) - 1) / len(vals) * np.sum((vals - vals.mean()) ** 2)))
        out.append({"method": method or f"delete-one-block jackknife ({k} blocks, refitted)", "stderr": se,
                    "blocks": [{n: fp[i][n] for n in m.names} for fp in fold_params if i < len(fp)]})
    return out


def _starts(cand: Mechanism) -> list:
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


def _redate(prob: Problem, diag: Diagnosis, mechs: list[Mechanism], start: FitResult) -> list[Mechanism]:
    """A finding switched on or off mid-run (a closure's onset, a leak's `since`, either's
    `until`), dated again in the fitted model: each time profiled over window starts from
    REDATE_REACH before the change point's bracket to as far after it, each refitted on all rows
    with the calibration. The change point works on the nominal calibration, where the fault leans
    on the coefficients: a T3 leak opening at 300 s with a drain test (V2 wide open) from 301 to
    316 s was 4 % beside V2's flow there, taken by V2's coefficient, and stepped at 315 s (bracket
    305-325 s); a T3 leak repaired at 300 s, as T3 drained from 280 to 295 s, seemed to stop at
    280 s (bracket 270-290 s). Where the likeliest time falls outside the change point's bracket
    it is adopted, and the bracket grows to hold every time within ONSET_LR of it (the change
    point's stays: in the fitted model the profile is flatter, a T1 leak's 295-305 s became
    295-340 s), unless the change point's own date is within ONSET_LR of it too: the date stands
    then, the bracket grown the same way. A reading's step is dated to the sample
    (`Localisation.reading_steps`) and moves only where a window start beats that date by
    ONSET_LR. A date guessed on a grid (a drift's start) takes the profile's best and its
    ONSET_LR bracket. The finding's own records follow."""
    out = list(mechs)
    for i, m in enumerate(mechs):
        for key, lo_key, hi_key in ((m.switch_key, "not_before", "not_after"),
                                    ("until", "until_not_before", "until_not_after")):
            if key is not None and key in out[i].fixed:
                out[i] = _redate_one(prob, diag, out, i, key, lo_key, hi_key, start)
    return out


def _redate_one(prob: Problem, diag: Diagnosis, mechs: list[Mechanism], i: int, key: str, lo_key: str,
                hi_key: str, start: FitResult) -> Mechanism:
    """`mechs[i]` with its time `key` dated again (see `_redate`); its bracket in `lo_key`,
    `hi_key`."""
    m = mechs[i]
    rows = np.ones_like(prob.engine.train)
    starts = prob.engine.row_times[:, 0]
    width = float(prob.engine.row_times[0, 1] - starts[0])       # one window
    lo, hi = m.fixed.get(lo_key, m.fixed[key]), m.fixed.get(hi_key, m.fixed[key])
    # its own date among them: a reading's step is dated to the sample, between window starts
    grid = np.union1d(starts[(starts >= lo - REDATE_REACH) & (starts <= hi + REDATE_REACH)], [m.fixed[key]])
    if key == "until":
        grid = grid[grid > (m.switched_on or 0.0) + width]           # off after it was switched on
    else:
        grid = grid[grid < m.fixed.get("until", np.inf) - width]     # switched on before it was off
    if grid.size < 2:
        return m
    fits = [prob.fit(mechs[:i] + [m.with_fixed(**{key: float(t)})] + mechs[i + 1:], rows=rows,
                     start_cal=start.cal, start_x0=start.x0_extra) for t in grid]
    sse = np.array([f.train_sse for f in fits])
    best = float(grid[int(np.argmin(sse))])
    near = grid[sse <= sse.min() + ONSET_LR]
    grown = {lo_key: min(lo, float(near[0]) - width), hi_key: max(hi, float(near[-1]) + width)}
    if key != "until" and m.fixed.get("guessed"):
        # a date guessed on a grid (a drift's start): the profile's best, its own bracket
        dated = {key: best, lo_key: max(float(near[0]) - width, 0.0), hi_key: float(near[-1]) + width}
    elif lo <= best <= hi:
        return m        # the change point's date stands, with its (sharper) bracket
    elif sse[grid == m.fixed[key]][0] <= sse.min() + ONSET_LR:
        if hi - lo < width:
            return m    # a date the readings give to the sample moves only on evidence (the
                        # balance rows around a reading's step may be hidden: a flat profile)
        # nor does the change point's: a profile as flat there as at its best keeps the date and
        # takes the flat stretch into the bracket. VM1 closed at 180 s under PI, the drain shut
        # from 120 to 160 s: the change point said 180 s (105-195), the profile 100 s by 0.08
        dated = grown
    else:
        dated = {key: best, **grown}
    # the forward selection's i-th finding is this mechanism (its label, its intervals)
    for x in (diag.findings[i]["mechanism"], diag.findings[i]["fit"].mechanisms[-1]):
        x.fixed.update(dated)
    return m.with_fixed(**dated)


def _all_rows_sse(prob: Problem, mechs: list[Mechanism], start: FitResult) -> float:
    """Weighted SSE on all rows of `mechs` at their current values, from `start`'s calibration
    and unmeasured initial volumes (no fit)."""
    model = prob.build(mechs, [m.x0 for m in mechs], start.cal)
    return float(np.sum(prob.residuals(model, start.x0_extra) ** 2))


def _refit_all(prob: Problem, mechs: list[Mechanism], start: FitResult) -> FitResult:
    """Final parameters from all rows (training and held out)."""
    rows = np.ones_like(prob.engine.train)
    return prob.fit(mechs, rows=rows, start_cal=start.cal, start_x0=start.x0_extra)


def _general(candidates: list[Mechanism]) -> list[Mechanism]:
    """One candidate per family and component, the most general variant (a split spill covers
    all-in and all-out, a sensor characteristic covers an offset); dead times (structural:
    a recompile per value) stay out of the joint fit."""
    best: dict = {}
    for c in candidates:
        if c.name in ("dead_time", "leak"):
            continue
        key = (getattr(c, "general_key", c.name), c.component)
        if key not in best or len(c.params) > len(best[key].params):
            best[key] = c
    shaped = {c.component for c in best.values() if c.name == "sensor_characteristic"}
    return [c for (name, comp), c in best.items() if not (name == "sensor_offset" and comp in shaped)]


def _removal_score(w: FitResult, current: FitResult, folds: list[int] | None = None) -> float:
    """How much removing a finding raises the held-out free-run RMSE (1: no change): pooled over
    every fold, or over the `folds` that can judge it (`_judging_folds`)."""
    if folds is None or len(folds) == len(current.fold_sse):
        return w.val_rmse / max(current.val_rmse, 1e-300)
    return math.sqrt(sum(w.fold_sse[f] for f in folds) / max(sum(current.fold_sse[f] for f in folds), 1e-300))


def _judging_folds(prob: Problem, fit: FitResult) -> list[list[int] | None]:
    """Per mechanism of `fit`, the cross-validation folds that can judge it. One that acts
    only in some rows (a spill above a rim) is judged by the folds that see it act both in
    their training rows (where they fit it) and in their held-out rows (where it matters): a
    fold that never saw the spill in training only extrapolates what it could not fit, one that
    never holds it out sees its side effects only. None: it acts everywhere (every fold judges);
    []: no fold can (the rows where it acts sit in one block), so the data cannot remove it.
    On the second half of the Cascaded Tanks record T2 reaches its sensor's clip once, in the
    last block: the pooled error, whose one telling fold never fitted the spill there, dropped
    it, and the model then stored water above the sensor's range on the first half."""
    prob.engine.x0_extra = dict(fit.x0_extra)
    vol = prob.engine.simulate(fit.model)["volumes"][prob.engine.skip:]
    folds = prob.folds()
    out = []
    for m in fit.mechanisms:
        rows = m.active_rows(fit.model, vol)
        out.append(None if rows is None else
                   [f for f, mask in enumerate(folds) if (rows & mask).any() and (rows & ~mask).any()])
    return out


def _removable(m: Mechanism, score: float) -> bool:
    """Backward elimination drops a finding whose removal raises the held-out RMSE by less than
    MIN_ABLATION: parsimony, fewer parameters to fit. A finding without free parameters (a spill
    where the sensor clips: its rim is read from the data) adds none, so it goes only when its
    removal *lowers* the held-out RMSE beyond the cross-validation's own spread (FIXED_ABLATION).
    On half of the Cascaded Tanks record (one brief clip episode) removing T2's spill changed
    the held-out RMSE by -0.02 % and -1.7 % in two passes, and the model without it, transferred
    to the other half's long overflow, stored water above the sensor's range (docs/diagnose.md)."""
    return score <= (1 + MIN_ABLATION if m.params else 1 - FIXED_ABLATION)


def _free_rim_last(c: Mechanism) -> bool:
    """Sort key of the free-run joint fit: an overflow with a free rim goes last (its extra starts
    spread the rim)."""
    return bool(_starts(c)) and c.name == "overflow" and "volume" in c.params


def _backward(prob: Problem, diag: Diagnosis, candidates: list[Mechanism], base: FitResult, progress=None):
    """Free run: every family's most general candidate fitted jointly (multi-start, all rows),
    then backward elimination on blocked cross-validation in time: each finding removed and
    the rest refitted per fold; while some removal does not raise the held-out free-run RMSE
    (over the folds that can judge it, `_judging_folds`) by MIN_ABLATION, the least useful
    finding goes. The last pass is the ablation table;
    findings are ordered by their contribution."""
    # a free rim is the flattest parameter: that candidate goes last, its extra starts spread the rim
    mechs = sorted(_general(candidates), key=_free_rim_last)
    every = np.ones_like(prob.engine.train)
    # each candidate alone first: the joint fit also starts from the best single one's values
    singles = []
    for i, m in enumerate(mechs):
        if progress:
            progress(i, len(mechs) + 1, f"alone: {m.label}")
        singles.append(prob.fit([m], rows=every, start_cal=base.cal, start_x0=base.x0_extra, starts=_starts(m)))
    if progress:
        progress(len(mechs), len(mechs) + 1, f"joint fit of {len(mechs)} candidates (multi-start)")
    fits = [prob.fit(mechs, rows=every, start_cal=base.cal, start_x0=base.x0_extra,
                     starts=_starts(mechs[-1]) if mechs else None)]
    if singles:
        k = int(np.argmin([r.train_sse for r in singles]))
        warm = [singles[k].mechanisms[0] if j == k else m for j, m in enumerate(mechs)]
        fits.append(prob.fit(warm, rows=every, start_cal=singles[k].cal, start_x0=singles[k].x0_extra))
    # the objective minimised: all rows (`train_sse` alone covers the first 65 %). Picking the start
    # by the blocked CV's held-out RMSE instead picked the same fit on Cascaded Tanks (whole
    # record and both halves)
    full = min(fits, key=lambda r: r.train_sse + r.val_sse)
    diag.joint = full
    # physically negligible in the joint fit: not a finding, and no use refitting it per fold
    kept = [(m, j) for m, j in zip(full.mechanisms, _judging_folds(prob, full))
            if not m.negligible(m.values(), prob.model)]
    mechs, judges = [m for m, _ in kept], [j for _, j in kept]
    # per-fold refits start at the joint optimum: a short budget suffices
    start = dict(start_cal=full.cal, start_x0=full.x0_extra, budget=CV_BUDGET)
    current = prob.evaluate(mechs, **start)
    first_pass = True
    while mechs:
        without = []
        for i, m in enumerate(mechs):
            if progress:
                progress(i, len(mechs), f"cross-validation: without {m.label}")
            without.append(prob.evaluate(mechs[:i] + mechs[i + 1:], **start))
        if first_pass:
            for m, w in zip(mechs, without):
                diag.tried.append(_tried(m.label, current, w, m))
            first_pass = False
        score = [_removal_score(w, current, judges[j]) for j, w in enumerate(without)]
        eligible = [j for j, m in enumerate(mechs) if judges[j] != [] and _removable(m, score[j])]
        if not eligible:
            break
        i = min(eligible, key=lambda j: score[j])
        mechs, judges = mechs[:i] + mechs[i + 1:], judges[:i] + judges[i + 1:]
        current = without[i]
    if not mechs:
        return [], base
    order = sorted(range(len(mechs)), key=lambda i: -_removal_score(without[i], current))
    chosen = [mechs[i] for i in order]
    current.mechanisms = list(chosen)
    current.fold_params = [[fp[i] for i in order] for fp in current.fold_params]
    held = {m.label for m in chosen}
    pool = [m for m in full.mechanisms if m.label not in held]
    for i in order:
        m, w = mechs[i], without[i]
        others = [x for x in chosen if x is not m]
        alternatives = []
        if _removal_score(w, current) < SWAP_WINDOW:
            alternatives = _swaps(prob, m, others, current, w, pool, start, progress)
        diag.findings.append({"mechanism": m, "fit": replace(current, mechanisms=others + [m]),
                              "dbic": current.val_bic - w.val_bic,
                              "gain": 1 - current.val_sse / max(w.val_sse, 1e-300), "prev": w,
                              "heldout_rmse_without": w.val_rmse, "alternatives": alternatives})
    diag.ablation = {"heldout_rmse": current.val_rmse, "folds": len(prob.folds()),
                     "without": [{"finding": mechs[i].label, "heldout_rmse": without[i].val_rmse,
                                  "judged_by_folds": "all" if judges[i] is None else judges[i]}
                                 for i in order]}
    return chosen, current


def _swaps(prob: Problem, finding: Mechanism, others: list[Mechanism], current: FitResult, without: FitResult,
           pool: list[Mechanism], start: dict, progress=None) -> list[dict]:
    """Free run: the candidates backward elimination dropped that, put in the place of a weakly
    supported `finding` (its removal raises the held-out RMSE by less than SWAP_WINDOW) and the
    rest refitted per fold, explain the held-out data as well: held-out RMSE within MIN_ABLATION
    of the chosen set's and below the set without the finding, and not negligible. The record
    cannot tell them apart (best first); like the equation error's, they are never findings and
    a variant of the finding's own family on its component is not one."""
    out = []
    for j, c in enumerate(pool):
        if (c.name, c.component) == (finding.name, finding.component):
            continue
        if progress:
            progress(j, len(pool), f"swap: {c.label} for {finding.label}")
        try:
            r = prob.evaluate(others + [c], **start)
        except RuntimeError:
            continue
        alt = r.mechanisms[-1]
        if (r.val_rmse <= current.val_rmse * (1 + MIN_ABLATION) and r.val_rmse < without.val_rmse
                and not alt.negligible(alt.values(), prob.model)):
            out.append({"mechanism": c, "fit": r, "dbic": r.val_bic - without.val_bic,
                        "gain": 1 - r.val_sse / max(without.val_sse, 1e-300),
                        "dbic_vs_chosen": r.val_bic - current.val_bic})
    return sorted(out, key=lambda a: a["fit"].val_rmse)[:MAX_ALTERNATIVES]


def check_integrator(model: PlantModel, prob: Problem, res: FitResult, tol: float = 1.0) -> dict:
    """The fixed-step integrator against one with 8x the substeps, from the fitted state: the
    substeps double (up to 64) until the outputs differ by less than `tol` x the noise sigma."""
    eng = prob.engine
    eng.x0_extra = dict(res.x0_extra)
    while True:
        fine = model.copy()
        fine.substeps = 8 * model.substeps
        P = np.stack([eng.simulate(model)[s] for s in eng.columns], axis=1)
        F = np.stack([eng.simulate(fine)[s] for s in eng.columns], axis=1)
        dev = float(np.max(np.abs(P - F) / prob.sigma))
        if dev < tol or model.substeps >= 64:
            return {"substeps": model.substeps, "max_deviation_sigma": round(dev, 4),
                    "reference_substeps": fine.substeps}
        model.substeps *= 2
