"""Labelled recordings made with the plant simulator: evaluation sets and model-only training."""
from __future__ import annotations

from pathlib import Path

from civic.plant.model import PlantModel
from civic.plant.procedures import FAULT_CLASSES, append_label, label_row, make_procedure, run_procedure
from civic.plant.simulate import write_recording
from civic.report import progress_bar

DRAIN_LEVELS = (6.0, 6.5, 7.0, 7.5, 8.0, 8.5)   # L: start conditions around the paper's 6.5 and 7.5


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
