"""Scores as the CIVIC paper reports them: per class precision, recall, F1, accuracy.

Only evaluated messages (verdict code != 0) are scored; coverage says how many
of the messages whose full window qualified got a verdict, and the detection
delay is the time from the first qualifying message of a run to its first
correct verdict.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import NamedTuple

import numpy as np

from civic.config import MonitorConfig
from civic.entries import Entries, probe_entries
from civic.errors import CivicError
from civic.pipeline import SwitchModel
from civic.wire import CLASS_CODES, CLASS_NAMES, ip_to_int, monitor_verdict, read_pcap

CLASSES = (1, 2, 3)


def score(true: np.ndarray, pred: np.ndarray) -> dict:
    """Per-class one-vs-rest precision/recall/F1/accuracy, macro F1 and the confusion matrix."""
    true, pred = np.asarray(true), np.asarray(pred)
    out = {"classes": {}, "n": int(len(true))}
    f1s = []
    for c in CLASSES:
        tp = int(np.sum((pred == c) & (true == c)))
        fp = int(np.sum((pred == c) & (true != c)))
        fn = int(np.sum((pred != c) & (true == c)))
        tn = len(true) - tp - fp - fn
        prec = tp / (tp + fp) if tp + fp else 0.0
        rec = tp / (tp + fn) if tp + fn else 0.0
        f1 = 2 * prec * rec / (prec + rec) if prec + rec else 0.0
        support = tp + fn
        out["classes"][CLASS_NAMES[c]] = {"precision": prec, "recall": rec, "f1": f1,
                                    "accuracy": (tp + tn) / len(true) if len(true) else 0.0,
                                    "support": support}
        if support:
            f1s.append(f1)
    out["macro_f1"] = float(np.mean(f1s)) if f1s else 0.0
    out["accuracy"] = float(np.mean(true == pred)) if len(true) else 0.0
    out["confusion"] = [[int(np.sum((true == a) & (pred == b))) for b in CLASSES] for a in CLASSES]
    return out


class ScoredRun(NamedTuple):
    """One labelled run as the monitor saw it (arrays over its plant messages)."""

    label: str
    cls: int
    t: np.ndarray         # s from the run's first message
    slope: np.ndarray     # mL/s
    level: np.ndarray     # mL
    code: np.ndarray      # verdict code of this monitor
    resid: np.ndarray     # mL/s: the slope the class table sees (minus the compensated inflow)


@dataclass
class MonitorResult:
    name: str
    true: list = field(default_factory=list)      # per evaluated message
    pred: list = field(default_factory=list)
    qualified: int = 0                            # messages whose full window qualified
    delays: dict = field(default_factory=lambda: {c: [] for c in CLASSES})
    runs: list[ScoredRun] = field(default_factory=list)

    def summary(self) -> dict:
        true = np.concatenate(self.true) if self.true else np.zeros(0, int)
        pred = np.concatenate(self.pred) if self.pred else np.zeros(0, int)
        s = score(true, pred)
        s["coverage"] = len(true) / self.qualified if self.qualified else 0.0
        s["detection_delay_s"] = {CLASS_NAMES[c]: (float(np.mean(d)) if d else None) for c, d in self.delays.items()}
        s["undetected_runs"] = sum(1 for r in self.runs if not np.any(r.code == r.cls))
        return s


def find_output(out: Path, name: str, single: bool) -> Path | None:
    if out.is_dir():
        p = out / name
        return p if p.exists() else None
    return out if single or out.name == name else None


class Labelled(NamedTuple):
    """One label row as the switch model saw its recording: the row, the plant messages it is about
    (their indices in the capture), the verdict code given there and what the monitor computed."""

    row: dict
    n: int                # the row's number in labels.csv (header = 1)
    msgs: np.ndarray      # the whole capture
    rows: np.ndarray      # indices of the row's plant messages in msgs
    code: np.ndarray      # this monitor's verdict code on them
    trace: object         # MonitorTrace of the whole capture (sel picks the row's plant)
    sel: np.ndarray       # the row's plant among the capture's plant messages


def labelled(out: str | Path, labels: list[dict], config: MonitorConfig | Entries):
    """Every label row whose recording is in `out` (a file or a folder), replayed through the switch
    model once per recording (for what the monitors computed) next to the verdicts found there."""
    out = Path(out)
    if not out.exists():
        raise CivicError(f"{out}: no such file or directory")
    single = out.is_file() and len({r["file"] for r in labels}) == 1
    names = [m.name for m in config.monitors]
    probe = config if isinstance(config, Entries) else probe_entries(config, "lsq")
    cache = {}
    matched = 0
    for i, row in enumerate(labels):
        path = find_output(out, row["file"], single)
        if path is None:
            continue
        if row["monitor"] not in names:
            raise CivicError(f"labels: monitor {row['monitor']!r} is not configured ({', '.join(names)})")
        matched += 1
        if path not in cache:
            cap = read_pcap(path, config.udp_port, config.plant_prefix)
            cache[path] = (cap.messages, *SwitchModel(probe).traces(cap.messages))
        msgs, idx, traces = cache[path]
        m = names.index(row["monitor"])
        sel = np.ones(len(idx), bool)
        if row.get("src_ip"):
            sel &= msgs["src"][idx] == ip_to_int(row["src_ip"])
        yield Labelled(row, i + 2, msgs, idx[sel], monitor_verdict(msgs["verdict"][idx][sel], m).astype(int),
                       traces[m], sel)
    if matched == 0:
        raise CivicError(f"{out}: none of the labelled recordings found there")


def evaluate(out: str | Path, labels: list[dict], config: MonitorConfig | Entries) -> dict[str, MonitorResult]:
    """Score the verdicts in replayed recordings (a file or a folder) against labels."""
    results = {m.name: MonitorResult(m.name) for m in config.monitors}
    for lab in labelled(out, labels, config):
        row, code, tr, sel = lab.row, lab.code, lab.trace, lab.sel
        cls = CLASS_CODES[row["class"]]
        ev = code != 0
        res = results[row["monitor"]]
        res.true.append(np.full(int(ev.sum()), cls))
        res.pred.append(code[ev])
        res.qualified += int(tr.evaluated[sel].sum())
        t = lab.msgs["t"][lab.rows]
        start = np.flatnonzero(tr.run[sel] == 1)
        hit = np.flatnonzero(code == cls)
        if len(start) and len(hit):
            res.delays[cls].append(float(t[hit[0]] - t[start[0]]))
        res.runs.append(ScoredRun(f"{row['file']} {row.get('src_ip', '')}".strip(), cls, t - t[0] if len(t) else t,
                                  tr.slope[sel] * tr.monitor.slope_scale, tr.level[sel], code,
                                  tr.resid[sel] * tr.monitor.slope_scale))
    return results


def plot_monitor(res: MonitorResult, path: Path, entries_monitor=None) -> None:
    """Slope over time per run (coloured by true class) and, with entries, the decision the switch
    makes: its compensate table (expected inflow against aux) when it has one, and its class regions
    over (compensated slope, level)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    colors = {1: "tab:green", 2: "tab:orange", 3: "tab:red"}
    compensated = entries_monitor is not None and len(entries_monitor.offsets) > 0
    fig, axes = plt.subplots(1, 3 if compensated else 2, figsize=(19 if compensated else 13, 5))
    ax = axes[0]
    for run in res.runs:
        ev = run.code != 0
        ax.plot(run.t[ev], run.slope[ev], ".", ms=2, color=colors[run.cls], alpha=0.6)
    if entries_monitor is not None and not compensated and len(np.unique(entries_monitor.classes[:, 2])) == 1:
        # a 1-D table: its slope ranges are horizontal bands over time
        lo_y, hi_y = ax.get_ylim()
        for lo, hi, _, _, c in entries_monitor.classes:
            y0, y1 = max(lo * entries_monitor.slope_scale, lo_y), min(hi * entries_monitor.slope_scale, hi_y)
            if y1 > y0:
                ax.axhspan(y0, y1, color=colors[int(c)], alpha=0.15, lw=0)
        ax.set_ylim(lo_y, hi_y)
    ax.set(title=f"{res.name}: window slope of evaluated messages", xlabel="time in recording (s)",
           ylabel="slope (mL/s)")
    ax.legend(handles=[plt.Line2D([], [], marker="o", ls="", color=c, label=CLASS_NAMES[k]) for k, c in colors.items()],
              title="true class")
    if compensated:
        ax = axes[1]
        plus, minus = entries_monitor.compensate
        rows = entries_monitor.offsets
        top = min(int(rows[-1, 0]) + 1000, 0xFFFF)
        edges = np.concatenate([[r[0], min(r[1], top) + 1] for r in rows])
        values = np.repeat(rows[:, 2] * entries_monitor.slope_scale, 2)
        ax.plot(edges, values, color="k", lw=1)
        ax.set(title=f"compensate table: expected inflow vs aux = {plus} - {minus}",
               xlabel=f"aux = max({plus} - {minus}, 0) (mL)", ylabel="offset (mL/s)", xlim=(0, top))
    ax = axes[-1]
    if entries_monitor is not None and len(entries_monitor.classes):
        scale = entries_monitor.slope_scale
        lv = np.concatenate([r.level[r.code != 0] for r in res.runs])
        sv = np.concatenate([r.resid[r.code != 0] for r in res.runs])
        lmin, lmax = (lv.min() - 500, lv.max() + 500) if len(lv) else (0, 10000)
        smin, smax = (sv.min() * 1.3, sv.max() * 1.3) if len(sv) else (-1, 1)
        smin, smax = min(smin, smax, 0), max(smin, smax, 0)
        for lo, hi, llo, lhi, c in entries_monitor.classes:
            x0, x1 = max(llo, lmin), min(lhi, lmax)
            y0, y1 = max(lo * scale, smin), min(hi * scale, smax)
            if x1 > x0 and y1 > y0:
                ax.add_patch(plt.Rectangle((x0, y0), x1 - x0, y1 - y0, color=colors[int(c)], alpha=0.15, lw=0))
        ax.set_xlim(lmin, lmax)
        ax.set_ylim(smin, smax)
    for run in res.runs:
        ev = run.code != 0
        ax.plot(run.level[ev], run.resid[ev], ".", ms=2, color=colors[run.cls], alpha=0.6)
    what = "slope - expected inflow" if compensated else "slope"
    ax.set(title=f"{what} vs level with the class table (shaded)", xlabel="level (mL)", ylabel=f"{what} (mL/s)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


# ------------------------------------------------------------------ closed-loop operation (issue: continuous)
SETTLE_S = 60.0          # the minute after an onset is not scored
DETECT_HOLD_S = 10.0     # a fault counts as detected once the correct class held this long


@dataclass
class TimelineRun:
    """One monitor over one closed-loop run: per plant message time, expected and given class."""

    label: str
    cls: int                       # the class from onset + SETTLE_S on (normal for a fault-free run)
    onset: float | None            # s from the run's first message; None: fault-free
    t: np.ndarray                  # s from the run's first message
    truth: np.ndarray              # expected class, 0 where not scored
    code: np.ndarray               # the verdict
    resid: np.ndarray              # mL/s: what the class table sees
    levels: np.ndarray | None = None   # (n, 4) mL, for the timeline plot


def expected_classes(t: np.ndarray, cls: int, onset: float | None) -> np.ndarray:
    """normal before the onset, `cls` from onset + SETTLE_S on, 0 (not scored) in between."""
    out = np.full(len(t), CLASS_CODES["normal"])
    if onset is not None:
        out[(t >= onset) & (t < onset + SETTLE_S)] = 0
        out[t >= onset + SETTLE_S] = cls
    return out


def detection_delay(t: np.ndarray, code: np.ndarray, cls: int, onset: float) -> float | None:
    """Seconds from the onset until the monitor's current class (its last verdict) has been `cls`
    for DETECT_HOLD_S; None if that never happens."""
    given = np.flatnonzero(code != 0)
    if not len(given):
        return None
    last = np.zeros(len(code), np.int64)
    last[given] = given
    current = code[np.maximum.accumulate(last)]
    current[: given[0]] = 0
    ok = (current == cls) & (t >= onset)
    starts = np.flatnonzero(ok & ~np.concatenate(([False], ok[:-1])))
    ends = np.flatnonzero(ok & ~np.concatenate((ok[1:], [False])))
    for s, e in zip(starts, ends):
        if t[e] - t[s] >= DETECT_HOLD_S:
            return float(t[s] + DETECT_HOLD_S - onset)
    return None


def closed_loop_summary(runs: list[TimelineRun], dt: float = 0.1) -> dict:
    """The paper's table on the scored messages with a verdict, error recall, coverage (scored
    messages with a verdict), false-alarm runs and verdict-minutes (warning/error where normal
    is expected), detection delays, undetected faults."""
    scored = [r.truth > 0 for r in runs]
    given = [s & (r.code > 0) for s, r in zip(scored, runs)]
    true = np.concatenate([r.truth[g] for r, g in zip(runs, given)]) if runs else np.zeros(0, int)
    pred = np.concatenate([r.code[g] for r, g in zip(runs, given)]) if runs else np.zeros(0, int)
    s = score(true, pred)
    n_scored = sum(int(x.sum()) for x in scored)
    s["coverage"] = float(sum(int(g.sum()) for g in given) / n_scored) if n_scored else 0.0
    alarms = [int(np.sum((r.truth == 1) & (r.code > 1))) for r in runs]
    s["false_alarm_runs"] = sum(1 for a in alarms if a)
    s["false_alarm_verdict_minutes"] = sum(alarms) * dt / 60.0
    delays = {r.label: detection_delay(r.t, r.code, r.cls, r.onset) for r in runs
              if r.onset is not None and r.cls != CLASS_CODES["normal"]}
    s["detection_delay_s"] = delays
    found = [d for d in delays.values() if d is not None]
    s["max_detection_delay_s"] = max(found) if found else None
    s["undetected_runs"] = sum(1 for d in delays.values() if d is None)
    s["runs"] = len(runs)
    return s


def evaluate_closed_loop(out: str | Path, labels: list[dict], config: MonitorConfig | Entries
                         ) -> dict[str, list[TimelineRun]]:
    """Per monitor, every labelled closed-loop run (labels with an onset_s column) as it saw it."""
    results: dict[str, list[TimelineRun]] = {m.name: [] for m in config.monitors}
    for lab in labelled(out, labels, config):
        row, msgs, rows = lab.row, lab.msgs, lab.rows
        try:
            onset = float(row["onset_s"]) if (row.get("onset_s") or "").strip() else None
        except ValueError:
            raise CivicError(f"labels: row {lab.n}: onset_s {row['onset_s']!r} is not a number") from None
        t = msgs["t"][rows] - (msgs["t"][rows][0] if len(rows) else 0.0)
        cls = CLASS_CODES[row["class"]]
        results[row["monitor"]].append(TimelineRun(
            f"{row['file']} {row.get('src_ip', '')}".strip(), cls, onset, t, expected_classes(t, cls, onset),
            lab.code, lab.trace.resid[lab.sel] * lab.trace.monitor.slope_scale,
            np.stack([msgs[k][rows] for k in ("l1", "l2", "l3", "l4")], axis=1)))
    return results


def plot_timeline(label: str, runs: dict[str, TimelineRun], path: Path) -> None:
    """One closed-loop run: levels, each labelled monitor's residual and verdict over time."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    colors = {0: "0.85", 1: "tab:green", 2: "tab:orange", 3: "tab:red"}
    fig, axes = plt.subplots(1 + 2 * len(runs), 1, figsize=(13, 2.2 + 2.2 * 2 * len(runs)), sharex=True)
    first = next(iter(runs.values()))
    for j, name in enumerate(("L1", "L2", "L3")):
        axes[0].plot(first.t, first.levels[:, j] / 1000.0, lw=0.7, label=name)
    axes[0].set(ylabel="volume (L)", title=label)
    axes[0].legend(loc="upper right", ncols=3)
    for k, (mon, r) in enumerate(runs.items()):
        ax_r, ax_v = axes[1 + 2 * k], axes[2 + 2 * k]
        ev = r.code != 0
        ax_r.plot(r.t, np.where(ev, r.resid, np.nan), lw=0.6, color="k")
        ax_r.set(ylabel=f"{mon}\nresidual (mL/s)")
        ax_v.scatter(r.t, r.code, c=[colors[int(c)] for c in r.code], s=2)
        ax_v.plot(r.t, r.truth, lw=1, color="tab:blue", alpha=0.5, label="expected (0: not scored)")
        ax_v.set(ylabel=f"{mon}\nverdict", yticks=[0, 1, 2, 3], yticklabels=["-", "normal", "warning", "error"])
        ax_v.legend(loc="upper left")
        if r.onset is not None:
            for ax in (axes[0], ax_r, ax_v):
                ax.axvline(r.onset, color="tab:red", lw=0.8, ls="--")
    axes[-1].set(xlabel="time in recording (s)")
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)
