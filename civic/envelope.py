"""The operating envelope for training: the plant model calibrated to the recordings, its windows.

The bundled recordings all start at 7.5 L on one unit; a switch must classify
drain tests from any start level on any unit of the plant type. `Envelope`
calibrates the coefficients a test exercises to the recordings (scipy least
squares: the recorded commands and start state through the simulator, closures
fixed by the fault classes), then simulates the test from every start level of
the envelope, every class, on units whose coefficients spread over the datasheet's
and the calibrated unit's ±3 %, with the sensors' noise. Its windows (what the
switch computes) join the recordings in training; the recordings stay the check.

`compensation_table` turns the calibrated link law into the switch's compensate
table (docs/pipeline.md 3a).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from civic.errors import CivicError
from civic.plant.model import DATASHEET, PlantModel
from civic.plant.procedures import FAULT_CLASSES, apply_faults, make_procedure, run_procedure
from civic.plant.simulate import from_wire, measured_state, simulate, to_wire
from civic.wire import CLASS_CODES, MESSAGE_DTYPE, ip_to_int, read_pcap

SCENARIOS = {"drain_t3": "drain", "fill_t1": "fill"}      # monitor -> test procedure (docs/plant.md)
# the levels each test's fit compares: T3 and T2 (pipe23 empties T2 into T3) for the drain test
TESTED_SIGNALS = {"drain": ("L2", "L3"), "fill": ("L1",)}
FAULT_VALVE = {"drain": "vm1", "fill": "vm2"}
# the coefficients each test exercises (calibrated to the recordings)
CALIBRATED = {"drain": ("link.pipe23.coeff", "link.V2.coeff"), "fill": ("pump.P1.gain",)}
# the coefficients that differ between units of the plant type
UNIT_COEFFICIENTS = ("pump.P1.gain", "link.V1.coeff", "link.pipe23.coeff", "link.V2.coeff")
UNIT_SPREAD = 0.03
START_LEVELS = {"drain": tuple(np.round(np.arange(4.5, 10.01, 0.5), 1)), "fill": (2.5, 3.0, 3.5)}
UNITS_PER_CASE = 4
OFFSET_TOLERANCE = 2.0      # mL/s: largest step error of the piecewise constant compensation
PLANT_SRC = ip_to_int("10.0.0.1")


@dataclass
class Recorded:
    """One labelled recording of one plant: its wire fields and class."""

    file: str
    monitor: str
    cls: int
    fields: dict          # wire field -> int64 array
    t: np.ndarray


def load_recorded(folder: str | Path, labels: list[dict], udp_port: int, prefix: str) -> list[Recorded]:
    out = []
    for row in labels:
        cap = read_pcap(Path(folder) / row["file"], udp_port, prefix)
        msgs = cap.messages[cap.messages["plant"]]
        if row.get("src_ip"):
            msgs = msgs[msgs["src"] == ip_to_int(row["src_ip"])]
        if len(msgs) < 2:
            continue
        fields = {k: msgs[k].astype(np.int64) for k in ("l1", "l2", "l3", "l4", "p1", "v1", "v2")}
        out.append(Recorded(row["file"], row["monitor"], CLASS_CODES[row["class"]], fields, msgs["t"] - msgs["t"][0]))
    return out


def messages(fields: dict, seq0: int = 1, src: int = PLANT_SRC, dt: float = 0.1) -> np.ndarray:
    """Plant messages (MESSAGE_DTYPE) from wire fields, consecutive sequence numbers."""
    n = len(fields["l1"])
    a = np.zeros(n, MESSAGE_DTYPE)
    a["t"] = np.arange(n) * dt
    a["plant"] = True
    a["src"] = src
    a["seq"] = (seq0 + np.arange(n)) & 0xFFFFFFFF
    for k, v in fields.items():
        a[k] = v
    return a


@dataclass
class Envelope:
    """Calibrate the plant model to recordings, then simulate the tests the recordings lack."""

    model: PlantModel
    start_levels: dict = field(default_factory=lambda: dict(START_LEVELS))
    units: int = UNITS_PER_CASE
    spread: float = UNIT_SPREAD
    seed: int = 2026

    def fit(self, recorded: list[Recorded]) -> "Envelope":
        """Calibrated coefficients per test (scenario -> {path: value}) and a calibrated model."""
        self.calibrated_ = {}
        self.model_ = self.model.copy()
        for scenario, params in CALIBRATED.items():
            runs = [r for r in recorded if SCENARIOS.get(r.monitor) == scenario]
            if runs:
                values = self._calibrate(runs, scenario, params)
                self.calibrated_[scenario] = values
                for p, v in values.items():
                    self.model_.set(p, v)
        return self

    def _calibrate(self, runs: list[Recorded], scenario: str, params: tuple) -> dict:
        from scipy.optimize import least_squares

        signals_fit = TESTED_SIGNALS[scenario]
        nominal = np.array([float(self.model.get(p)) for p in params])
        cases = []
        closures = {CLASS_CODES[c]: v for c, v in FAULT_CLASSES[scenario].items()}
        for r in runs:
            signals = from_wire(self.model, r.fields)
            model = apply_faults(self.model, {FAULT_VALVE[scenario]: closures[r.cls]})
            x0 = measured_state(model, signals, average=3)
            inputs = {k: signals[k] for k in ("p1", "v1", "v2")}
            cases.append((model, np.arange(len(r.t)) * model.dt, inputs, x0, signals))

        def residuals(scale):
            out = []
            for model, t, inputs, x0, signals in cases:
                m = model.copy()
                for p, v in zip(params, nominal * scale):
                    m.set(p, v)
                sim = simulate(m, t, inputs, x0)
                out += [sim[s] - signals[s] for s in signals_fit]
            return np.concatenate(out)

        fit = least_squares(residuals, np.ones(len(params)), bounds=(0.5, 2.0), x_scale=0.05)
        if not fit.success:
            raise CivicError(f"calibrating the {scenario} test's coefficients to the recordings failed")
        return {p: float(v) for p, v in zip(params, nominal * fit.x)}

    def unit_range(self, path: str) -> tuple[float, float]:
        """Coefficient range of the plant type's units: the datasheet's and the calibrated ±spread."""
        a, b = float(self.model.get(path)), float(self.model_.get(path))
        return min(a, b) * (1 - self.spread), max(a, b) * (1 + self.spread)

    def unit(self, rng: np.random.Generator) -> PlantModel:
        m = self.model_.copy()
        for p in UNIT_COEFFICIENTS:
            lo, hi = self.unit_range(p)
            m.set(p, float(rng.uniform(lo, hi)))
        return m

    def runs(self, monitor: str) -> list[tuple[int, np.ndarray]]:
        """(class, plant messages) of every simulated test for a monitor (none if it has no test)."""
        scenario = SCENARIOS.get(monitor)
        if scenario is None:
            return []
        rng = np.random.default_rng([self.seed, len(monitor)])
        out = []
        for v0 in self.start_levels[scenario]:
            for cls, closure in FAULT_CLASSES[scenario].items():
                for _ in range(self.units):
                    proc = make_procedure(self.unit(rng), scenario, float(v0), {FAULT_VALVE[scenario]: closure})
                    sim = run_procedure(proc, noise=True, seed=int(rng.integers(2**31)))
                    out.append((CLASS_CODES[cls], messages(to_wire(proc.model, sim))))
        return out


def compensation_table(model: PlantModel, plus: str, minus: str, scale: float, step: int,
                       tolerance: float = OFFSET_TOLERANCE) -> np.ndarray:
    """Compensate table rows (aux_lo, aux_hi, offset): the flow from `plus`'s tank into `minus`'s
    tank when their volumes differ by aux mL, by the model's link law, in raw slope units
    (`scale` mL/s per raw unit), piecewise constant within `tolerance` mL/s, offsets
    multiples of `step`. Needs equal tank areas (aux is a volume difference)."""
    tank = {s.wire: s.tank for s in model.sensors if s.wire}
    a, b = tank.get(plus), tank.get(minus)
    link = next((lk for lk in model.links if {lk.from_, lk.to} == {a, b}), None)
    if link is None:
        raise CivicError(f"plant model {model.name}: no link between {a} ({plus}) and {b} ({minus}) to compensate")
    area = model.tank(a).area
    if abs(model.tank(b).area - area) > 1e-9:
        raise CivicError(f"compensating {plus} - {minus}: tanks {a} and {b} differ in area")
    rim = max(model.tank(a).rim_volume(), model.tank(b).rim_volume())
    top = int(min(rim if np.isfinite(rim) else 65.535, 65.535) * 1000)
    aux = np.arange(top + 1)
    if link.law != "bidirectional" and link.from_ != a:
        raise CivicError(f"compensating {plus} - {minus}: link {link.name} never flows from {a} to {b}")
    flow = link.coeff * (aux / 1000.0 / area) ** link.exponent * 1000.0       # mL/s into `minus`
    rows, lo = [], 0
    while lo <= top:
        # the longest stretch whose flows stay within 2 * tolerance
        hi = int(np.searchsorted(flow, flow[lo] + 2 * tolerance, side="right")) - 1
        hi = max(lo, min(hi, top))
        mid = (flow[lo] + flow[hi]) / 2 / scale
        rows.append([lo, hi if hi < top else 0xFFFF, int(round(mid / step)) * step])
        lo = hi + 1
    return np.array(rows, dtype=np.int64)


def calibrated(folder: str | Path, labels: list[dict], config, model: PlantModel | None = None) -> Envelope:
    """The envelope of `civic train`'s default: the plant model (default configs/plant.toml)
    calibrated to the labelled recordings in `folder`."""
    if model is None:
        model = PlantModel.from_toml(DATASHEET)
    return Envelope(model).fit(load_recorded(folder, labels, config.udp_port, config.plant_prefix))
