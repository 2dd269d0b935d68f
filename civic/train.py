"""Learn class boundaries from labelled recordings and emit switch table entries.

`BandClassifier` is a small estimator (fit/predict/score on numpy arrays):
it maps each evaluated window to z = log|slope| - beta*log(level), a feature
in which the classes of a fault differ by a constant (Torricelli: flow scales
with a power of the level, a closure scales it by a factor), picks thresholds
on z for the best cost-weighted training accuracy with the widest margin, and
writes them back as integer range entries on (slope, level) per level band.
With `banded=False` (beta = 0, one band) it is the paper's 1-D slope table.

With an `Envelope` (civic/envelope.py, the default of `civic train`), a monitor
configured with `compensate` gets a compensate table from the calibrated plant
model and its classes are learned on the compensated slope (slope - expected
inflow, docs/pipeline.md 3a), from the recordings and the model's tests over the
whole operating envelope.
"""
from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from civic.config import Monitor, MonitorConfig
from civic.entries import SLOPE_MAX, SLOPE_MIN, Entries, MonitorEntries, monitor_entries, probe_entries
from civic.errors import CivicError
from civic.pipeline import SwitchModel
from civic.pipeline.classification import compensate
from civic.pipeline.slope import to_int32
from civic.wire import CLASS_CODES, ip_to_int, read_pcap

LEVEL_TOP = 10_000          # mL: an upper tank's rim; bands above it repeat the last one
ABOVE_NORMAL = CLASS_CODES["error"]  # faster than any normal run: the model does not explain it


@dataclass
class Run:
    """The evaluated windows of one labelled recording (one plant, one monitor)."""

    file: str
    src: str
    monitor: str
    cls: int
    slope: np.ndarray
    level: np.ndarray
    t: np.ndarray
    aux: np.ndarray

    def resid(self, offsets: np.ndarray) -> np.ndarray:
        """The slope the class table sees once the compensate table's offsets are subtracted."""
        return to_int32(self.slope - compensate(self.aux, offsets))


def read_labels(path: str | Path) -> list[dict]:
    """labels.csv rows; needs columns file, monitor, class (src_ip optional)."""
    try:
        with open(path, newline="") as fh:
            rows = list(csv.DictReader(fh))
    except OSError as exc:
        raise CivicError(f"cannot read labels {path}: {exc.strerror}") from exc
    except (UnicodeDecodeError, csv.Error) as exc:
        raise CivicError(f"{path}: not a labels CSV ({exc})") from exc
    if not rows:
        raise CivicError(f"{path}: no label rows")
    for col in ("file", "monitor", "class"):
        if col not in rows[0]:
            raise CivicError(f"{path}: missing column '{col}'")
    for i, r in enumerate(rows):
        if r["class"] not in CLASS_CODES:
            raise CivicError(f"{path}: row {i + 2}: class {r['class']!r} is not normal/warning/error")
    return rows


def collect_runs(folder: str | Path, labels: list[dict], config: MonitorConfig, estimator: str) -> list[Run]:
    """Run the switch model over every labelled recording and keep the evaluated windows."""
    folder = Path(folder)
    names = [m.name for m in config.monitors]
    entries = probe_entries(config, estimator)
    runs, cache = [], {}
    for row in labels:
        if row["monitor"] not in names:
            raise CivicError(f"labels: monitor {row['monitor']!r} is not configured ({', '.join(names)})")
        path = folder / row["file"]
        if path not in cache:
            cap = read_pcap(path, config.udp_port, config.plant_prefix)
            cache[path] = (cap.messages, *SwitchModel(entries).traces(cap.messages))
        msgs, idx, traces = cache[path]
        tr = traces[names.index(row["monitor"])]
        keep = tr.evaluated.copy()
        if row.get("src_ip"):
            keep &= msgs["src"][idx] == ip_to_int(row["src_ip"])
        runs.append(Run(file=row["file"], src=row.get("src_ip", ""), monitor=row["monitor"],
                        cls=CLASS_CODES[row["class"]], slope=tr.slope[keep], level=tr.level[keep],
                        t=msgs["t"][idx][keep], aux=tr.aux[keep]))
    return runs


def envelope_runs(envelope, config: MonitorConfig, estimator: str) -> list[Run]:
    """The evaluated windows of every test the envelope simulates, per configured monitor."""
    out = []
    for m, mon in enumerate(config.monitors):
        single = MonitorConfig([Monitor(mon.name, mon.signal, mon.window, mon.precondition, mon.compensate)],
                               config.udp_port, config.plant_prefix)
        probe = SwitchModel(probe_entries(single, estimator))
        for i, (cls, msgs) in enumerate(envelope.runs(mon.name)):
            probe.reset()
            _, (tr,) = probe.traces(msgs)
            keep = tr.evaluated
            out.append(Run(file=f"model:{mon.name}:{i}", src="", monitor=mon.name, cls=cls, slope=tr.slope[keep],
                           level=tr.level[keep], t=msgs["t"][keep], aux=tr.aux[keep]))
    return out


def _cost(true: np.ndarray, pred: np.ndarray) -> np.ndarray:
    """Missing severity costs twice a false alarm: an undetected error is the worst mistake."""
    return np.where(pred < true, 2.0, np.where(pred > true, 1.0, 0.0))


class BandClassifier:
    """Slope classes per level band, learned in the level-normalized feature z."""

    def __init__(self, banded: bool = True, band_ml: int = 200):
        self.banded = banded
        self.band_ml = band_ml

    # -- features
    def _z(self, slope, level):
        mag = np.maximum(self.sign_ * np.asarray(slope, float), 1.0)
        return np.log(mag) - self.beta_ * np.log(np.maximum(np.asarray(level, float), 1.0))

    def fit(self, slope: np.ndarray, level: np.ndarray, y: np.ndarray, level_range=(0, 0xFFFF)):
        slope, level, y = (np.asarray(a) for a in (slope, level, y))
        classes = np.unique(y)
        if len(classes) < 2:
            raise CivicError("training needs windows of at least two classes per monitor")
        normal = CLASS_CODES["normal"]
        ref = slope[y == normal] if np.any(y == normal) else slope
        self.sign_ = 1.0 if np.median(ref) >= 0 else -1.0
        self.beta_ = 0.0
        if self.banded:
            # common exponent: regress log|slope| on log(level) within classes
            lm = np.log(np.maximum(self.sign_ * slope, 1.0))
            ll = np.log(np.maximum(level, 1.0))
            num = den = 0.0
            for c in classes:
                k = y == c
                if k.sum() > 2:
                    dl = ll[k] - ll[k].mean()
                    num += float(dl @ (lm[k] - lm[k].mean()))
                    den += float(dl @ dl)
            self.beta_ = num / den if den > 0 else 0.0
            # keep beta only when the data show a level dependence (|t| > 3); else one band
            if den > 0:
                resid = np.concatenate([lm[y == c] - lm[y == c].mean() - self.beta_ * (ll[y == c] - ll[y == c].mean())
                                        for c in classes])
                stderr = np.sqrt(resid.var() / den)
                if abs(self.beta_) < 3 * stderr:
                    self.beta_ = 0.0
        z = self._z(slope, level)
        centers = {int(c): float(np.median(z[y == c])) for c in classes}
        order = sorted(centers, key=centers.get)      # classes by ascending z
        cuts = []
        for a, b in zip(order[:-1], order[1:]):
            cuts.append(self._best_cut(z, y, a, b, centers))
        # above the top class (faster than any normal run, by more than the distance from the
        # normal centre to its cut): the model has no explanation
        top = order[-1]
        upper = float(z[y == top].max()) + abs(centers[top] - cuts[-1]) if cuts else np.inf
        self.intervals_ = []   # (z_lo, z_hi, class) covering the real line
        lo = -np.inf
        for c, hi in zip(order, cuts + [upper]):
            self.intervals_.append((lo, hi, c))
            lo = hi
        if np.isfinite(upper):
            self.intervals_.append((upper, np.inf, ABOVE_NORMAL))
        self.level_range_ = level_range
        self.rows_ = self._rows()
        return self

    @staticmethod
    def _best_cut(z, y, a, b, centers) -> float:
        """Threshold between adjacent classes a (below) and b (above): least cost, widest margin."""
        k = (y == a) | (y == b)
        zz, yy = z[k], y[k]
        cand = np.unique(zz)
        mids = np.concatenate(([cand[0] - 1.0], (cand[:-1] + cand[1:]) / 2, [cand[-1] + 1.0]))
        costs = np.array([_cost(yy, np.where(zz < t, a, b)).sum() for t in mids])
        best = np.flatnonzero(costs == costs.min())
        # widest margin: the middle of the longest stretch of equally good cuts
        runs = np.split(best, np.flatnonzero(np.diff(best) > 1) + 1)
        widths = [cand[min(r[-1], len(cand) - 1)] - cand[max(r[0] - 1, 0)] for r in runs]
        r = runs[int(np.argmax(widths))]
        lo = cand[max(r[0] - 1, 0)] if r[0] > 0 else centers[a]
        hi = cand[min(r[-1], len(cand) - 1)] if r[-1] < len(cand) else centers[b]
        return float((lo + hi) / 2)

    # -- table
    def _bands(self) -> list[tuple[int, int, float]]:
        lo, hi = self.level_range_
        if not self.banded:
            return [(0, 0xFFFF, 1.0)]
        top = min(hi, LEVEL_TOP)
        edges = list(range(lo, top, self.band_ml)) + [top + 1]
        bands = [(a, b - 1, (a + b - 1) / 2) for a, b in zip(edges[:-1], edges[1:])]
        # outside the precondition's level range the table repeats the edge bands, so it
        # covers every level (a miss would mean error)
        last = bands[-1]
        bands[-1] = (last[0], 0xFFFF, last[2])
        if lo > 0:
            bands.insert(0, (0, lo - 1, bands[0][2]))
        return bands

    def _slope_at(self, z: float, level: float) -> int:
        """Raw slope whose feature is z at this level (rounded toward zero)."""
        v = self.sign_ * np.exp(z + self.beta_ * np.log(max(level, 1.0)))
        return int(np.clip(np.trunc(v), SLOPE_MIN, SLOPE_MAX))

    def _rows(self) -> np.ndarray:
        """Per level band, the z-intervals as contiguous raw-slope ranges covering int32."""
        cuts = [zhi for _, zhi, _ in self.intervals_[:-1]]     # interior boundaries, ascending z
        classes = [c for _, _, c in self.intervals_]
        rows = []
        for llo, lhi, lc in self._bands():
            bounds, order = [self._slope_at(z, lc) for z in cuts], classes
            if self.sign_ < 0:          # a larger |slope| is a more negative slope
                bounds, order = bounds[::-1], order[::-1]
            start = SLOPE_MIN
            for end, c in zip(bounds + [SLOPE_MAX], order):
                if end >= start:
                    rows.append([start, end, llo, lhi, c])
                    start = end + 1
        return self._merge_bands(np.array(rows, dtype=np.int64))

    @staticmethod
    def _merge_bands(rows: np.ndarray) -> np.ndarray:
        """Join neighbouring bands with identical slope boundaries (fewer table entries)."""
        out: list[list[int]] = []
        bands = [rows[rows[:, 2] == lo] for lo in np.unique(rows[:, 2])]
        prev = None
        for b in bands:
            key = b[:, [0, 1, 4]].tolist()
            if key == prev:
                for r in out[-len(b):]:
                    r[3] = int(b[0, 3])
            else:
                out.extend(b.tolist())
            prev = key
        return np.array(out, dtype=np.int64)

    def predict(self, slope, level) -> np.ndarray:
        from civic.pipeline.classification import classify
        return classify(np.asarray(slope), np.asarray(level), self.rows_, ABOVE_NORMAL)

    def score(self, slope, level, y) -> float:
        return float(np.mean(self.predict(slope, level) == np.asarray(y)))


def offsets_for(mon: Monitor, estimator: str, envelope) -> np.ndarray:
    """The monitor's compensate table from the calibrated model (empty: not compensated)."""
    if envelope is None or mon.compensate is None:
        return np.zeros((0, 3), np.int64)
    from civic.envelope import compensation_table

    probe = monitor_entries(mon, estimator)
    step = mon.window - 1 if estimator == "lsq" else 1
    return compensation_table(envelope.model_, *mon.compensate, probe.slope_scale, step)


def fit_monitor(mon: Monitor, runs: list[Run], estimator: str, banded: bool,
                offsets: np.ndarray | None = None) -> tuple[MonitorEntries, BandClassifier]:
    mine = [r for r in runs if r.monitor == mon.name and len(r.slope)]
    if not mine:
        raise CivicError(f"no evaluated training windows for monitor {mon.name!r}")
    offsets = np.zeros((0, 3), np.int64) if offsets is None else offsets
    resid = np.concatenate([r.resid(offsets) for r in mine])
    level = np.concatenate([r.level for r in mine])
    y = np.concatenate([np.full(len(r.slope), r.cls) for r in mine])
    lrange = mon.precondition.get(mon.signal, (0, 0xFFFF))
    clf = BandClassifier(banded=banded).fit(resid, level, y, level_range=lrange)
    return monitor_entries(mon, estimator, clf.rows_, ABOVE_NORMAL, offsets), clf


def train(runs: list[Run], config: MonitorConfig, estimator: str, banded: bool, envelope=None,
          model=None, progress=None) -> Entries:
    """Class tables from the recordings' windows, with an envelope: compensated, over the envelope.

    Balance monitors (docs/pipeline.md 3b) are trained on simulated closed-loop operation of the
    plant model (the envelope's calibrated one, else `model`): civic.continuous."""
    tested = [m for m in config.monitors if m.kind == "slope"]
    for mon in tested:
        if not any(r.monitor == mon.name for r in runs):
            raise CivicError(f"labels have no recording for monitor {mon.name!r} (drop it from the monitors file)")
    single = MonitorConfig(tested, config.udp_port, config.plant_prefix)
    simulated = envelope_runs(envelope, single, estimator) if envelope is not None else []
    fitted = {mon.name: fit_monitor(mon, runs + simulated, estimator, banded, offsets_for(mon, estimator, envelope))[0]
              for mon in tested}
    training = {"estimator": estimator, "banded": banded, "runs": sorted({r.file for r in runs})}
    for mon in config.monitors:
        if mon.kind == "limit":
            fitted[mon.name] = limit_entries(mon)
    balances = [m for m in config.monitors if m.kind == "balance"]
    if balances:
        from civic.continuous import CLOSED_LOOP_UNITS, CLOSED_LOOP_SEED, UNIT_SPREAD, closed_loop_runs, train_balance

        plant = envelope.model_ if envelope is not None else model
        if plant is None:
            from civic.plant.model import DATASHEET, PlantModel

            plant = PlantModel.from_toml(DATASHEET)
        sims = closed_loop_runs(plant, CLOSED_LOOP_UNITS, UNIT_SPREAD, CLOSED_LOOP_SEED, progress=progress)
        training["closed_loop"] = {"simulated_runs": len(sims), "unit_spread": UNIT_SPREAD, "monitors": {}}
        for mon in balances:
            fitted[mon.name], info = train_balance(mon, plant, sims)
            training["closed_loop"]["monitors"][mon.name] = info
    if envelope is not None:
        training["calibrated"] = envelope.calibrated_
        training["envelope"] = {"start_levels_l": {k: list(map(float, v)) for k, v in envelope.start_levels.items()},
                                "units_per_case": envelope.units, "unit_spread": envelope.spread,
                                "simulated_runs": len(simulated)}
    return Entries(monitors=[fitted[m.name] for m in config.monitors], udp_port=config.udp_port,
                   plant_prefix=config.plant_prefix, training=training)


def limit_entries(mon: Monitor) -> MonitorEntries:
    """A limit monitor's class table straight from its configured limits (nothing to learn)."""
    if not mon.limits:
        raise CivicError(f"monitor {mon.name}: a limit monitor needs limits = {{ warning = N, error = N }}")
    w, e = mon.limits["warning"], mon.limits["error"]
    if w < e:          # a high limit: normal below the warning limit
        rows = [[0, w - 1, 0, 0xFFFF, 1], [w, e - 1, 0, 0xFFFF, 2], [e, 0xFFFF, 0, 0xFFFF, 3]]
    else:              # a low limit: normal above it
        rows = [[w + 1, 0xFFFF, 0, 0xFFFF, 1], [e + 1, w, 0, 0xFFFF, 2], [0, e, 0, 0xFFFF, 3]]
    return monitor_entries(mon, "value", rows, default_class=1)


def predict_run(entries: MonitorEntries, run: Run) -> np.ndarray:
    """The classes the switch gives a run's windows under these entries (compensated as they say)."""
    from civic.pipeline.classification import classify
    return classify(run.resid(entries.offsets), run.level, entries.classes, entries.default_class)


def leave_one_run_out(runs: list[Run], mon: Monitor, estimator: str, banded: bool,
                      envelope_without=None) -> tuple[np.ndarray, np.ndarray]:
    """Pooled (true, predicted) classes, each run predicted by a table trained without it.

    envelope_without(file) -> Envelope calibrated without that recording: the calibrated mode."""
    mine = [r for r in runs if r.monitor == mon.name and len(r.slope)]
    single = MonitorConfig([mon])
    true, pred = [], []
    for i, held in enumerate(mine):
        rest = mine[:i] + mine[i + 1:]
        env = envelope_without(held.file) if envelope_without else None
        simulated = envelope_runs(env, single, estimator) if env is not None else []
        entries, _ = fit_monitor(mon, rest + simulated, estimator, banded, offsets_for(mon, estimator, env))
        true.append(np.full(len(held.slope), held.cls))
        pred.append(predict_run(entries, held))
    return np.concatenate(true), np.concatenate(pred)
