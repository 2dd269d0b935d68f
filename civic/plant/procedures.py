"""Test procedures of docs/plant.md (drain test, fill test) and their fault classes.

A procedure is a start state, a command schedule and a duration; a fault is a
manual-valve closure (VM1 on the drain link for the drain test, VM2 on the pump
for the fill test) applied to a copy of the model.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from civic.errors import CivicError
from civic.plant.model import PlantModel
from civic.plant.simulate import simulate

TOTAL_VOLUME = 40.0
SWITCH_TIME = 3.0       # s: the test command is applied at t = 3 s

# fault classes: closure fraction of the manual valve per class
FAULT_CLASSES = {
    "drain": {"normal": 0.0, "warning": 0.30, "error": 0.55},
    "fill": {"normal": 0.0, "warning": 0.20, "error": 0.40},
}
MONITORS = {"drain": "drain_t3", "fill": "fill_t1"}
DURATION = {"drain": 18.0, "fill": 40.0}
DEFAULT_V0 = {"drain": 7.5, "fill": 3.0}
LABEL_COLUMNS = ("file", "scenario", "monitor", "class", "v0", "closure", "seed", "src_ip", "set")


@dataclass
class Procedure:
    scenario: str
    t: np.ndarray
    inputs: dict
    x0: dict
    model: PlantModel
    closure: float
    v0: float


def class_of(scenario: str, closure: float) -> str:
    """Fault class of a closure (the nearest class level; exact levels map to themselves)."""
    levels = FAULT_CLASSES[scenario]
    return min(levels, key=lambda k: abs(levels[k] - closure))


def parse_fault(text: str | None) -> dict:
    """'vm1=0.3' or 'vm2=0.2' (also 'vm1=warning') -> {'vm1': 0.3}."""
    if not text:
        return {}
    out = {}
    for part in text.split(","):
        if "=" not in part:
            raise CivicError(f"bad --fault {text!r}: expected vm1=C or vm2=C")
        k, v = (s.strip().lower() for s in part.split("=", 1))
        if k not in ("vm1", "vm2"):
            raise CivicError(f"bad --fault {text!r}: unknown valve {k!r} (vm1 = drain line, vm2 = pump line)")
        scen = "drain" if k == "vm1" else "fill"
        if v in FAULT_CLASSES[scen]:
            c = FAULT_CLASSES[scen][v]
        else:
            try:
                c = float(v)
            except ValueError:
                raise CivicError(f"bad --fault {text!r}: closure must be a number in [0, 1] or a class name") from None
        if not 0.0 <= c <= 1.0:
            raise CivicError(f"bad --fault {text!r}: closure must lie in [0, 1]")
        out[k] = c
    return out


def apply_faults(model: PlantModel, faults: dict) -> PlantModel:
    """A copy with VM1 (closure on the link draining T3) / VM2 (pump closure) set."""
    m = model.copy()
    if "vm1" in faults:
        links = [lk for lk in m.links if lk.valve is not None and lk.law == "orifice"] or \
                [lk for lk in m.links if lk.law == "orifice"]
        if not links:
            raise CivicError(f"model {m.name}: no drain link for vm1")
        links[-1].closure = faults["vm1"]
    if "vm2" in faults:
        if not m.pumps:
            raise CivicError(f"model {m.name}: no pump for vm2")
        m.pumps[0].closure = faults["vm2"]
    return m


def _check_plant(model: PlantModel):
    need = {"T1", "T2", "T3", "T4"}
    if not need <= set(model.tank_names) or not {"p1", "v1", "v2"} <= set(model.input_names):
        raise CivicError(f"model {model.name}: the drain/fill tests need tanks T1..T4 and inputs p1, v1, v2")


def drain_test(model: PlantModel, v0: float = 7.5, closure: float = 0.0, duration: float | None = None) -> Procedure:
    """V1 = V2 = V3 = v0, V4 = 40 - 3 v0, all off; at t = 3 s V2 -> 100 %."""
    _check_plant(model)
    if not 0.0 < v0 <= 10.0:
        raise CivicError(f"--v0 {v0}: the start volume must lie in (0, 10] L")
    if 3 * v0 > TOTAL_VOLUME:
        raise CivicError(f"--v0 {v0}: more water than the plant holds")
    return _step_test("drain", apply_faults(model, {"vm1": closure}), "v2", v0, closure, duration)


def fill_test(model: PlantModel, v0: float = 3.0, closure: float = 0.0, duration: float | None = None) -> Procedure:
    """V1 = V2 = V3 = 3 L, V4 = 31 L, all off; at t = 3 s P1 -> 100 %."""
    _check_plant(model)
    if not 0.0 <= v0 <= 10.0 or 3 * v0 > TOTAL_VOLUME:
        raise CivicError(f"--v0 {v0}: the start volume must lie in [0, 10] L")
    return _step_test("fill", apply_faults(model, {"vm2": closure}), "p1", v0, closure, duration)


def _step_test(scenario: str, m: PlantModel, step: str, v0: float, closure: float,
               duration: float | None) -> Procedure:
    """T1..T3 at v0, the rest of the water in T4, all off; at SWITCH_TIME `step` -> 100 %."""
    dur = DURATION[scenario] if duration is None else duration
    n = int(round(dur / m.dt))
    t = np.arange(n) * m.dt
    inputs = {k: np.zeros(n) for k in ("p1", "v1", "v2")}
    inputs[step] = np.where(t >= SWITCH_TIME - 1e-9, 1.0, 0.0)
    x0 = {"T1": v0, "T2": v0, "T3": v0, "T4": TOTAL_VOLUME - 3 * v0, "V1": 0.0, "V2": 0.0}
    return Procedure(scenario, t, inputs, x0, m, closure, v0)


def make_procedure(model: PlantModel, scenario: str, v0: float | None = None, faults: dict | None = None,
                   duration: float | None = None) -> Procedure:
    faults = faults or {}
    if scenario == "drain":
        if "vm2" in faults and faults["vm2"] > 0:
            model = apply_faults(model, {"vm2": faults["vm2"]})
        return drain_test(model, DEFAULT_V0["drain"] if v0 is None else v0, faults.get("vm1", 0.0), duration)
    if scenario == "fill":
        if "vm1" in faults and faults["vm1"] > 0:
            model = apply_faults(model, {"vm1": faults["vm1"]})
        return fill_test(model, DEFAULT_V0["fill"] if v0 is None else v0, faults.get("vm2", 0.0), duration)
    raise CivicError(f"unknown scenario {scenario!r} (drain, fill, closed-loop)")


def run_procedure(proc: Procedure, noise: bool = True, seed=None) -> dict:
    return simulate(proc.model, proc.t, proc.inputs, proc.x0, noise=noise, seed=seed)


def label_row(file: str, proc: Procedure, seed, src_ip: str = "10.0.0.1", set_name: str | None = None) -> dict:
    """One row of labels.csv (columns as in traces/training/labels.csv)."""
    if set_name is None:
        set_name = f"drain_v{int(round(proc.v0 * 10)):03d}" if proc.scenario == "drain" else "fill"
    return {"file": file, "scenario": proc.scenario, "monitor": MONITORS[proc.scenario],
            "class": class_of(proc.scenario, proc.closure), "v0": repr(float(proc.v0)),
            "closure": repr(float(proc.closure)), "seed": "" if seed is None else str(seed),
            "src_ip": src_ip, "set": set_name}


def append_label(path, row: dict) -> None:
    """Append a row to a labels CSV (writing the header for a new file; the row's keys are the columns,
    those of LABEL_COLUMNS first)."""
    import csv
    import os

    new = not os.path.exists(path) or os.path.getsize(path) == 0
    columns = [c for c in LABEL_COLUMNS if c in row] + [c for c in row if c not in LABEL_COLUMNS]
    with open(path, "a", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=columns)
        if new:
            w.writeheader()
        w.writerow(row)


def lsq_slopes(x: np.ndarray, window: int, dt: float) -> np.ndarray:
    """Least-squares slope (units/s) of every full window ending at each sample (NaN before)."""
    x = np.asarray(x, float)
    n = len(x)
    out = np.full(n, np.nan)
    if n < window:
        return out
    k = np.arange(window) - (window - 1) / 2
    den = np.sum(k * k) * dt
    win = np.lib.stride_tricks.sliding_window_view(x, window)
    out[window - 1:] = win @ k / den
    return out


def monitor_slopes(scenario: str, signals: dict, dt: float = 0.1) -> np.ndarray:
    """Slopes (L/s) of the monitored signal over the windows where the monitor evaluates."""
    if scenario == "drain":
        x, w = signals["L3"], 20
        ok = (signals["L3"] > 3.0) & (signals["v2"] >= 0.8)
    else:
        x, w = signals["L1"], 90
        ok = (signals["p1"] > 0.99) & (signals["L1"] > 5.0) & (signals["L1"] < 8.0)
    s = lsq_slopes(x, w, dt)
    run = np.zeros(len(ok), int)
    c = 0
    for i, q in enumerate(ok):
        c = c + 1 if q else 0
        run[i] = c
    return s[run >= w]
