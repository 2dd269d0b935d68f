"""Diagnosis report: JSON contract, rich summary table, plot.

JSON (keys required by the contract, others informative):
{"mismatch": bool,
 "findings": [{"mechanism", "component", "parameters", "intervals", "evidence", ...}],
 "fit": {"before": {"rmse": {signal: float}}, "after": {"rmse": {signal: float}}, ...}}
Times are seconds from the first message/sample.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
from scipy.ndimage import uniform_filter1d

from civic.errors import CivicError
from civic.plant.figures import save_figure
from civic.plant.model import PlantModel
from civic.plant.simulate import Recording, initial_state, simulate

from .compare import INVENTORY, EquationError, SimulationError, rmse
from .forward import BOTH_ORDERS
from .problem import Diagnosis
from .locate import mask_intervals, median_nonzero, merge
from .mechanisms.base import Mechanism

SHORT_HORIZON_S = 30.0


def _sim_free(model: PlantModel, rec: Recording, n_init: int) -> dict:
    n = len(rec.t)
    t = np.arange(n) * model.dt
    inputs = {k: np.asarray(rec.signals[k], float) for k in model.input_names}
    x0 = initial_state(model, rec.signals, n_init)
    return simulate(model, t, inputs, x0)


def simulation_rmse(model: PlantModel, rec: Recording, n_init: int = 1, skip: int = 0) -> tuple[dict, dict]:
    """Open-loop simulation driven by the recorded inputs: RMSE per measured signal (after `skip`)."""
    sim = _sim_free(model, rec, n_init)
    out = {}
    for s in model.signal_names:
        if s in rec.signals:
            out[s] = round(rmse(sim[s][skip:], np.asarray(rec.signals[s], float)[skip:]), 6)
    return out, sim


def short_horizon_rmse(model: PlantModel, rec: Recording, horizon_s: float = SHORT_HORIZON_S) -> dict:
    eng = SimulationError(model, rec, horizon_s=horizon_s)
    return {k: round(v, 6) for k, v in eng.rmse(model).items()}


def _mask_intervals(mask: np.ndarray, t: np.ndarray, dt: float, gap: float) -> list[list[float]]:
    return mask_intervals(mask, t, t + dt, gap=gap)


def _finding_intervals(diag: Diagnosis, prev, res, mech=None) -> list[list[float]]:
    """Where the finding acts: for a spill or a clipped sensor, where it is physically active
    (tank at its rim in the fitted model's simulation, sensor at its clip value); otherwise
    the rows whose residual it reduces well beyond noise."""
    eng = diag.engine
    model = diag.model_nominal
    t = np.arange(len(diag.engine.rec.t)) * model.dt
    gap = 0.01 * float(t[-1] - t[0] + model.dt)
    fitted = res.mechanisms[-1]
    p = fitted.values()
    acting = fitted.acting_at(t)
    if acting is not None:
        return _mask_intervals(acting, t, model.dt, gap)
    if fitted.name == "sensor_saturation":
        y = np.asarray(eng.rec.signals[fitted.component], float)
        return _mask_intervals(y >= p["max"] - 1e-9, t, model.dt, gap)
    if fitted.name == "overflow" and isinstance(eng, SimulationError):
        eng.x0_extra = dict(res.x0_extra)
        vol = eng.simulate(res.model)["volumes"]
        return _mask_intervals(fitted.active_rows(res.model, vol), t, model.dt, gap)
    if fitted.name == "overflow":
        # every tank is measured: where its measured volume reaches the rim or crest
        vol, _ = eng.volumes(res.model)
        at = eng.reaching(res.model, vol, res.model.tank_names.index(fitted.component), fitted.onset_volume(res.model))
        return _mask_intervals(at, t, model.dt, gap)
    prob_sigma = diag.sigma
    Rp = _resid(diag, prev) / prob_sigma
    Ra = _resid(diag, res) / prob_sigma
    # improvement of the squared weighted residual per row (~0 where the finding changes nothing)
    d = np.sum(Rp ** 2 - Ra ** 2, axis=1)
    smooth = 3 if isinstance(eng, EquationError) else 25
    s = uniform_filter1d(d, smooth, mode="nearest")
    span = float(eng.row_times[-1, 1] - eng.row_times[0, 0])
    return mask_intervals(s > 2.0, eng.row_times[:, 0], eng.row_times[:, 1], gap=0.03 * span)


def _resid(diag: Diagnosis, res) -> np.ndarray:
    eng = diag.engine
    if isinstance(eng, SimulationError):
        eng.x0_extra = dict(res.x0_extra)
    return eng.residuals(res.model)


def _mean_rate(diag: Diagnosis, tank: str, R: np.ndarray) -> tuple[float, float]:
    """Mean mass-balance residual of a tank (L/s) and its z-score in the equation-error
    residuals R, for the evidence text."""
    eng = diag.engine
    j = eng.columns.index(tank)
    r = R[:, j]
    rate = float(np.mean(r)) / (eng.W * eng.dt)
    z = float(np.mean(r) / (diag.sigma[j] / math.sqrt(len(r))))
    return rate, z


def build_report(diag: Diagnosis, rec: Recording, n_init: int = 1, skip: int = 0) -> dict:
    model = diag.model_nominal
    eng = diag.engine
    findings = []
    judged = {r["finding"]: r["judged_by_folds"] for r in diag.ablation.get("without", [])}
    for i, f in enumerate(diag.findings):
        mech = f["mechanism"]
        fitted = diag.final_all.mechanisms[i] if diag.final_all else f["fit"].mechanisms[-1]
        params = fitted.report_parameters()
        for k in ("base",):
            params.pop(k, None)
        intervals = _finding_intervals(diag, f["prev"], f["fit"], mech)
        ev = [f"held-out {eng.kind} error: BIC {f['dbic']:+.1f}, weighted SSE {-100 * f['gain']:+.0f} % "
              f"vs the calibrated model without it"]
        if f.get("held_out") == BOTH_ORDERS:
            ev[0] += (f" ({f['held_out']}: one order's held-out blocks did not find it significant, so the model "
                      "with and without it were fitted on each order's training blocks and judged on the other's, pooled)")
        elif f.get("held_out"):
            ev[0] += (f" ({f['held_out']}: it acts in the training blocks only, so the model with and "
                      "without it were refitted on the held-out blocks and judged on the training ones)")
        if f.get("both_orders"):
            ev.append("chosen on both block orders among its variants, the candidates one order did not "
                      "separate and those that fit the training blocks best (pooled held-out BIC vs the model "
                      "without: "
                      + ", ".join(f"{v['candidate']} {v['dbic']:+.1f}" for v in f["both_orders"]) + ")")
        if f.get("what_follows"):
            w = f["what_follows"]
            ev.append(f"both block orders did not separate it from {w['other']}: chosen by what follows, the "
                      f"selection after it ending {-w['dbic']:.1f} lower in held-out BIC than after "
                      + (", ".join(w["other_findings"]) or "the other"))
        if isinstance(eng, EquationError):
            Rp = _resid(diag, f["prev"])            # the model without this finding
            tanks = [mech.component] if mech.component in eng.columns else []
            if mech.name == "leak" and params.get("to") in eng.columns:
                tanks.append(params["to"])
            for t in tanks:
                rate, z = _mean_rate(diag, t, Rp)
                if math.isfinite(rate):
                    ev.append(f"{t} mass balance: {rate:+.4f} L/s unexplained on average (z = {z:+.1f})")
            if INVENTORY in eng.columns:
                j = eng.columns.index(INVENTORY)
                before = median_nonzero(Rp[:, j])
                after = median_nonzero(_resid(diag, f["fit"])[:, j])
                if abs(before) > diag.sigma[j]:
                    ev.append(f"the measured volumes add up to {before:+.3f} L off the {model.total_volume:g} L "
                              f"the circuit holds (less what the model lets out); with it: {after:+.3f} L")
            if mech.name == "leak":
                ev.append("concealed in closed loop: levels track their setpoints, but the actuators "
                          "work against a loss the model does not have (mass balance of "
                          f"{mech.component} with the recorded commands)")
        if f.get("replay"):
            ev.append("every mass balance closes within its noise, but the calibrated model replayed open loop "
                      "departs from the recording (RMS over noise: "
                      + ", ".join(f"{k} {v:.2f}" for k, v in f["replay"].items()) + "): judged on the replay")
        if isinstance(eng, SimulationError):
            ev += diag.loc.regimes
            if intervals:
                ev.append("active " + ", ".join(f"{a:g}-{b:g} s" for a, b in intervals[:4]))
            if judged.get(mech.label) == []:
                ev.append("kept unjudged: no fold of the cross-validation sees it act in both its training "
                          "and held-out rows with its held-out readings within those of its training")
        else:
            ev += [r for r in diag.loc.regimes if r.split(":")[0] in (mech.component, params.get("to"))]
            if mech.component in diag.loc.pinned:
                ev.append(f"the calibration alone pinned {mech.component}'s coefficient at the datasheet "
                          "spread's edge")
        description = fitted.describe(fitted.values()) if fitted.params or fitted.fixed else ""
        ev.append(description)
        findings.append({
            "mechanism": mech.name,
            "component": mech.component,
            "parameters": params,
            "description": description,
            "intervals": [[round(a, 2), round(b, 2)] for a, b in intervals],
            "evidence": "; ".join(e for e in ev if e),
            "heldout_dbic": round(f["dbic"], 2),
            "heldout_sse_reduction": round(f["gain"], 4),
        })
        if f.get("held_out"):
            findings[-1]["heldout_split"] = "both" if f["held_out"] == BOTH_ORDERS else "swapped"
        if f.get("both_orders"):
            # the pooled evidence the choice was made on, next to the single order's
            findings[-1]["heldout_dbic_both_orders"] = round(f["dbic_both_orders"], 2)
            findings[-1]["variants_both_orders"] = [{"candidate": v["candidate"], "heldout_dbic": round(v["dbic"], 2)}
                                                    for v in f["both_orders"]]
        if f.get("what_follows"):
            # a near-tie decided by the rounds after it: the path not taken and how much worse it ended
            w = f["what_follows"]
            findings[-1]["what_follows"] = {"other": w["other"], "other_findings": w["other_findings"],
                                            "heldout_bic_vs_other": round(w["dbic"], 2)}
        if "heldout_rmse_without" in f:
            findings[-1]["heldout_rmse_without"] = round(f["heldout_rmse_without"], 6)
        findings[-1]["heldout_error"] = _heldout_error(f["fit"])
        findings[-1]["alternatives"] = _alternatives_report(diag, f)
        unc = diag.uncertainty[i] if i < len(diag.uncertainty) else None
        if unc:
            findings[-1]["uncertainty"] = {
                "method": unc["method"],
                "stderr": {k: round(v, 6) for k, v in unc["stderr"].items()},
                "blocks": [{k: round(float(v), 6) for k, v in b.items()} for b in unc["blocks"]]}
            if unc.get("unit_of_volume"):
                # the data fix every reading, not this parameter: with it the volume unit moves
                findings[-1]["uncertainty"]["not_identifiable"] = {
                    k: "sets the rig's unit of volume (the coefficients and volumes scale with it)"
                    for k in unc["unit_of_volume"]}
    skip_rows = skip
    before, sim_before = simulation_rmse(model, rec, n_init, skip_rows)
    after, sim_after = simulation_rmse(diag.model_improved, rec, n_init, skip_rows)
    for f, mech in zip(findings, [f["mechanism"] for f in diag.findings]):
        f["plot"] = _panel(diag, rec, mech, sim_before, sim_after, f["intervals"])
    calib, _ = simulation_rmse(diag.model_calibrated, rec, n_init, skip_rows)
    fit = {"before": {"rmse": before, "model": "nominal (model file)"},
           "after": {"rmse": after, "model": "improved (calibrated + findings)"},
           "calibrated": {"rmse": calib},
           "mode": "open-loop simulation driven by the recorded inputs from the recorded initial state",
           "selection_error": eng.kind}
    if isinstance(eng, EquationError):
        fit["before"]["rmse_short_horizon"] = short_horizon_rmse(model, rec)
        fit["after"]["rmse_short_horizon"] = short_horizon_rmse(diag.model_improved, rec)
        fit["short_horizon_s"] = SHORT_HORIZON_S
        Rb = eng.residuals(model)
        Ra = eng.residuals(diag.model_improved)
        val = ~eng.train
        fit["before"]["mass_balance_rmse_heldout"] = {t: round(float(np.sqrt(np.mean(Rb[val, j] ** 2))), 6)
                                                     for j, t in enumerate(eng.columns)}
        fit["after"]["mass_balance_rmse_heldout"] = {t: round(float(np.sqrt(np.mean(Ra[val, j] ** 2))), 6)
                                                    for j, t in enumerate(eng.columns)}
        fit["mass_balance_window_s"] = eng.W * eng.dt
    fit["heldout"] = {"rows": int(np.sum(~eng.train)), "bic_calibrated": round(diag.base.val_bic, 2),
                      "bic_final": round(diag.final.val_bic, 2)}
    if diag.ablation:
        fit["ablation"] = {"heldout_rmse": round(diag.ablation["heldout_rmse"], 6),
                           "folds": diag.ablation["folds"],
                           "without": [{"finding": r["finding"], "heldout_rmse": round(r["heldout_rmse"], 6),
                                        "judged_by_folds": r["judged_by_folds"]}
                                       for r in diag.ablation["without"]]}
    if diag.integrator:
        fit["integrator"] = diag.integrator
    if diag.replay:
        fit["replay_check"] = diag.replay
    if diag.negligible:
        fit["negligible"] = diag.negligible
    loc = diag.loc
    report = {
        "mismatch": bool(diag.mismatch),
        "findings": findings,
        "fit": fit,
        "verdict": diag.verdict,
        "recording": rec.path,
        "duration_s": round(float(len(rec.t) * diag.model_nominal.dt), 3),
        "unreadable": getattr(rec, "unreadable", []),
        "model": diag.model_nominal.name,
        "calibration": diag.cal_report,
        "localisation": {
            "error": loc.kind,
            "flagged": loc.flagged,
            "suspect": loc.suspect,
            "pinned_coefficients": loc.pinned,
            "scores": {c: {k: round(v, 3) for k, v in s.items()} for c, s in loc.scores.items()},
            "intervals": {c: v for c, v in loc.intervals.items()},
            "regimes": loc.regimes,
            "at_rim_s": loc.at_rim,
            "limits_reached": _limits_reached(diag, rec),
        },
        "candidates": [{"candidate": t["candidate"], "heldout_dbic": round(t["dbic"], 2),
                        "heldout_sse_reduction": round(t["val_gain"], 4), "error": t.get("error", loc.kind)}
                       for t in sorted(diag.tried, key=lambda x: x["dbic"])],
    }
    report["_sims"] = (sim_before, sim_after)
    return report


def _heldout_error(res) -> dict:
    out = {"weighted_sse": round(float(res.val_sse), 4), "bic": round(float(res.val_bic), 2)}
    if math.isfinite(res.val_rmse):
        out["rmse"] = round(float(res.val_rmse), 6)
    return out


def _alternatives_report(diag: Diagnosis, f: dict) -> list[dict]:
    """Candidates the held-out data does not separate from the chosen finding (forward.indistinguishable),
    with their held-out errors and the experiment that would tell them apart."""
    from .experiments import separating_experiment

    out = []
    for a in f.get("alternatives", ()):
        m = a["fit"].mechanisms[-1]
        p = m.report_parameters()
        p.pop("base", None)
        out.append({"mechanism": m.name, "component": m.component, "parameters": p,
                    "heldout_dbic": round(a["dbic"], 2), "heldout_sse_reduction": round(a["gain"], 4),
                    "heldout_error": _heldout_error(a["fit"]),
                    "heldout_dbic_vs_chosen": round(a["dbic_vs_chosen"], 2),
                    "description": m.describe(m.values()),
                    "experiment": separating_experiment(f["mechanism"], m, diag.model_nominal)})
        if "dbic_both_orders" in a:
            out[-1]["heldout_dbic_both_orders"] = round(a["dbic_both_orders"], 2)
    return out


def _component_tanks(model: PlantModel, comp) -> list[str]:
    """The tanks a component acts on (a tank itself, a sensor's tank, a link's or a valve's ends,
    a pump's delivery tank)."""
    names = model.tank_names
    if comp in names:
        return [comp]
    out = []
    for s in model.sensors:
        if s.name == comp:
            out.append(s.tank)
    for lk in model.links:
        if comp in (lk.name, lk.valve):
            out += [t for t in (lk.from_, lk.to) if t in names]
    for p in model.pumps:
        if p.name == comp:
            out += [t for t in (p.to, p.from_) if t in names]
    return list(dict.fromkeys(out)) or list(names)


PANEL_POINTS = 300


def _panel(diag: Diagnosis, rec: Recording, mech, sim_before: dict, sim_after: dict, intervals) -> dict:
    """The plot panel of a finding: recorded vs nominal vs improved open-loop simulation on the
    signal it affects most (a sensor of the tanks it acts on), decimated to PANEL_POINTS."""
    model = diag.model_nominal
    sigs = [s.name for t in _component_tanks(model, mech.component) for s in model.sensors
            if s.tank == t and s.name in rec.signals]
    if mech.component in rec.signals:
        sigs = [mech.component]
    if not sigs:
        sigs = [s for s in model.signal_names if s in rec.signals]
    if not sigs:
        return {}
    sig = max(sigs, key=lambda s: float(np.sqrt(np.mean((np.asarray(sim_after[s]) - np.asarray(sim_before[s])) ** 2))))
    n = len(rec.t)
    idx = np.unique(np.linspace(0, n - 1, min(n, PANEL_POINTS)).round().astype(int))
    t = np.arange(n) * model.dt
    y = np.asarray(rec.signals[sig], float)
    return {"signal": sig, "intervals": intervals,
            "rmse_nominal": round(rmse(sim_before[sig], y), 6), "rmse_improved": round(rmse(sim_after[sig], y), 6),
            "t": [round(float(v), 2) for v in t[idx]],
            "recorded": [round(float(v), 5) for v in y[idx]],
            "nominal": [round(float(v), 5) for v in np.asarray(sim_before[sig])[idx]],
            "improved": [round(float(v), 5) for v in np.asarray(sim_after[sig])[idx]]}


def _limits_reached(diag: Diagnosis, rec: Recording) -> dict:
    """Sensors sitting at a clip value the model already has (e.g. y_V at 10 V): intervals."""
    out = {}
    model = diag.model_nominal
    t = np.arange(len(rec.t)) * model.dt
    for s in model.sensors:
        if s.name not in rec.signals or s.max is None:
            continue
        y = np.asarray(rec.signals[s.name], float)
        at = y >= s.max - max(s.resolution, 1e-9) * 0.5
        if at.sum() >= 2:
            out[s.name] = {"max": s.max, "samples": int(at.sum()),
                           "intervals": _mask_intervals(at, t, model.dt, 0.01 * float(t[-1] + model.dt))}
    return out


def write_json(report: dict, path: str | Path) -> None:
    clean = {k: v for k, v in report.items() if not k.startswith("_")}
    try:
        Path(path).write_text(json.dumps(clean, indent=1, default=_json_default) + "\n")
    except OSError as exc:
        raise CivicError(f"cannot write {path}: {exc.strerror}") from exc


def _json_default(o):
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(type(o))


def print_summary(report: dict, console=None) -> None:
    from rich.console import Console
    from rich.table import Table

    console = console or Console()
    head = "[bold red]MISMATCH[/]" if report["mismatch"] else "[bold green]OK[/]"
    console.print(f"{head}: {report['verdict']}")
    if not report["findings"]:
        # the calibration needed all of the datasheet's spread: what it absorbed may be more
        for path, c in report["calibration"].items():
            if c.get("at_spread_edge"):
                console.print(f"note: the calibration puts {path} at {c['change_pct']:+.1f} %, the edge of the "
                              "datasheet's spread: a coefficient off by more, or an effect that scales that flow "
                              "(a pump head, a closure, a leak beside it), which this record cannot tell apart")
    if report["findings"]:
        t = Table(title="findings (most important first)")
        for c in ("#", "mechanism", "component", "parameters", "held-out dBIC", "intervals (s)"):
            t.add_column(c)
        for i, f in enumerate(report["findings"], 1):
            # the brackets of its times are in the JSON and the evidence: the table keeps to the values
            params = ", ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}"
                               for k, v in f["parameters"].items()
                               if k not in ("path", "nominal") and k not in Mechanism.BRACKET)
            iv = f["intervals"]
            ivs = ", ".join(f"{a:g}-{b:g}" for a, b in iv[:3]) + (f" (+{len(iv) - 3})" if len(iv) > 3 else "")
            t.add_row(str(i), f["mechanism"], str(f["component"]), params, f"{f['heldout_dbic']:+.1f}", ivs)
        console.print(t)
        # what each finding means, and what the record cannot tell it from (the JSON has the evidence)
        for i, f in enumerate(report["findings"], 1):
            if f.get("description"):
                console.print(f"{i}. {f['description']}", markup=False, highlight=False)
            for a in f.get("alternatives", ()):
                console.print(f"   the record cannot tell it from {a['mechanism']} {a['component']} (held-out BIC "
                              f"{a['heldout_dbic_vs_chosen']:+.1f} from the chosen one's: {a['description']}); to "
                              f"tell them apart: {a['experiment']}", markup=False, highlight=False)
    abl = report["fit"].get("ablation")
    if abl:
        t = Table(title=f"ablation: held-out free-run RMSE (blocked {abl['folds']}-fold CV in time, refit per fold)")
        t.add_column("model")
        t.add_column("held-out RMSE", justify="right")
        t.add_row("all findings", f"{abl['heldout_rmse']:.4g}")
        for r in abl["without"]:
            t.add_row(f"without {r['finding']}", f"{r['heldout_rmse']:.4g}")
        console.print(t)
    t = Table(title="open-loop simulation RMSE (recorded inputs)")
    t.add_column("signal")
    t.add_column("before (nominal)", justify="right")
    t.add_column("after (improved)", justify="right")
    fb, fa = report["fit"]["before"], report["fit"]["after"]
    for s in fb["rmse"]:
        t.add_row(s, f"{fb['rmse'][s]:.4g}", f"{fa['rmse'][s]:.4g}")
    if "rmse_short_horizon" in fb:
        for s in fb["rmse_short_horizon"]:
            t.add_row(f"{s} ({report['fit']['short_horizon_s']:g} s horizon)",
                      f"{fb['rmse_short_horizon'][s]:.4g}", f"{fa['rmse_short_horizon'][s]:.4g}")
    console.print(t)


def plot(report: dict, diag: Diagnosis, rec: Recording, path: str | Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sim_before, sim_after = report["_sims"]
    sigs = [s for s in diag.model_nominal.signal_names if s in rec.signals]
    eng = diag.engine
    extra = isinstance(eng, EquationError)
    panels = [(i, f) for i, f in enumerate(report["findings"], 1) if f.get("plot")]
    rows = len(sigs) + (1 if extra else 0) + len(panels)
    fig, axes = plt.subplots(rows, 1, figsize=(11, 2.2 * rows + 0.6), sharex=True, squeeze=False)
    axes = axes[:, 0]
    t = np.arange(len(rec.t)) * diag.model_nominal.dt
    shade = merge([iv for f in report["findings"] for iv in f["intervals"]]) or \
        (diag.loc.all_intervals() if report["mismatch"] else [])
    for ax, s in zip(axes, sigs):
        ax.plot(t, rec.signals[s], color="0.55", lw=2.2, label="recorded")
        ax.plot(t, sim_before[s], color="tab:red", lw=1.0, alpha=0.8, label="nominal")
        ax.plot(t, sim_after[s], color="tab:blue", lw=1.0, alpha=0.8, label="improved")
        ax.set_ylabel(s)
    if extra:
        ax = axes[len(sigs)]
        Rb = eng.residuals(diag.model_nominal)
        Ra = eng.residuals(diag.model_improved)
        tw = eng.row_times[:, 1]
        for j, c in enumerate(eng.columns):
            line, = ax.plot(tw, np.cumsum(Rb[:, j]), lw=1.0, ls="--", label=f"{c} nominal")
            ax.plot(tw, np.cumsum(Ra[:, j]), lw=1.0, color=line.get_color(), label=f"{c} improved")
        ax.set_ylabel("cum. mass-balance\nresidual (L)")
        ax.legend(loc="upper left", fontsize=7, ncol=4)
    # one panel per finding: its affected signal, its own intervals shaded
    for ax, (i, f) in zip(axes[len(sigs) + (1 if extra else 0):], panels):
        p = f["plot"]
        ax.plot(p["t"], p["recorded"], color="0.55", lw=2.2, label="recorded")
        ax.plot(p["t"], p["nominal"], color="tab:red", lw=1.0, label=f"nominal (RMSE {p['rmse_nominal']:.3g})")
        ax.plot(p["t"], p["improved"], color="tab:blue", lw=1.0, label=f"improved (RMSE {p['rmse_improved']:.3g})")
        for a, b in f["intervals"]:
            ax.axvspan(a, b, color="green", alpha=0.12, lw=0)
        ax.set_ylabel(p["signal"])
        ax.set_title(f"finding {i}: {f['mechanism']} {f['component']}", fontsize=8, loc="left")
        ax.legend(loc="upper right", fontsize=7, ncol=3)
    for ax in axes[:len(sigs) + (1 if extra else 0)]:
        for a, b in shade:
            ax.axvspan(a, b, color="orange", alpha=0.15, lw=0)
    axes[0].legend(loc="upper right", fontsize=8, ncol=3)
    axes[-1].set_xlabel("time (s)")
    title = "; ".join(f"{f['mechanism']} {f['component']}" for f in report["findings"]) or \
        ("mismatch, unexplained" if report["mismatch"] else "no significant mismatch")
    save_figure(fig, path, f"civic diagnose: {title} (shaded: mismatch intervals)")
