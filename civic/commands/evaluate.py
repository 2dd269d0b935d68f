"""civic evaluate: score replayed verdicts against labels (the paper's tables) + plots."""
from __future__ import annotations

import json
from pathlib import Path


def register(sub) -> None:
    p = sub.add_parser("evaluate", help="score verdicts in replayed recordings against labels")
    p.add_argument("out", metavar="OUT", help="a replayed pcap or a folder of them")
    p.add_argument("--labels", required=True, metavar="labels.csv")
    p.add_argument("--json", metavar="FILE", help="write the scores as JSON")
    p.add_argument("--entries", metavar="ENTRIES.json",
                   help="the entries replayed with (monitor order, estimator, class regions in plots)")
    p.add_argument("--monitors", metavar="FILE", help="monitors TOML when no --entries (default: configs/monitors.toml)")
    p.add_argument("--plot-dir", metavar="DIR", help="where evaluate_<monitor>.png go (default: beside --json, else OUT)")
    p.set_defaults(func=run)


def run(args) -> int:
    from civic.config import load_monitors
    from civic.entries import load_entries
    from civic.evaluate import evaluate, plot_monitor
    from civic.report import console, score_table
    from civic.train import read_labels

    labels = read_labels(args.labels)
    config = load_entries(args.entries) if args.entries else load_monitors(args.monitors)
    results = evaluate(args.out, labels, config)
    out = Path(args.out)
    plot_dir = Path(args.plot_dir) if args.plot_dir else (
        Path(args.json).parent if args.json else (out if out.is_dir() else out.parent))
    plot_dir.mkdir(parents=True, exist_ok=True)
    report = {"monitors": {}}
    for mon in config.monitors:
        res = results[mon.name]
        if not res.runs:
            continue
        s = res.summary()
        png = plot_dir / f"evaluate_{mon.name}.png"
        plot_monitor(res, png, mon if args.entries else None)
        s["plot"] = str(png)
        report["monitors"][mon.name] = s
        console.print(score_table(f"{mon.name}", s))
        delay = ", ".join(f"{k} {v:.1f} s" for k, v in s["detection_delay_s"].items() if v is not None)
        console.print(f"coverage {s['coverage']:.3f}   detection delay: {delay or 'n/a'}   "
                      f"undetected runs: {s['undetected_runs']}   plot: {png}\n")
    if args.json:
        Path(args.json).write_text(json.dumps(report, indent=1) + "\n")
    return 0
