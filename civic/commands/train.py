"""civic train: learn class tables from labelled recordings -> table entries JSON."""
from __future__ import annotations

import argparse
from pathlib import Path

from civic.config import load_monitors
from civic.errors import CivicError

DEFAULT_ESTIMATOR = "lsq"   # least squares: less noise than newest - oldest
DEFAULT_BANDED = True       # level bands: boundaries that hold at any start level


def register(sub) -> None:
    p = sub.add_parser("train", help="learn class boundaries from labelled recordings")
    p.add_argument("training_dir", metavar="TRAINING_DIR")
    p.add_argument("-o", "--output", required=True, metavar="ENTRIES.json")
    p.add_argument("--labels", metavar="FILE", help="labels CSV (default: TRAINING_DIR/labels.csv)")
    p.add_argument("--monitors", metavar="FILE", help="monitors TOML (default: configs/monitors.toml)")
    p.add_argument("--estimator", choices=("endpoint", "lsq"), default=DEFAULT_ESTIMATOR)
    p.add_argument("--banded", action=argparse.BooleanOptionalAction, default=DEFAULT_BANDED,
                   help="2-D tables: slope ranges per level band (default: on)")
    p.set_defaults(func=run)


def run(args) -> int:
    from civic.train import collect_runs, read_labels, train

    folder = Path(args.training_dir)
    if not folder.is_dir():
        raise CivicError(f"{folder}: not a directory")
    labels = read_labels(args.labels or folder / "labels.csv")
    config = load_monitors(args.monitors)
    runs = collect_runs(folder, labels, config, args.estimator)
    entries = train(runs, config, args.estimator, args.banded)
    entries.save(args.output)
    n = sum(len(m.classes) for m in entries.monitors)
    mode = f"{args.estimator}, {'banded' if args.banded else '1-D'}"
    print(f"trained {len(entries.monitors)} monitors ({mode}) on {len(runs)} runs: "
          f"{n} table entries -> {args.output}")
    return 0
