"""civic crossval: leave-one-run-out scores of every training mode, side by side."""
from __future__ import annotations

import json
from pathlib import Path

from civic.errors import CivicError


def register(sub) -> None:
    p = sub.add_parser("crossval", help="leave-one-run-out comparison of paper mode and improved modes")
    p.add_argument("training_dir", metavar="TRAINING_DIR")
    p.add_argument("--labels", metavar="FILE", help="labels CSV (default: TRAINING_DIR/labels.csv)")
    p.add_argument("--monitors", metavar="FILE")
    p.add_argument("--json", metavar="FILE")
    p.add_argument("--sim", action="store_true",
                   help="also score every mode on simulated tests from start levels 6.0-8.5 L, "
                        "and tables derived from the plant model alone")
    p.add_argument("--model", metavar="FILE", help="plant model for --sim (default: configs/plant.toml)")
    p.set_defaults(func=run)


def run(args) -> int:
    from rich.table import Table

    from civic.config import load_monitors
    from civic.evaluate import score
    from civic.report import console
    from civic.train import MODES, collect_runs, leave_one_run_out, read_labels

    folder = Path(args.training_dir)
    if not folder.is_dir():
        raise CivicError(f"{folder}: not a directory")
    labels = read_labels(args.labels or folder / "labels.csv")
    config = load_monitors(args.monitors)
    runs = {est: collect_runs(folder, labels, config, est) for est in {m[0] for m in MODES}}
    report = {}
    table = Table(title="leave-one-run-out macro F1 (accuracy)", title_justify="left")
    table.add_column("monitor")
    for est, banded in MODES:
        table.add_column(f"{est}, {'banded' if banded else '1-D'}" + (" (paper)" if (est, banded) == MODES[0] else ""),
                         justify="right")
    for mon in config.monitors:
        if not any(r.monitor == mon.name for r in runs["lsq"]):
            continue
        cells = []
        for est, banded in MODES:
            s = score(*leave_one_run_out(runs[est], mon, est, banded))
            report.setdefault(mon.name, {})[f"{est}_{'banded' if banded else '1d'}"] = s
            cells.append(f"{s['macro_f1']:.3f} ({s['accuracy']:.3f})")
        table.add_row(mon.name, *cells)
    console.print(table)
    if args.sim:
        report["simulated"] = simulated_scores(runs, config, args.model)
    if args.json:
        Path(args.json).write_text(json.dumps(report, indent=1) + "\n")
    return 0


def simulated_scores(runs: dict, config, model_path: str | None) -> dict:
    """Every mode trained on the recordings, and lsq/banded trained on the model, scored on simulated tests."""
    import tempfile

    import numpy as np
    from rich.table import Table

    from civic.commands.simulate import default_model_path
    from civic.evalsets import DRAIN_LEVELS, simulate_set
    from civic.evaluate import score
    from civic.plant.model import PlantModel
    from civic.report import console
    from civic.train import MODES, collect_runs, fit_monitor, read_labels

    model = PlantModel.from_toml(model_path or default_model_path())
    with tempfile.TemporaryDirectory(prefix="civic-sim-") as tmp:
        labels = read_labels(simulate_set(Path(tmp) / "eval", model, runs=2, seed=7000))
        evals = {est: collect_runs(Path(tmp) / "eval", labels, config, est) for est in runs}
        train_labels = read_labels(simulate_set(Path(tmp) / "train", model, runs=3, seed=9000))
        from_model = collect_runs(Path(tmp) / "train", train_labels, config, "lsq")
    sources = [(f"{est}, {'banded' if b else '1-D'} (recordings)", runs[est], est, b) for est, b in MODES]
    sources.append(("lsq, banded (model only)", from_model, "lsq", True))
    levels = ", ".join(f"{v:g}" for v in DRAIN_LEVELS)
    table = Table(title=f"macro F1 on simulated tests (drain from {levels} L; fill)", title_justify="left")
    table.add_column("trained as")
    names = [m.name for m in config.monitors if any(r.monitor == m.name for r in evals["lsq"])]
    for n in names:
        table.add_column(f"{n} (sim)", justify="right")
    for n in names:
        table.add_column(f"{n} (recordings)", justify="right")
    def scored(clf, held_runs, name):
        held = [r for r in held_runs if r.monitor == name and len(r.slope)]
        return score(np.concatenate([np.full(len(r.slope), r.cls) for r in held]),
                     np.concatenate([clf.predict(r.slope, r.level) for r in held]))

    out = {}
    for label, train_runs, est, banded in sources:
        sim_cells, real_cells = [], []
        for mon in (m for m in config.monitors if m.name in names):
            _, clf = fit_monitor(mon, train_runs, est, banded)
            s = out.setdefault(label, {})[mon.name] = scored(clf, evals[est], mon.name)
            sim_cells.append(f"{s['macro_f1']:.3f}")
            if train_runs is from_model:  # model-only tables meet the real recordings
                s = out[label][mon.name + "_on_recordings"] = scored(clf, runs[est], mon.name)
                real_cells.append(f"{s['macro_f1']:.3f}")
            else:
                real_cells.append("see LORO")
        table.add_row(label, *sim_cells, *real_cells)
    console.print(table)
    return out
