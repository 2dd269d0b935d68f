"""civic crossval: the paper's mode, the previous default and the default, side by side.

Scored on leave-one-run-out of the recordings (every table trained without the run
it classifies; the default's calibration too), and, unless --no-sim, on simulated
tests the recordings lack: drain tests from every start level 5.0-9.5 L, fill tests,
each on its own unit (coefficients within ±3 % of the datasheet), and a 64-plant
capture. Simulated tests go through the switch model with the trained entries.
With balance monitors configured, closed-loop rows follow: every fault and severity
(and fault-free operation) switched on at 200-500 s into 15 minutes of PI operation,
on units spread ±3 % that training never saw; the balance monitors are scored over
time (civic evaluate's closed-loop rules) and the test monitors must stay silent
before the onset.
"""
from __future__ import annotations

import json
from pathlib import Path

from civic.errors import CivicError

# mode -> (estimator, banded, calibrate); the paper's first
MODES = {"paper": ("endpoint", False, False), "previous default": ("lsq", True, False),
         "default": ("lsq", True, True)}
SIM_RUNS = 3          # simulated tests per class and start level
FLEET_PLANTS = 64
CLOSED_LOOP_UNITS = 4     # simulated units per closed-loop fault case (5 cases each)


def register(sub) -> None:
    p = sub.add_parser("crossval", help="compare the paper's mode and the defaults on recordings and simulated tests")
    p.add_argument("training_dir", metavar="TRAINING_DIR")
    p.add_argument("--labels", metavar="FILE", help="labels CSV (default: TRAINING_DIR/labels.csv)")
    p.add_argument("--monitors", metavar="FILE")
    p.add_argument("--json", metavar="FILE")
    p.add_argument("--no-sim", dest="sim", action="store_false",
                   help="leave-one-run-out only (no simulated start levels, units, fleet)")
    p.add_argument("--spread", type=float, default=0.03, metavar="F",
                   help="unit coefficient spread of the simulated tests (default 0.03)")
    p.add_argument("--seed", type=int, default=7000)
    p.add_argument("--model", metavar="FILE", help="plant model (default: configs/plant.toml)")
    p.set_defaults(func=run)


def cell(s: dict) -> str:
    return f"{s['macro_f1']:.3f} / {s['classes']['error']['recall']:.3f}" if s else "-"


def run(args) -> int:
    from rich.table import Table

    from civic.commands.simulate import default_model_path
    from civic.config import load_monitors
    from civic.envelope import Envelope, load_recorded
    from civic.evaluate import score
    from civic.plant.model import PlantModel
    from civic.report import console, progress_bar
    from civic.train import collect_runs, leave_one_run_out, read_labels, train

    folder = Path(args.training_dir)
    if not folder.is_dir():
        raise CivicError(f"{folder}: not a directory")
    if not 0 <= args.spread < 0.5:
        raise CivicError(f"--spread {args.spread}: expected a fraction in [0, 0.5)")
    labels = read_labels(args.labels or folder / "labels.csv")
    config = load_monitors(args.monitors)
    model = PlantModel.from_toml(args.model or default_model_path())
    runs = {est: collect_runs(folder, labels, config, est) for est in {m[0] for m in MODES.values()}}
    recorded = load_recorded(folder, labels, config.udp_port, config.plant_prefix)
    monitors = [m for m in config.monitors if any(r.monitor == m.name for r in runs["lsq"])]

    def envelope_without(file: str) -> Envelope:
        return Envelope(model).fit([r for r in recorded if r.file != file])

    report: dict = {"modes": {k: dict(zip(("estimator", "banded", "calibrate"), v)) for k, v in MODES.items()},
                    "leave_one_run_out": {}}
    with progress_bar() as progress:
        task = progress.add_task("leave-one-run-out", total=len(MODES) * len(monitors))
        for mode, (est, banded, cal) in MODES.items():
            for mon in monitors:
                s = score(*leave_one_run_out(runs[est], mon, est, banded, envelope_without if cal else None))
                report["leave_one_run_out"].setdefault(mon.name, {})[mode] = s
                progress.advance(task)
    if args.sim:
        envelope = Envelope(model).fit(recorded)
        entries = {mode: train(runs[est], config, est, banded, envelope if cal else None)
                   for mode, (est, banded, cal) in MODES.items()}
        report["simulated"] = simulated_scores(entries, model, args.spread, args.seed)
        if any(m.kind == "balance" for m in config.monitors):
            report["closed_loop"] = closed_loop_scores(entries, envelope.model_, args.spread, args.seed)

    table = Table(title="macro F1 / error recall", title_justify="left")
    table.add_column("test set")
    for mode in MODES:
        table.add_column(mode, justify="right")
    for name, by_mode in report["leave_one_run_out"].items():
        table.add_row(f"{name}, leave-one-run-out (recordings)", *(cell(by_mode[m]) for m in MODES))
    for name, by_mode in report.get("simulated", {}).items():
        table.add_row(name, *(cell(by_mode.get(m)) for m in MODES))
    for name, by_mode in report.get("closed_loop", {}).items():
        table.add_row(name, *(closed_cell(by_mode.get(m)) for m in MODES))
    console.print(table)
    if "closed_loop" in report:
        console.print("closed-loop rows: macro F1 / error recall, coverage, false-alarm runs, longest detection "
                      "delay (s); test monitors: warnings or errors before an onset")
    if args.json:
        Path(args.json).write_text(json.dumps(report, indent=1) + "\n")
    return 0


def closed_cell(s: dict) -> str:
    if not s:
        return "-"
    if "alarms_before_onset" in s:
        return f"{s['alarms_before_onset']} alarms"
    delay = s["max_detection_delay_s"]
    return (f"{s['macro_f1']:.3f} / {s['classes']['error']['recall']:.3f}, cov {s['coverage']:.2f}, "
            f"FA {s['false_alarm_runs']}, {'-' if delay is None else f'{delay:.0f}'}")


def closed_loop_scores(entries: dict, model, spread: float, seed: int) -> dict:
    """Every mode's entries on simulated closed-loop runs (faults switched on mid-run)."""
    import numpy as np

    from civic.continuous import FAULTS, closed_loop_runs
    from civic.evaluate import TimelineRun, closed_loop_summary
    from civic.pipeline import SwitchModel
    from civic.report import progress_bar

    with progress_bar() as progress:
        task = progress.add_task("closed-loop operation", total=CLOSED_LOOP_UNITS * 5)
        runs = closed_loop_runs(model, CLOSED_LOOP_UNITS, spread, seed + 1, progress=lambda: progress.advance(task))
    out: dict = {}
    for mode, ent in entries.items():
        per = {m.name: [] for m in ent.monitors}
        for i, run in enumerate(runs):
            _, traces = SwitchModel(ent).traces(run.msgs)
            t = run.msgs["t"] - run.msgs["t"][0]
            for mon, tr in zip(ent.monitors, traces):
                truth = run.truth(mon.name)
                cls = int(truth[-1]) if run.onset_s is not None else 1
                per[mon.name].append(TimelineRun(f"{i}:{run.fault}:{run.closure}", cls, run.onset_s, t, truth,
                                                 tr.code, tr.resid * mon.slope_scale))
        for mon in ent.monitors:
            name = f"{mon.name}, closed loop, {len(runs)} runs (units ±{spread:.0%})"
            if mon.kind == "balance" and mon.name in FAULTS:
                out.setdefault(name, {})[mode] = closed_loop_summary(per[mon.name])
            elif mon.kind != "balance":
                before = sum(int(np.sum((r.code > 1) & (r.t < (r.onset if r.onset is not None else np.inf))))
                             for r in per[mon.name])
                out.setdefault(name, {})[mode] = {"alarms_before_onset": before}
    return out


def simulated_scores(entries: dict, model, spread: float, seed: int) -> dict:
    """Score every mode's entries on simulated tests through the switch model."""
    import numpy as np

    from civic.evalsets import ENVELOPE_LEVELS, fleet, unit_tests
    from civic.evaluate import score
    from civic.pipeline import SwitchModel
    from civic.report import progress_bar

    sets = {f"drain_t3, drain from {v0:.1f} L (units ±{spread:.0%})": unit_tests(model, "drain", v0, SIM_RUNS,
                                                                                  spread, seed)
            for v0 in ENVELOPE_LEVELS}
    sets[f"fill_t1, fill tests (units ±{spread:.0%})"] = unit_tests(model, "fill", None, SIM_RUNS, spread, seed)
    sets[f"drain_t3, {FLEET_PLANTS} plants in one capture"] = [fleet(model, FLEET_PLANTS, spread, seed)]
    out: dict = {}
    with progress_bar() as progress:
        task = progress.add_task("simulated tests", total=len(sets) * len(entries))
        for name, tests in sets.items():
            for mode, ent in entries.items():
                names = [m.name for m in ent.monitors]
                true, pred = [], []
                for group in tests:
                    group = group if isinstance(group, list) else [group]
                    msgs = np.concatenate([t.msgs for t in group])
                    msgs = msgs[np.argsort(msgs["t"], kind="stable")]
                    _, traces = SwitchModel(ent).traces(msgs)
                    for t in group:
                        tr = traces[names.index(t.monitor)]
                        mine = (msgs["src"] == t.msgs["src"][0]) & tr.evaluated
                        true.append(np.full(int(mine.sum()), t.cls))
                        pred.append(tr.code[mine])
                out.setdefault(name, {})[mode] = score(np.concatenate(true), np.concatenate(pred))
                progress.advance(task)
    return out
