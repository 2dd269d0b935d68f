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
    out = Path(args.out)
    plot_dir = Path(args.plot_dir) if args.plot_dir else (
        Path(args.json).parent if args.json else (out if out.is_dir() else out.parent))
    if "onset_s" in labels[0]:
        return run_closed_loop(args, labels, config, plot_dir)
    results = evaluate(args.out, labels, config)
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


def run_closed_loop(args, labels, config, plot_dir: Path) -> int:
    """Closed-loop labels (one row per run and monitor, with onset_s): scores over time, a timeline per run."""
    from civic.evaluate import closed_loop_summary, evaluate_closed_loop, plot_timeline
    from civic.report import console, score_table

    results = evaluate_closed_loop(args.out, labels, config)
    plot_dir.mkdir(parents=True, exist_ok=True)
    report = {"monitors": {}, "timelines": {}}
    for name, runs in results.items():
        if not runs:
            continue
        s = closed_loop_summary(runs)
        report["monitors"][name] = s
        console.print(score_table(f"{name} (closed loop, {len(runs)} runs)", s))
        delay = s["max_detection_delay_s"]
        console.print(f"error recall {s['classes']['error']['recall']:.3f}   coverage {s['coverage']:.3f}   "
                      f"false-alarm runs {s['false_alarm_runs']} ({s['false_alarm_verdict_minutes']:.2f} "
                      f"verdict-min)   detection delay max {'n/a' if delay is None else f'{delay:.1f} s'}   "
                      f"undetected {s['undetected_runs']}\n")
    by_run: dict[str, dict] = {}
    for name, runs in results.items():
        for r in runs:
            by_run.setdefault(r.label, {})[name] = r
    for label, runs in by_run.items():
        png = plot_dir / f"timeline_{Path(label.split()[0]).stem}{'_' + label.split()[1] if ' ' in label else ''}.png"
        plot_timeline(label, runs, png)
        report["timelines"][label] = str(png)
    console.print(f"timelines: {len(by_run)} PNG in {plot_dir}")
    if args.json:
        Path(args.json).write_text(json.dumps(report, indent=1) + "\n")
    return 0
