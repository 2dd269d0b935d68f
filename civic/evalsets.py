"""Labelled tests made with the plant simulator: evaluation sets and model-only training.

`simulate_set` writes recordings (pcap + labels.csv); `unit_tests` and `fleet` make
plant messages in memory for scoring tables over the operating envelope: drain tests
from every start level, fill tests, on units whose coefficients spread around the
datasheet, and many plants interleaved in one capture.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from civic.envelope import FAULT_VALVE, UNIT_COEFFICIENTS, messages
from civic.plant.model import PlantModel
from civic.plant.procedures import FAULT_CLASSES, append_label, label_row, make_procedure, run_procedure
from civic.plant.simulate import to_wire, write_recording
from civic.report import progress_bar
from civic.wire import CLASS_CODES, ip_to_int

DRAIN_LEVELS = (6.0, 6.5, 7.0, 7.5, 8.0, 8.5)   # L: start conditions around the paper's 6.5 and 7.5
ENVELOPE_LEVELS = tuple(np.round(np.arange(5.0, 9.51, 0.5), 1))   # L: the drain test's operating envelope
MONITOR_OF = {"drain": "drain_t3", "fill": "fill_t1"}


def simulate_set(folder: str | Path, model: PlantModel, drain_levels=DRAIN_LEVELS, runs: int = 2,
                 seed: int = 1000, fill: bool = True) -> Path:
    """Drain tests from every start level and fill tests, every fault class, `runs` noisy runs each.

    Writes one pcap per run and a labels.csv into `folder`; returns the labels path.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    labels = folder / "labels.csv"
    labels.unlink(missing_ok=True)
    jobs = [("drain", v0) for v0 in drain_levels] + ([("fill", None)] if fill else [])
    total = len(jobs) * 3 * runs
    with progress_bar() as progress:
        task = progress.add_task("simulating", total=total)
        for scenario, v0 in jobs:
            valve = "vm1" if scenario == "drain" else "vm2"
            for cls, closure in FAULT_CLASSES[scenario].items():
                for r in range(runs):
                    seed += 1
                    proc = make_procedure(model, scenario, v0, {valve: closure})
                    name = f"{scenario}_{'' if v0 is None else f'v{round(v0 * 10):03d}_'}{cls}_s{seed}.pcap"
                    write_recording(folder / name, proc.model, proc.t, run_procedure(proc, True, seed), seed=seed)
                    append_label(labels, label_row(name, proc, seed))
                    progress.advance(task)
    return labels


@dataclass
class Test:
    """One simulated test of one plant: its monitor, true class and messages."""

    monitor: str
    cls: int
    v0: float
    msgs: np.ndarray


def spread_unit(model: PlantModel, rng: np.random.Generator, spread: float) -> PlantModel:
    """A unit of the plant type: every unit coefficient within ±spread of the model's."""
    m = model.copy()
    for p in UNIT_COEFFICIENTS:
        m.set(p, float(m.get(p)) * (1 + rng.uniform(-spread, spread)))
    return m


def unit_test(model: PlantModel, scenario: str, v0: float, cls: str, rng: np.random.Generator,
              spread: float, src: str = "10.0.0.1") -> Test:
    proc = make_procedure(spread_unit(model, rng, spread), scenario, v0,
                          {FAULT_VALVE[scenario]: FAULT_CLASSES[scenario][cls]})
    sim = run_procedure(proc, noise=True, seed=int(rng.integers(2**31)))
    msgs = messages(to_wire(proc.model, sim), seq0=int(rng.integers(2**32)), src=ip_to_int(src))
    return Test(MONITOR_OF[scenario], CLASS_CODES[cls], float(proc.v0), msgs)


def unit_tests(model: PlantModel, scenario: str, v0: float | None, runs: int, spread: float,
               seed: int) -> list[Test]:
    """`runs` tests per fault class from one start level, each on its own unit."""
    rng = np.random.default_rng([seed, int(round((v0 or 0) * 10)), len(scenario)])
    return [unit_test(model, scenario, v0, cls, rng, spread) for cls in FAULT_CLASSES[scenario] for _ in range(runs)]


def fleet(model: PlantModel, plants: int, spread: float, seed: int, levels=ENVELOPE_LEVELS) -> list[Test]:
    """`plants` drain tests in one capture: gateways 10.0.0.1.., classes in turn, start levels drawn
    from the envelope, each plant its own unit, messages interleaved in time (plant k at k*dt/N)."""
    rng = np.random.default_rng(seed)
    classes = list(FAULT_CLASSES["drain"])
    tests = []
    for k in range(plants):
        t = unit_test(model, "drain", float(rng.choice(levels)), classes[k % 3], rng, spread,
                      src=f"10.0.0.{k + 1}")
        t.msgs["t"] += k * model.dt / plants
        tests.append(t)
    return tests
