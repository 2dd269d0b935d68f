"""civic train: learn class tables from labelled recordings -> table entries JSON."""
from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

from civic.config import load_monitors
from civic.errors import CivicError

DEFAULT_ESTIMATOR = "lsq"   # least squares: less noise than newest - oldest
DEFAULT_BANDED = True       # level bands: boundaries that hold at any start level


def register(sub) -> None:
    p = sub.add_parser("train", help="learn class boundaries from labelled recordings")
    p.add_argument("training_dir", metavar="TRAINING_DIR", nargs="?",
                   help="labelled recordings (not with --from-model)")
    p.add_argument("-o", "--output", required=True, metavar="ENTRIES.json")
    p.add_argument("--labels", metavar="FILE", help="labels CSV (default: TRAINING_DIR/labels.csv)")
    p.add_argument("--monitors", metavar="FILE", help="monitors TOML (default: configs/monitors.toml)")
    p.add_argument("--estimator", choices=("endpoint", "lsq"), default=DEFAULT_ESTIMATOR)
    p.add_argument("--banded", action=argparse.BooleanOptionalAction, default=DEFAULT_BANDED,
                   help="2-D tables: slope ranges per level band (default: on)")
    p.add_argument("--from-model", action="store_true",
                   help="derive the tables from the plant model alone (simulated drain/fill tests)")
    p.add_argument("--model", metavar="FILE", help="plant model for --from-model (default: configs/plant.toml)")
    p.set_defaults(func=run)


def run(args) -> int:
    from civic.commands.simulate import default_model_path
    from civic.train import collect_runs, read_labels, train

    if args.from_model == bool(args.training_dir):
        raise CivicError("give either TRAINING_DIR or --from-model")
    config = load_monitors(args.monitors)
    with tempfile.TemporaryDirectory(prefix="civic-sim-") as tmp:
        if args.from_model:
            from civic.evalsets import simulate_set
            from civic.plant.model import PlantModel

            model = PlantModel.from_toml(args.model or default_model_path())
            folder = Path(tmp)
            labels = read_labels(simulate_set(folder, model, runs=3))
        else:
            folder = Path(args.training_dir)
            if not folder.is_dir():
                raise CivicError(f"{folder}: not a directory")
            labels = read_labels(args.labels or folder / "labels.csv")
        runs = collect_runs(folder, labels, config, args.estimator)
    entries = train(runs, config, args.estimator, args.banded)
    if args.from_model:
        entries.training["source"] = f"model {args.model or default_model_path()}"
    entries.save(args.output)
    n = sum(len(m.classes) for m in entries.monitors)
    mode = f"{args.estimator}, {'banded' if args.banded else '1-D'}"
    print(f"trained {len(entries.monitors)} monitors ({mode}) on {len(runs)} runs: "
          f"{n} table entries -> {args.output}")
    return 0
