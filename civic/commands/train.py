"""civic train: learn class tables from labelled recordings -> table entries JSON."""
from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

from civic.config import load_monitors
from civic.errors import CivicError

DEFAULT_ESTIMATOR = "lsq"   # least squares: less noise than newest - oldest
DEFAULT_BANDED = True       # level bands: boundaries that hold at any start level
DEFAULT_CALIBRATE = True    # compensated tables over the model's operating envelope (civic/envelope.py)


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
    p.add_argument("--calibrate", action=argparse.BooleanOptionalAction, default=DEFAULT_CALIBRATE,
                   help="calibrate the plant model to the recordings, compensate the inflow a monitor's "
                        "`compensate` names and train over start levels 4.5-10 L on units spread +-3%% "
                        "(default: on; --no-calibrate: the recordings alone, uncompensated)")
    p.add_argument("--from-model", action="store_true",
                   help="derive the tables from the plant model alone (simulated drain/fill tests)")
    p.add_argument("--model", metavar="FILE",
                   help="plant model for --calibrate and --from-model (default: configs/plant.toml)")
    p.set_defaults(func=run)


def run(args) -> int:
    from civic.commands.simulate import default_model_path
    from civic.envelope import Envelope, load_recorded
    from civic.plant.model import PlantModel
    from civic.train import collect_runs, read_labels, train

    if args.from_model == bool(args.training_dir):
        raise CivicError("give either TRAINING_DIR or --from-model")
    config = load_monitors(args.monitors)
    with tempfile.TemporaryDirectory(prefix="civic-sim-") as tmp:
        model = PlantModel.from_toml(args.model or default_model_path())
        if args.from_model:
            from civic.evalsets import simulate_set

            folder = Path(tmp)
            labels = read_labels(simulate_set(folder, model, runs=3))
        else:
            folder = Path(args.training_dir)
            if not folder.is_dir():
                raise CivicError(f"{folder}: not a directory")
            labels = read_labels(args.labels or folder / "labels.csv")
        runs = collect_runs(folder, labels, config, args.estimator)
        envelope = None
        if args.calibrate:
            recorded = [] if args.from_model else load_recorded(folder, labels, config.udp_port, config.plant_prefix)
            envelope = Envelope(model).fit(recorded)
    from civic.report import progress_bar

    with progress_bar() as bar:
        task = bar.add_task("simulating closed-loop operation", total=None)
        entries = train(runs, config, args.estimator, args.banded, envelope, model=model,
                        progress=lambda: bar.advance(task))
    if args.from_model:
        entries.training["source"] = f"model {args.model or default_model_path()}"
    entries.save(args.output)
    n = sum(len(m.classes) for m in entries.monitors)
    mode = f"{args.estimator}, {'banded' if args.banded else '1-D'}{', calibrated' if args.calibrate else ''}"
    print(f"trained {len(entries.monitors)} monitors ({mode}) on {len(runs)} runs: "
          f"{n} table entries -> {args.output}")
    return 0
