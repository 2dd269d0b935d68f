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
    if args.json:
        Path(args.json).write_text(json.dumps(report, indent=1) + "\n")
    return 0
