"""Continuous validation: the balance monitors' tables, learned from simulated closed-loop operation.

A balance monitor (docs/pipeline.md 3b) needs two kinds of table:

* **flow terms** from the calibrated plant model: for each model component the monitor
  names (a link or a pump), the expected flow into the monitored tank per sample, as a
  piecewise constant range table on what sets it (a head and a command), fine enough that
  a cell's flow stays within a few percent (`tabulate_term`);
* **classes** on (residual, band), band = the expected flow a fault scales. A clogged
  drain passes a fraction of V2's expected flow and a failing pump delivers a fraction of
  its expected flow, so the classes differ by the residual *relative* to the band:
  `BalanceClassifier` learns two cuts on that ratio, the smallest band at which sensor
  noise still keeps them apart (below it: no verdict) and the hold that keeps fault-free
  operation silent, from closed-loop runs of the plant simulator (PI control with
  setpoint changes and the embedded tests, units spread over ±3 %, every fault class
  switched on mid-run: `closed_loop_runs`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from civic.config import Monitor
from civic.envelope import FAULT_VALVE
from civic.entries import BALANCE_SHIFT, BAND_SUM_SHIFT, SLOPE_MAX, SLOPE_MIN, FlowTerm, MonitorEntries
from civic.errors import CivicError
from civic.plant.model import PlantModel
from civic.plant.noise import robust_sigma
from civic.plant.procedures import FAULT_CLASSES, class_of
from civic.wire import CLASS_CODES, ip_to_int

SAMPLE_RATE = 10.0                      # messages per second
FLOW_UNIT = 1000.0 / SAMPLE_RATE * (1 << BALANCE_SHIFT)   # L/s -> 1/64 mL per sample
BAND_UNIT = 10.0                        # a flow term's band: expected flow in 0.1 mL/s
TERM_REL_TOL = 0.02                     # a 1-D flow-table cell's flow stays within ±2 %
TERM_REL_TOL_2D = 0.03                  # ... a 2-D cell's within ±3 % along each key
TERM_ABS_TOL = 1.0                      # ... or ±1 mL/s where the flow is small
BAND_ERROR = 0.05                       # no verdict in bands where the cuts misclassify more
BAND_RATIO = 1.1                        # class bands: geometric, 10 % wide
BAND_TOP = 5000                         # 500 mL/s: the last band covers everything above
NOISE_MARGIN = 4.0                      # faulty windows with a band this many residual sigmas up place the cuts
HOLDS = (5, 10, 15, 20, 30, 40, 50, 60, 80, 100)   # candidate holds, messages
HOLD_MARGIN = 1.5
CLOSED_LOOP_UNITS = 4                   # simulated units per fault case in training
CLOSED_LOOP_SEED = 2026
UNIT_SPREAD = 0.03
PI_GAINS = ((0.2, 0.25, 0.25), (5.0, 5.0, 5.0))   # like the recorded loops: command noise ~0.6 % a message, settled within ~20 s
# the fault each balance monitor sees is the one its tank's test procedure is for (docs/plant.md)
SCENARIO = {"balance_t3": "drain", "balance_t1": "fill"}
FAULTS = {m: (FAULT_VALVE[s], {c: v for c, v in FAULT_CLASSES[s].items() if v}) for m, s in SCENARIO.items()}


# ------------------------------------------------------------------ flow terms
def _sensor_wire(model: PlantModel, tank: str) -> str:
    s = next((s for s in model.sensors if s.tank == tank and s.wire), None)
    if s is None:
        raise CivicError(f"plant model {model.name}: tank {tank} has no sensor on the wire")
    if s.quantity != "volume" or s.gain != 1.0 or s.offset != 0.0 or s.exponent != 1.0 or s.curvature \
            or s.wire_scale != 1000.0:
        raise CivicError(f"plant model {model.name}: sensor {s.name} is not a plain volume sensor in mL "
                         f"(a balance monitor keys its flow tables on wire values)")
    return s.wire


def _input_wire(model: PlantModel, name: str) -> str:
    inp = next((i for i in model.inputs if i.name == name), None)
    wire = getattr(inp, "wire", None) if inp is not None else None
    if not wire:
        raise CivicError(f"plant model {model.name}: input {name} is not a wire field")
    return wire


def _segments(q: np.ndarray, rel: float, absolute: float) -> list[tuple[int, int]]:
    """Greedy [lo, hi] index stretches of a fine grid whose flows stay within the tolerance."""
    out, lo, n = [], 0, len(q)
    while lo < n:
        hi = lo
        qmin = qmax = q[lo]
        while hi + 1 < n:
            a, b = min(qmin, q[hi + 1]), max(qmax, q[hi + 1])
            if b - a > 2 * max(rel * max(abs(a), abs(b)), absolute):
                break
            qmin, qmax, hi = a, b, hi + 1
        out.append((lo, hi))
        lo = hi + 1
    return out


@dataclass
class TermSpec:
    """How one model component's flow into the monitored tank is keyed."""

    component: str
    head: tuple[str, str]
    command: str
    flow: object              # f(head_mL (array), command_0.1% (array)) -> L/s into the tank
    head_signed: bool         # heads of both signs (a two-way link)
    head_max: int             # mL: the largest head tabulated finely


def term_spec(model: PlantModel, tank: str, component: str) -> TermSpec:
    """The flow of a link or pump of the model into `tank`, as a function of wire values."""
    from civic.plant.simulate import flows

    names = [t.name for t in model.tanks]
    pump = next((p for p in model.pumps if p.name == component), None)
    link = next((lk for lk in model.links if lk.name == component), None)
    if pump is None and link is None:
        raise CivicError(f"balance flow {component!r}: no link or pump of that name in plant model {model.name}")
    ends = (pump.from_, pump.to) if pump else (link.from_, link.to)
    if tank not in ends:
        raise CivicError(f"balance flow {component!r} does not touch tank {tank}")
    sign = 1.0 if ends[1] == tank else -1.0
    rest = {t.name: min(t.capacity if np.isfinite(t.capacity) else 30.0, 30.0) * 0.6 for t in model.tanks}
    nv = len(model.valves)

    def run(vols: dict, openings: np.ndarray, commands: np.ndarray) -> np.ndarray:
        n = len(openings)
        V = np.array([np.full(n, vols.get(t, rest[t])) if np.isscalar(vols.get(t, rest[t])) else vols[t]
                      for t in names]).T
        f = flows(model, V, openings, commands)
        return f.pumps[:, model.pumps.index(pump)] if pump else f.links[:, model.links.index(link)]

    if pump is not None:
        cmd = _input_wire(model, pump.input)

        def flow(head, c):
            c = np.asarray(c, float)
            commands = np.zeros((len(c), len(model.pumps)))
            commands[:, model.pumps.index(pump)] = c / 1000.0
            return sign * run({}, np.zeros((len(c), nv)), commands)
        return TermSpec(component, ("zero", "zero"), cmd, flow, False, 0)
    area_a, area_b = model.tank(link.from_).area, model.tank(link.to).area
    plus = _sensor_wire(model, link.from_)
    valve = next((v for v in model.valves if v.name == link.valve), None)
    cmd = _input_wire(model, valve.input) if valve else "zero"
    two_way = link.law == "bidirectional"
    if two_way and abs(area_a - area_b) > 1e-9:
        raise CivicError(f"balance flow {component!r}: tanks {link.from_} and {link.to} differ in area")
    minus = _sensor_wire(model, link.to) if two_way else "zero"
    top = model.tank(link.from_).rim_volume()
    head_max = int(min(top if np.isfinite(top) else 20.0, 20.0) * 1000)

    def flow(head, c):
        head = np.asarray(head, float) / 1000.0
        c = np.asarray(c, float)
        openings = np.zeros((len(head), nv))
        if valve is not None:
            openings[:, model.valves.index(valve)] = c / 1000.0
        base = rest[link.to]
        vols = {link.from_: base + head / 2, link.to: base - head / 2} if two_way else {link.from_: head}
        return sign * run(vols, openings, np.zeros((len(head), len(model.pumps))))
    return TermSpec(component, (plus, minus), cmd, flow, two_way, head_max)


def tabulate_term(spec: TermSpec, band: bool) -> FlowTerm:
    """A flow term's range table: cells within ±TERM_REL_TOL (or TERM_ABS_TOL), flow at the cell's
    centre in 1/64 mL per sample, band = |flow| in 0.1 mL/s where `band`."""
    tol_rel = TERM_REL_TOL if spec.command == "zero" or spec.head == ("zero", "zero") else TERM_REL_TOL_2D
    if spec.head == ("zero", "zero"):
        head_bins = [(0, 0xFFFF, 0.0)]
    else:
        h = np.arange(spec.head_max + 1, dtype=float)
        q = spec.flow(h, np.full(len(h), 1000.0)) * 1000.0
        head_bins = []
        for lo, hi in _segments(q, tol_rel, TERM_ABS_TOL):
            mid, last = (lo + hi) / 2.0, hi == spec.head_max
            head_bins.append((lo, 0x7FFF if last else hi, mid))
            if spec.head_signed:          # heads -hi..-lo wrap to 65536 - hi .. 65536 - lo (0 stays above)
                head_bins.append((0x8000 if last else 0x10000 - hi, 0xFFFF if lo == 0 else 0x10000 - lo, -mid))
        head_bins = [b for b in head_bins if b[0] <= b[1]]
    if spec.command == "zero":
        cmd_bins = [(0, 0xFFFF, 0.0)]
    else:
        c = np.arange(1001, dtype=float)
        ref = float(spec.head_max) if spec.head != ("zero", "zero") else 0.0     # the largest flows: the finest cells
        q = spec.flow(np.full(len(c), ref), c) * 1000.0
        cmd_bins = [(lo, 0xFFFF if hi == 1000 else hi, (lo + hi) / 2.0) for lo, hi in _segments(q, tol_rel, TERM_ABS_TOL)]
    hh = np.array([b[2] for b in head_bins])
    rows = []
    for clo, chi, cmid in cmd_bins:
        q = spec.flow(hh, np.full(len(hh), cmid))          # L/s into the tank
        for (hlo, hhi, _), qi in zip(head_bins, q):
            rows.append([hlo, hhi, clo, chi, int(round(qi * FLOW_UNIT)),
                         min(int(round(abs(qi) * 1000.0 * BAND_UNIT)), 0xFFFF) if band else 0])
    return FlowTerm(spec.head, spec.command, np.array(rows, dtype=np.int64))


def flow_terms(mon: Monitor, model: PlantModel) -> list[FlowTerm]:
    """The monitor's flow terms from the (calibrated) plant model, in the order of `flows`."""
    tank = next((s.tank for s in model.sensors if s.wire == mon.signal), None)
    if tank is None:
        raise CivicError(f"monitor {mon.name}: no tank of plant model {model.name} is measured by {mon.signal}")
    return [tabulate_term(term_spec(model, tank, c), band=(c == mon.band)) for c in mon.flows]


# ------------------------------------------------------------------ simulated operation
@dataclass
class ClosedLoopRun:
    """One simulated closed-loop run: plant messages and the true class per monitor over time."""

    msgs: np.ndarray
    onset_s: float | None     # None: fault-free
    fault: str                # "none", "vm1", "vm2"
    closure: float
    unit_seed: int

    def truth(self, monitor: str) -> np.ndarray:
        """Expected class per message: normal before the onset, the fault's class from onset + 60 s
        on for the monitor it touches (normal for the others), 0 (not scored) in between."""
        from civic.evaluate import expected_classes

        cls = "normal"
        if monitor in FAULTS and FAULTS[monitor][0] == self.fault:
            cls = class_of(SCENARIO[monitor], self.closure)
        return expected_classes(self.msgs["t"] - self.msgs["t"][0], CLASS_CODES[cls], self.onset_s)


def closed_loop_runs(model: PlantModel, units: int, spread: float, seed: int, duration: float = 900.0,
                     onsets=(200.0, 500.0), progress=None) -> list[ClosedLoopRun]:
    """Every fault (none; VM1 warning/error; VM2 warning/error) on `units` units spread ±`spread`,
    PI control through random setpoints and the embedded tests, onsets drawn in `onsets`."""
    from civic.envelope import messages
    from civic.evalsets import spread_unit
    from civic.plant.control import operation_schedule, run_closed_loop
    from civic.plant.procedures import apply_faults

    cases = [("none", 0.0)] + [(v, c) for v, cl in FAULTS.values() for c in cl.values()]
    rng = np.random.default_rng(seed)
    out = []
    for u in range(units):
        for fault, closure in cases:
            unit_seed = int(rng.integers(2**31))
            unit = spread_unit(model, np.random.default_rng(unit_seed), spread)
            onset = None if fault == "none" else float(rng.uniform(*onsets))
            faulted = (onset, apply_faults(unit, {fault: closure})) if onset is not None else None
            run_rng = np.random.default_rng(int(rng.integers(2**31)))
            res = run_closed_loop(unit, duration, controller="pi", seed=int(run_rng.integers(2**31)),
                                  schedule=operation_schedule(duration, run_rng), controller_model=model,
                                  onset=faulted, pi_gains=PI_GAINS)
            msgs = messages(res.fields, seq0=int(rng.integers(2**32)), src=ip_to_int("10.0.0.1"))
            out.append(ClosedLoopRun(msgs, onset, fault, closure, unit_seed))
            if progress is not None:
                progress()
    return out


# ------------------------------------------------------------------ classes
def _cut(x: np.ndarray, lower: np.ndarray, upper: np.ndarray, miss_cost: float = 2.0) -> float:
    """The threshold between two classes on x (lower class below): midway between the lower class's
    99th and the upper class's 1st percentile where they are apart (the widest margin), otherwise of
    least cost (a missed severity costs `miss_cost`, a false alarm 1) in the widest least-cost gap."""
    a, b = np.quantile(x[lower], 0.99), np.quantile(x[upper], 0.01)
    if a < b:
        return float((a + b) / 2)
    xs = np.sort(np.unique(np.concatenate((x[lower], x[upper]))))
    if len(xs) < 2:
        raise CivicError("too few simulated windows to place a class boundary")
    cands = (xs[:-1] + xs[1:]) / 2
    lo_sorted, up_sorted = np.sort(x[lower]), np.sort(x[upper])
    false_alarm = len(lo_sorted) - np.searchsorted(lo_sorted, cands, side="right")
    missed = np.searchsorted(up_sorted, cands, side="left")
    cost = false_alarm + miss_cost * missed
    best = np.flatnonzero(cost == cost.min())
    gaps = xs[best + 1] - xs[best]
    return float(cands[best[np.argmax(gaps)]])


class BalanceClassifier:
    """Classes of a balance monitor from (residual, band) windows: two cuts on the residual relative
    to the band's flow, in the direction faults push it; no verdict below `q_min_`.

    fit(resid, band, y): resid and band in mL/s, y the true class (0: not scored).
    """

    def __init__(self, noise_margin: float = NOISE_MARGIN):
        self.noise_margin = noise_margin

    def fit(self, resid, band, y) -> "BalanceClassifier":
        resid, band, y = (np.asarray(a, float) for a in (resid, band, y))
        scored = (y > 0) & (band > 0)
        faulty = scored & (y > 1)
        if not faulty.any():
            raise CivicError("no faulty windows in the simulated operation")
        ratio = resid / np.maximum(band, 1e-9)
        self.direction_ = 1.0 if np.median(ratio[faulty]) >= 0 else -1.0
        r = self.direction_ * ratio
        normal = scored & (y == 1)
        self.sigma_ = robust_sigma(resid[normal])
        warn, err = scored & (y == 2), scored & (y == 3)
        # fit the cuts where the classes are meant to be told apart: enough flow for the noise
        visible = faulty & (band > self.noise_margin * self.sigma_)
        if not visible.any():
            raise CivicError("no faulty windows with flow enough to see the fault in the simulated operation")
        strong = band >= np.quantile(band[visible], 0.5)
        self.t1_ = _cut(r, normal & strong, (warn | err) & strong)
        self.t2_ = _cut(r, warn & strong, err & strong) if warn.any() and err.any() else np.inf
        self.q_min_ = self._min_band(resid, band, y)
        return self

    def _min_band(self, resid, band, y) -> float:
        """The upper edge of the highest 10 %-band, below the scored windows' median band, in which
        the cuts misclassify more than BAND_ERROR (sensor noise outweighs the fault there)."""
        scored = (y > 0) & (band > 0)
        wrong = self._by_cuts(resid, band) != y
        median = np.median(band[scored])
        edges = np.geomspace(max(band[scored].min(), 1.0), median, 40)
        q_min = edges[0]
        for lo, hi in zip(edges[:-1], edges[1:]):
            sel = scored & (band >= lo) & (band < hi)
            if sel.sum() >= 20 and wrong[sel].mean() > BAND_ERROR:
                q_min = hi
        return float(q_min)

    def _by_cuts(self, resid, band) -> np.ndarray:
        """The class the two cuts give, whatever the band."""
        r = self.direction_ * np.asarray(resid, float) / np.maximum(np.asarray(band, float), 1e-9)
        return np.where(r >= self.t2_, 3, np.where(r >= self.t1_, 2, 1))

    def predict(self, resid, band) -> np.ndarray:
        return np.where(np.asarray(band, float) < self.q_min_, 0, self._by_cuts(resid, band))

    def score(self, resid, band, y) -> float:
        y = np.asarray(y)
        p = self.predict(resid, band)
        keep = (y > 0) & (p > 0)
        return float(np.mean(p[keep] == y[keep])) if keep.any() else 0.0

    def rows(self, slope_scale: float, band_scale: float) -> np.ndarray:
        """Class table rows (slope_lo, slope_hi, band_lo, band_hi, cls) in raw units; band_scale: mL/s
        per band key unit."""
        q_min = max(int(np.ceil(self.q_min_ / band_scale)), 1)
        top = int(BAND_TOP / BAND_UNIT / band_scale)
        edges = [q_min]
        while edges[-1] < top:
            edges.append(max(int(np.ceil(edges[-1] * BAND_RATIO)), edges[-1] + 1))
        rows = [[SLOPE_MIN, SLOPE_MAX, 0, q_min - 1, 0]]
        for lo, nxt in zip(edges[:-1] + [edges[-1]], edges[1:] + [0x10000]):
            hi = nxt - 1
            q = np.sqrt(lo * min(hi, top)) * band_scale          # mL/s at the band's geometric centre
            t1 = int(np.ceil(self.t1_ * q / slope_scale))
            t2 = int(np.ceil(self.t2_ * q / slope_scale)) if np.isfinite(self.t2_) else SLOPE_MAX
            t1, t2 = min(max(t1, 1), SLOPE_MAX - 1), min(max(t2, t1 + 1), SLOPE_MAX)
            if self.direction_ > 0:
                rows += [[SLOPE_MIN, t1 - 1, lo, hi, 1], [t1, t2 - 1, lo, hi, 2]]
                if t2 < SLOPE_MAX:
                    rows.append([t2, SLOPE_MAX, lo, hi, 3])
            else:
                rows += [[-t1 + 1, SLOPE_MAX, lo, hi, 1], [-t2 + 1, -t1, lo, hi, 2]]
                if t2 < SLOPE_MAX:
                    rows.append([SLOPE_MIN, -t2, lo, hi, 3])
        return np.array(rows, dtype=np.int64)


def band_key_scale(mon: MonitorEntries) -> float:
    """mL/s of average expected flow per unit of the class table's band key (band_w)."""
    return (1 << BAND_SUM_SHIFT) / (mon.ring_len * BAND_UNIT)


def balance_entries(mon: Monitor, terms: list[FlowTerm], rows=None, hold: int | None = None) -> MonitorEntries:
    table = np.zeros((0, 5), np.int64) if rows is None else np.asarray(rows, np.int64)
    return MonitorEntries(name=mon.name, signal=mon.signal, window=mon.window, precondition=mon.precondition,
                          kind="balance", hold=hold or mon.hold, flows=mon.flows, band=mon.band,
                          estimator="lsq", default_class=CLASS_CODES["normal"], classes=table, terms=terms)


def monitor_windows(entries: MonitorEntries, runs: list[ClosedLoopRun]):
    """(resid mL/s, band mL/s, truth, run index) of every evaluated message of every run."""
    from civic.entries import Entries
    from civic.pipeline import SwitchModel

    probe = SwitchModel(Entries([entries]))
    out = []
    for i, run in enumerate(runs):
        probe.reset()
        _, (tr,) = probe.traces(run.msgs)
        ev = tr.evaluated
        out.append((tr.resid[ev] * entries.slope_scale, tr.band[ev] * band_key_scale(entries),
                    run.truth(entries.name)[ev],
                    np.full(int(ev.sum()), i)))
    return tuple(np.concatenate(a) for a in zip(*out))


def choose_hold(entries: MonitorEntries, runs: list[ClosedLoopRun]) -> int:
    """The smallest hold under which the simulated runs raise no warning or error where normal is
    expected and every scored error message that gets a verdict gets error, times HOLD_MARGIN (at most
    255); the longest candidate if none is clean."""
    from civic.entries import Entries
    from civic.pipeline import SwitchModel

    for h in HOLDS:
        entries.hold = h
        model = SwitchModel(Entries([entries]))
        clean = True
        for run in runs:
            model.reset()
            _, (tr,) = model.traces(run.msgs)
            truth = run.truth(entries.name)
            err = truth == CLASS_CODES["error"]
            if np.any((tr.code > 1) & (truth == 1)) or np.any(err & (tr.code > 0) & (tr.code != truth)):
                clean = False
                break
        if clean:
            return min(int(round(HOLD_MARGIN * h)), 255)
    return HOLDS[-1]


def train_balance(mon: Monitor, model: PlantModel, runs: list[ClosedLoopRun]) -> tuple[MonitorEntries, dict]:
    """Flow terms from the model, classes and hold from the simulated runs."""
    terms = flow_terms(mon, model)
    probe = balance_entries(mon, terms, hold=1)
    resid, band, y, _ = monitor_windows(probe, runs)
    clf = BalanceClassifier().fit(resid, band, y)
    entries = balance_entries(mon, terms, clf.rows(probe.slope_scale, band_key_scale(probe)), hold=1)
    entries.hold = choose_hold(entries, runs)
    info = {"ratio_cuts": [round(clf.t1_, 4), round(float(clf.t2_), 4)], "direction": int(clf.direction_),
            "residual_sigma_ml_per_s": round(clf.sigma_, 3), "min_band_ml_per_s": round(clf.q_min_, 2),
            "hold": entries.hold, "flow_entries": [len(t.rows) for t in terms]}
    return entries, info
