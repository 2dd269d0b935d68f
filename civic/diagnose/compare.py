"""Model vs recording: equation error and simulation error.

Two ways to confront a `PlantModel` with a recording:

* **Equation error** (`EquationError`, needs every tank measured): the
  per-tank mass balance evaluated on the *measured* states. Over consecutive
  windows of `window_s` seconds, the measured volume change of each tank is
  compared with the integral of the model's flows computed from the measured
  levels and the recorded commands (valve positioners, dead times, pump head,
  links, overflow spill, sensor gain/offset/saturation all taken from the
  model). It cannot drift, does not care about the closed loop, and is cheap
  (vectorised numpy): this is what the fitter uses.
* **Simulation error** (`SimulationError`): drive the model with the recorded
  inputs from the recorded initial state (open loop) and compare the sensor
  signals; `horizon_s` restarts the simulation from the measured state every
  horizon (multiple shooting) when all tanks are measured. Used for the
  before/after RMSE and, when some tanks are unmeasured (e.g. the Cascaded
  Tanks benchmark), for fitting too.

Both expose `residuals(model) -> (rows, columns)` with `columns` (tank or
signal names), `row_times` ([t0, t1] per row, seconds) and a boolean
`train` mask (the rest is held out).
"""
from __future__ import annotations

import math

import numpy as np
from scipy.ndimage import uniform_filter1d
from scipy.signal import lfilter

from civic.errors import CivicError
from civic.plant.model import OUTSIDE, PlantModel
from civic.plant.noise import noise_sigma
from civic.plant.simulate import Recording, initial_state, inputs_matrix, measured_state, simulate
from civic.plant.simulate import flows as plant_flows

N_BLOCKS = 6          # interleaved train / held-out blocks (even: train, odd: held out)
INVENTORY = "inventory"   # equation-error column: measured sum of the volumes vs the stated total
# how far a real fill may sit from the datasheet's total water, as a fraction of it: the
# inventory column's sigma (recorded plants sum to within 0.25 % of their 40 L)
INVENTORY_SPREAD = 0.005
# the inventory cannot tell an offset on a sensor whose level drives no flow (the reservoir's
# L4) from a fill this far off the stated total: flagged, and such an offset a finding,
# only beyond INVENTORY_BAND x its sigma (fills within 0.25 % leave a 0.1 L median)
INVENTORY_BAND = 1.25
RIM_TOL = 0.03       # L: a measured volume this close below the rim counts as at the rim...
# ...or within this many sigmas of the smoothed reading's noise, if more. With the gaps closed
# this keeps every sample of a stay at the rim, whether the rim is the datasheet's or the median
# reading of a plateau (what the diagnosis gives a tank it sees held); 6.5 sigmas spilled early
# enough on a tank nearing its datasheet rim to bend a fitted sensor map (L1 n = 1.1 fitted 1.155)
RIM_SIGMAS = 4.0
RIM_GAP = 7          # samples: shorter dips below that band are noise, not the tank leaving its rim
STARVED_ITERATIONS = 50   # secant passes of a starving pump and the spill it feeds (`flows`)
CACHE_ENTRIES = 256   # parameter-dependent pieces an equation error keeps (`EquationError._cached`)


def holdout_mask(n: int, blocks: int = N_BLOCKS) -> np.ndarray:
    """True = training row. Contiguous blocks, alternating train / held out."""
    b = np.minimum((np.arange(n) * blocks) // max(n, 1), blocks - 1)
    return (b % 2) == 0


def rmse(a, b) -> float:
    d = np.asarray(a, float) - np.asarray(b, float)
    return float(np.sqrt(np.mean(d * d))) if d.size else float("nan")


def _zoh_average(u: np.ndarray, delay: float, dt: float) -> np.ndarray:
    """Average over each sample interval [k dt, (k+1) dt] of the zero-order-held u delayed by `delay`."""
    n = len(u)
    knots = np.arange(n + 1) * dt
    cum = np.concatenate(([0.0], np.cumsum(u) * dt))
    a = knots[:-1] - delay
    b = knots[1:] - delay

    def c(x):
        inside = np.interp(x, knots, cum)
        return np.where(x < 0, u[0] * x, inside)

    return (c(b) - c(a)) / dt


def _ends(starts: list, ends: list, n1: int) -> np.ndarray:
    """(2 n1, k) columns: each start series over each end series, column-major (the generated
    flow code reads whole columns)."""
    out = np.empty((2 * n1, len(starts)), order="F")
    for j, (a, b) in enumerate(zip(starts, ends)):
        out[:n1, j] = a
        out[n1:, j] = b
    return out


def closed_gaps(mask: np.ndarray, width: int) -> np.ndarray:
    """`mask` with its gaps shorter than `width` samples filled; a gap at either end is kept.

    The morphological closing by `width` samples (record ends padded with their own value),
    done on the run boundaries: the equation error calls it on every residual evaluation."""
    mask = np.asarray(mask, bool)
    if mask.all() or not mask.any():
        return mask
    d = np.diff(mask.astype(np.int8))
    gap_start = np.flatnonzero(d == -1) + 1                 # first False after a True
    gap_end = np.flatnonzero(d == 1) + 1                    # first True after a False
    if not mask[0]:
        gap_end = gap_end[1:]                               # the record starts in a gap: kept
    if not mask[-1]:
        gap_start = gap_start[:-1]                          # a gap running to the end: kept
    short = gap_end - gap_start < width
    if not short.any():
        return mask
    cover = np.zeros(mask.size + 1, np.int32)
    np.add.at(cover, gap_start[short], 1)
    np.add.at(cover, gap_end[short], -1)
    return mask | (np.cumsum(cover[:-1]) > 0)


class EquationError:
    """Per-tank windowed mass-balance residuals on the measured states (litres per window)."""

    kind = "equation"

    def __init__(self, model: PlantModel, rec: Recording, window_s: float = 5.0, smooth: int = 5):
        self.rec = rec
        n = len(rec.t)
        self.n = n
        self.dt = float(model.dt)
        # short recordings (a 18 s drain test): shorter windows, at least 24 of them
        self.W = max(5, min(int(round(window_s / self.dt)), (n - 1) // 24))
        # a short record (windows shortened to keep 24 of them): every block is held out once
        self.short = self.W < int(round(window_s / self.dt))
        self.nwin = (n - 1) // self.W
        if self.nwin < 6:
            raise CivicError(f"{rec.path}: too short for the equation error ({n} samples)")
        # a closed circuit whose total water is stated: the sum of the measured volumes must
        # stay at that total less what the model lets out. This is the one check that sees a
        # constant offset on a sensor whose level drives no flow (a reservoir's)
        self.columns = model.tank_names + ([INVENTORY] if model.total_volume is not None else [])
        # which balances a saturated tank's hidden volume spoils: fixed by the nominal model's links
        # and overflows (a tank clipped below its rim may be spilling: a sensor clip in the loop
        # lets the controller fill it to the rim), so a candidate that adds a link (a leak, a
        # spill) is judged on the rows its reference is judged on, not credited with the noise
        # of the rows its link would hide
        tidx = {t.name: i for i, t in enumerate(model.tanks)}
        self.coupled = [(tidx[lk.from_], tidx[lk.to], lk.law == "bidirectional")
                        for lk in model.links if lk.to != OUTSIDE]
        self.coupled += [(i, tidx[dst], False) for i in model._overflow_order()
                         for dst, _ in model.tanks[i].overflow.targets() if dst != OUTSIDE]
        sensed = {}
        for s in model.sensors:
            if s.name in rec.signals and s.tank not in sensed:
                sensed[s.tank] = s.name
        missing = [t for t in model.tank_names if t not in sensed]
        if missing:
            raise CivicError(f"equation error needs every tank measured; unmeasured: {', '.join(missing)}")
        self.sensor_of = sensed
        self.smooth = smooth
        self.raw = {k: np.asarray(v, float) for k, v in rec.signals.items()}
        self.ys = {s: uniform_filter1d(self.raw[s], smooth, mode="nearest") for s in sensed.values()}
        # a tank at its rim reads the rim +- the smoothed noise (the rim: the datasheet's, a
        # plateau's median reading, or a fitted one): every sample within RIM_SIGMAS of those
        # sigmas below it counts as at the rim, and short dips below are closed
        self.rim_tol = {}
        for tk in model.tanks:
            s = model.find("sensor", sensed[tk.name])
            per_reading = (tk.area if s.quantity == "level" else 1.0) / max(abs(s.gain), 1e-9)
            sig = noise_sigma(self.raw[s.name]) / math.sqrt(smooth) * per_reading
            self.rim_tol[tk.name] = max(RIM_TOL, RIM_SIGMAS * sig)
        self.U = inputs_matrix(model, {k: rec.signals[k] for k in model.input_names}, n)
        self.input_index = {k: i for i, k in enumerate(model.input_names)}
        k0 = np.arange(self.nwin) * self.W
        self.k0, self.k1 = k0, k0 + self.W
        t = np.arange(n) * self.dt
        self.t = t
        self.row_times = np.stack([t[self.k0], t[self.k1]], axis=1)
        self.train = holdout_mask(self.nwin)
        self._cache = {}
        gaps = getattr(rec, "gaps", None)
        # samples filled in for lost messages: windows touching them carry no information
        self.gap_rows = gaps if gaps is not None and gaps.any() else None

    # ---- pieces that depend on a few parameters only (cached) -----------------------
    def _cached(self, key, make):
        """The cached value under `key`, made on a miss. The cache is emptied when it outgrows
        CACHE_ENTRIES: a fit that moves a cached parameter (a dead time, a sensor's clip) makes
        an entry per evaluation."""
        hit = self._cache.get(key)
        if hit is None:
            if len(self._cache) > CACHE_ENTRIES:
                self._cache.clear()
            hit = self._cache[key] = make()
        return hit

    def _pump_avg(self, inp: str, delay: float) -> np.ndarray:
        return self._cached(("p", inp, round(delay, 9)),
                            lambda: _zoh_average(self.U[:, self.input_index[inp]], delay, self.dt))

    def _opening(self, v) -> np.ndarray:
        """Valve opening at the sample instants (exact first order under a held delayed command)."""
        def make():
            ub = _zoh_average(self.U[:, self.input_index[v.input]], v.dead_time, self.dt)
            if v.tau <= 0:
                return np.concatenate(([ub[0]], ub[:-1]))
            e = math.exp(-self.dt / v.tau)
            a = np.empty(self.n)
            a[0] = ub[0]
            # a[k+1] = e a[k] + (1 - e) ub[k]
            a[1:], _ = lfilter([1 - e], [1, -e], ub[:-1], zi=[e * ub[0]])
            return a
        return self._cached(("v", v.input, round(v.tau, 9), round(v.dead_time, 9)), make)

    def volumes(self, model: PlantModel, smoothed: bool = True):
        """(n, ntanks) volumes from the sensors (inverted through gain/offset) and a censored mask."""
        V, (cens, _, _) = self._volumes(model, smoothed)
        return V, cens

    def _volumes(self, model: PlantModel, smoothed: bool = True):
        """The volumes and the sensors' censorship (`_censorship`)."""
        V = np.empty((self.n, len(model.tanks)))
        sensors = [model.find("sensor", self.sensor_of[tk.name]) for tk in model.tanks]
        for i, (tk, s) in enumerate(zip(model.tanks, sensors)):
            q = s.invert(self._unshifted(s, smoothed))
            V[:, i] = q * tk.area if s.quantity == "level" else q
        key = ("cens",) + tuple((s.name, s.max, s.resolution) for s in sensors)
        return V, self._cached(key, lambda: self._censorship(sensors))

    def _censorship(self, sensors: list):
        """For the tanks' sensors (all read-only): the censored mask (n, ntanks; a reading at its
        clip), the per-tank windows whose balance carries no information (None: none), and the
        windows the inventory cannot use (any sensor censored, or a lost message)."""
        raw = np.zeros((self.n, len(sensors)), bool)
        for i, s in enumerate(sensors):
            if s.max is not None:
                raw[:, i] = self.raw[s.name] >= s.max - max(s.resolution, 1e-9) * 1.5
        raw.flags.writeable = False     # cached: shared by every evaluation of these sensors
        cens = raw if self.gap_rows is None else raw | self.gap_rows[:, None]
        hide = None
        if cens.any():
            # a saturated sensor hides its tank's volume: those windows carry no information
            # about that tank, nor about the flows computed from it (its links' neighbours)
            cw = self.touched(cens)
            if cw.any():
                hide = cw.copy()
                if self.gap_rows is not None:
                    hide |= self.touched(self.gap_rows)[:, None]
                for a, b, both_ways in self.coupled:
                    hide[:, b] |= cw[:, a]
                    if both_ways:
                        hide[:, a] |= cw[:, b]
        blind = self.touched(cens.any(axis=1))
        for a in (hide, blind):         # cached too: shared by every evaluation, never written
            if a is not None:
                a.flags.writeable = False
        return raw, hide, blind

    def _unshifted(self, s, smoothed: bool) -> np.ndarray:
        """The readings of sensor `s` (smoothed or raw) less the step or drift it took from a
        time on (smoothed the same way: the smoothed reading ramps across a step)."""
        y = (self.ys if smoothed else self.raw)[s.name]
        if not s.moves:
            return y
        step = s.offset_at(self.t) - s.offset_at()      # beyond the offset `invert` takes off
        return y - (uniform_filter1d(step, self.smooth, mode="nearest") if smoothed else step)

    def flows(self, model: PlantModel, V: np.ndarray):
        """Per-interval volume changes (n-1, ntanks) and outside accumulation, spill included.

        The flows are the simulator's own right-hand side (`civic.plant.simulate.flows`),
        evaluated at both ends of every sample interval with the command held over it
        (trapezoid rule). A pump whose source is down to its dry-run level passes what flows
        into the source (`_starved`)."""
        VV, AA, CC = self._interval_ends(model, V)
        F, out, pumped = self._interval_flows(model, VV, AA, CC)
        starved = self._starved(model, V, VV, AA, CC)
        at_rim = self._at_rim(model, V)
        if not starved:
            return self._spill(model, V, F, out, at_rim)
        # the pumps' flows and the spill into their sources depend on each other (a tank at its
        # rim spills what the starving pump brings, and part of it may fall back into the
        # source): their fixed point, which the pump's full flow bounds, by secant steps (the
        # map is piecewise linear, its slope the share that falls back; plain iteration took
        # ten passes at a 20 % share)
        tidx = {t.name: i for i, t in enumerate(model.tanks)}
        q = {i: pumped[rows, i] for i, rows, _ in starved}
        prev = None
        for _ in range(STARVED_ITERATIONS):
            Fq = F.copy()
            for i, rows, _ in starved:
                p = model.pumps[i]
                moved = q[i] - pumped[rows, i]
                Fq[rows, tidx[p.from_]] -= moved
                if p.to in tidx:
                    Fq[rows, tidx[p.to]] += moved
            Fs, outs = self._spill(model, V, Fq, out, at_rim)
            g = {i: np.clip(Fs[rows, tidx[model.pumps[i].from_]] + q[i], 0.0, full) for i, rows, full in starved}
            if max(float(np.max(np.abs(g[i] - q[i]))) for i in q) < 1e-12:
                break
            nxt = {}
            for i, _, full in starved:
                step = g[i] - q[i]
                if prev is not None:
                    dq = q[i] - prev[0][i]
                    changed = np.abs(dq) > 1e-15
                    slope = np.where(changed, (g[i] - prev[1][i]) / np.where(changed, dq, 1.0), 0.0)
                    step = step / (1.0 - np.clip(slope, 0.0, 1.0 - 1e-6))
                nxt[i] = np.clip(q[i] + step, 0.0, full)
            prev, q = (q, g), nxt
        return Fs, outs

    def _interval_flows(self, model: PlantModel, VV, AA, CC, rows=None):
        """Per interval (or those in the index array `rows`): the tanks' net volume changes
        (spill aside), what goes outside, and what each pump delivers (litres; the trapezoid over
        the interval's two ends)."""
        n1 = self.n - 1
        at = np.arange(n1) if rows is None else rows
        ends = np.concatenate((at, at + n1))
        if rows is not None:
            VV, AA, CC = VV[ends], AA[ends], CC[ends]
        phases = model.phases()
        if len(phases) == 1:
            fl = plant_flows(model, VV, AA, CC)
            net, outside, pumps = fl.net, fl.outside, fl.pumps
        else:
            # a closure from its onset on: each interval with the model in force at its start
            starts = [int(round(t0 / self.dt)) for t0, _ in phases]
            which = np.tile(np.searchsorted(starts, at, side="right") - 1, 2)
            net, outside = np.zeros((ends.size, len(model.tanks))), np.zeros(ends.size)
            pumps = np.zeros((ends.size, len(model.pumps)))
            for p, (_, m) in enumerate(phases):
                sel = which == p
                if sel.any():
                    fl = plant_flows(m, VV[sel], AA[sel], CC[sel])
                    net[sel], outside[sel], pumps[sel] = fl.net, fl.outside, fl.pumps
        half, k = 0.5 * self.dt, at.size
        return (half * (net[:k] + net[k:]), half * (outside[:k] + outside[k:]),
                half * (pumps[:k] + pumps[k:]))

    def _starved(self, model: PlantModel, V: np.ndarray, VV, AA, CC) -> list:
        """Per pump whose source reads its dry-run level at both ends of some intervals (within
        the reading's noise band): (pump index, those intervals, its full flow over them). There
        it sucks air in bursts and passes, on average, what flows into its source; the measured
        volume cannot say which burst a sample saw (a spill to outside fed by such a pump was
        counted at the pump's full flow: the inventory took the difference for an L4 offset)."""
        out = []
        for i, src, low in self._dry_sources(model, V):
            rows = np.flatnonzero(low[:-1] & low[1:])
            if rows.size:
                lifted = VV.copy()
                lifted[:, src] = np.maximum(lifted[:, src], model.pumps[i].min_source_volume)
                out.append((i, rows, self._interval_flows(model, lifted, AA, CC, rows)[2][:, i]))
        return out

    def _dry_sources(self, model: PlantModel, V: np.ndarray) -> list:
        """Per pump with a dry-run protection whose source tank is measured: (pump index, source
        column, the samples where the source reads its minimum volume within the noise band)."""
        tidx = {t.name: i for i, t in enumerate(model.tanks)}
        return [(i, tidx[p.from_], V[:, tidx[p.from_]] <= p.min_source_volume + self.rim_tol[p.from_])
                for i, p in enumerate(model.pumps) if p.from_ in tidx and p.min_source_volume > 0]

    def _at_rim(self, model: PlantModel, V: np.ndarray) -> dict:
        """Per overflowing tank: the intervals that end with it at its rim."""
        return {i: self.reaching(model, V[1:], i, model.tanks[i].rim_volume()) for i in model._overflow_order()}

    def reaching(self, model: PlantModel, V: np.ndarray, i: int, volume: float) -> np.ndarray:
        """Per row of the volumes `V`: whether tank `i` is at or above `volume` (a rim, a crest),
        within its reading's noise band, short dips below closed."""
        return closed_gaps(V[:, i] >= volume - self.rim_tol[model.tanks[i].name], RIM_GAP)

    def _spill(self, model: PlantModel, V: np.ndarray, F: np.ndarray, out: np.ndarray, at_rim: dict):
        """The interval volume changes `F` and outside accumulation `out` with every overflow's
        instantaneous spill (keeping its tank at the rim, `_at_rim`) moved to where it goes."""
        tidx = {t.name: i for i, t in enumerate(model.tanks)}
        F = F.copy()

        def move(src, dst, q):
            nonlocal out
            F[:, tidx[src]] -= q
            if dst == OUTSIDE:
                out = out + q
            else:
                F[:, tidx[dst]] += q

        for i in model._overflow_order():
            tk = model.tanks[i]
            rim = tk.rim_volume()
            pre = V[:-1, i] + F[:, i]
            # at the rim every net inflow spills (measured noise is not rectified into spill), and
            # so does what a reading beyond the noise band above the rim loses on its way down to it
            # (a record that starts with the tank above its rim: the datasheet spills it at once)
            above = np.maximum(V[:, i] - rim - self.rim_tol[tk.name], 0.0)
            s = np.where(at_rim[i], np.maximum(F[:, i], 0.0) + np.maximum(above[:-1] - above[1:], 0.0),
                         np.maximum(pre - rim, 0.0))
            for dest, share in tk.overflow.targets():
                move(tk.name, dest, share * s)
        return F, out

    def _interval_ends(self, model: PlantModel, V: np.ndarray):
        """Volumes, openings and held pump commands at both ends of every sample interval
        (start rows, then end rows)."""
        def make():
            A = [self._opening(v) for v in model.valves]
            C = [self._pump_avg(p.input, p.dead_time)[:-1] for p in model.pumps]
            return _ends([a[:-1] for a in A], [a[1:] for a in A], self.n - 1), _ends(C, C, self.n - 1)
        key = ("ends",) + tuple((v.input, round(v.tau, 9), round(v.dead_time, 9)) for v in model.valves) \
            + tuple((p.input, round(p.dead_time, 9)) for p in model.pumps)
        AA, CC = self._cached(key, make)
        cols = range(V.shape[1])
        return _ends([V[:-1, i] for i in cols], [V[1:, i] for i in cols], self.n - 1), AA, CC

    def through(self, model: PlantModel, V: np.ndarray) -> dict:
        """Litres through each pump and link per window, from its first end to its second, on
        the measured volumes `V` (`volumes`; spill aside)."""
        fl = plant_flows(model, *self._interval_ends(model, V))
        n1 = self.n - 1
        out = {}
        for names, q in (([p.name for p in model.pumps], fl.pumps), ([lk.name for lk in model.links], fl.links)):
            out.update({name: self.window_sum(0.5 * (q[:n1, i] + q[n1:, i]) * self.dt) for i, name in enumerate(names)})
        return out

    def window_sum(self, x: np.ndarray) -> np.ndarray:
        """Per window, the sum of a per-interval series (n - 1 values)."""
        c = np.concatenate(([0.0], np.cumsum(x)))
        return c[self.k1] - c[self.k0]

    def touched(self, mask: np.ndarray) -> np.ndarray:
        """Per window, whether any of its samples (both ends) is set in the per-sample `mask`
        (n values, or n rows of columns)."""
        c = np.concatenate((np.zeros((1,) + mask.shape[1:], int), np.cumsum(mask, axis=0)))
        return (c[self.k1 + 1] - c[self.k0]) > 0

    def residuals(self, model: PlantModel) -> np.ndarray:
        V, (_, hide, blind) = self._volumes(model)
        F, out = self.flows(model, V)
        cF = np.concatenate((np.zeros((1, F.shape[1])), np.cumsum(F, axis=0)))
        R = (V[self.k1] - V[self.k0]) - (cF[self.k1] - cF[self.k0])
        if INVENTORY in self.columns:
            R = np.concatenate((R, self._inventory(model, V, out, blind)[:, None]), axis=1)
        if hide is not None:
            R[:, :len(model.tanks)] = np.where(hide, 0.0, R[:, :len(model.tanks)])
        self._hide_starved(model, V, R)
        return R

    def _hide_starved(self, model: PlantModel, V: np.ndarray, R: np.ndarray) -> None:
        """A pump whose source tank is down to its minimum volume (within the reading's noise
        band) sucks air in bursts: it passes what flows into the source, not its command's flow,
        and the measured volume says only roughly when. Those windows carry no information about
        the pump's two tanks (a large leak out of the circuit drained T4 to it in 8 min, and the
        starving pump was named a closure)."""
        tidx = {t.name: i for i, t in enumerate(model.tanks)}
        for i, src, low in self._dry_sources(model, V):
            if low.any():
                to = model.pumps[i].to
                R[np.ix_(self.touched(low), [src] + ([tidx[to]] if to in tidx else []))] = 0.0

    def level_error_spread(self, model: PlantModel, shift_sigmas: float = 1.0) -> np.ndarray:
        """(windows, columns): how far each window's balance moves when each tank's reading is
        shifted by `shift_sigmas` of its noise (in quadrature over the sensors; the inventory's
        own spread is how well the fill is known, so 0 there). A window where a link's head is
        near zero moves far (Torricelli's flow has an infinite slope there), one where the
        levels stand apart hardly at all."""
        R0 = self.residuals(model)
        spread = np.zeros_like(R0)
        for s in self.sensor_of.values():
            kept = self.ys[s]
            try:
                self.ys[s] = kept + shift_sigmas * noise_sigma(self.raw[s])
                spread += (self.residuals(model) - R0) ** 2
            finally:
                self.ys[s] = kept
        if INVENTORY in self.columns:
            spread[:, self.columns.index(INVENTORY)] = 0.0
        return np.sqrt(spread)

    def _inventory(self, model: PlantModel, V: np.ndarray, out: np.ndarray, blind: np.ndarray) -> np.ndarray:
        """Per window: mean measured total volume minus (stated total - water the model let out).
        The `blind` windows (a censored sensor or a lost message) carry no information (0)."""
        if model.total_volume is None:
            return np.zeros(self.nwin)
        left = np.concatenate(([0.0], np.cumsum(out)))          # water gone outside by each sample
        c = np.concatenate(([0.0], np.cumsum(V.sum(axis=1) - (model.total_volume - left))))
        inv = (c[self.k1] - c[self.k0]) / self.W
        return np.where(blind, 0.0, inv)


class SimulationError:
    """Open-loop simulation driven by the recorded inputs: sensor residuals per sample.

    horizon_s=None: one free run from the initial state (unmeasured tanks are
    nuisance parameters, see `x0`; measured ones from the mean of the first
    `average` samples). horizon_s=h: restart from the measured state every h
    seconds (multiple shooting; needs every tank measured).
    """

    kind = "simulation"

    def __init__(self, model: PlantModel, rec: Recording, horizon_s: float | None = None,
                 n_init: int = 1, skip: int = 0, average: int = 1):
        self.rec = rec
        self.n = len(rec.t)
        self.dt = float(model.dt)
        self.t = np.arange(self.n) * self.dt
        self.inputs = {k: np.asarray(rec.signals[k], float) for k in model.input_names}
        self.columns = [s for s in model.signal_names if s in rec.signals]
        self.Y = np.stack([np.asarray(rec.signals[s], float) for s in self.columns], axis=1)
        self.n_init = n_init
        self.average = average
        self.skip = skip
        self.horizon = None if horizon_s is None else max(2, int(round(horizon_s / self.dt)))
        rows = np.arange(skip, self.n)
        self.row_times = np.stack([self.t[rows], self.t[rows] + self.dt], axis=1)
        self.train = np.zeros(len(rows), bool)
        self.train[: int(0.65 * len(rows))] = True
        self.x0_extra: dict = {}

    def unmeasured(self, model: PlantModel) -> list[str]:
        sensed = {model.find("sensor", s).tank for s in self.columns}
        return [t for t in model.tank_names if t not in sensed]

    def x0(self, model: PlantModel, k: int = 0) -> dict:
        sig = {k2: v[k:] for k2, v in self.rec.signals.items()}
        if k == 0 and self.x0_extra:
            # measured tanks from the data, unmeasured ones as given (fitted nuisance values)
            part = {key: val for key, val in self.x0_extra.items()}
            sensed_only = measured_state(model, sig, self.average)
            sensed_only.update(part)
            return sensed_only
        return initial_state(model, sig, self.n_init if k == 0 else 1, average=self.average if k == 0 else 1)

    def simulate(self, model: PlantModel) -> dict:
        if self.horizon is None:
            # compile_model is cached on the structure: fitting changes numbers, never recompiles
            return simulate(model, self.t, self.inputs, self.x0(model))
        out = {s: np.empty(self.n) for s in self.columns}
        for k in range(0, self.n, self.horizon):
            e = min(self.n, k + self.horizon + 1)
            # restarted from the readings through the sensors as they stand then (a step or drift)
            mk = model.from_time(self.t[k])
            seg = simulate(mk, self.t[k:e] - self.t[k], {n: v[k:e] for n, v in self.inputs.items()},
                           measured_state(mk, {n: v[k:] for n, v in self.rec.signals.items()}, 1))
            for s in self.columns:
                out[s][k:e] = seg[s]
        return out

    def residuals(self, model: PlantModel) -> np.ndarray:
        sim = self.simulate(model)
        P = np.stack([sim[s] for s in self.columns], axis=1)
        R = P - self.Y
        gaps = getattr(self.rec, "gaps", None)
        if gaps is not None and gaps.any():
            R[gaps] = 0.0          # lost samples: nothing to compare
        return R[self.skip:]

    def rmse(self, model: PlantModel, rows=None) -> dict:
        R = self.residuals(model)
        if rows is not None:
            R = R[rows]
        return {s: float(np.sqrt(np.mean(R[:, j] ** 2))) for j, s in enumerate(self.columns)}


def fully_measured(model: PlantModel, rec: Recording) -> bool:
    sensed = {s.tank for s in model.sensors if s.name in rec.signals}
    return all(t in sensed for t in model.tank_names)
