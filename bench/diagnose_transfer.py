"""Cascaded Tanks: how the improved model transfers within the estimation record.

`transfer` runs `civic diagnose` on one part of the record and scores the improved model on the
other part; `transfer_structures` fits fixed candidate sets jointly (no elimination) on each
half and scores them on the other. The validation record is not used. Run both through
bench/bench_diagnose.py --transfer / --structures.
"""
from __future__ import annotations

import os
import time
from pathlib import Path

import civic  # noqa: F401  (before numpy: it pins the CPU code paths, civic/__init__.py)

ROOT = Path(__file__).resolve().parents[1]
# the record, its nominal model, and make bench's time target for diagnosing it (s)
CASCADED = (ROOT / "traces" / "cascaded-tanks" / "estimation.csv", ROOT / "configs" / "cascaded-tanks.toml", 60.0)


def _transfer_job(job) -> dict:
    """One direction of one split: `civic diagnose` on the part before (or after) the split
    point, the improved model scored on the rest."""

    from civic.diagnose import data
    from civic.diagnose.fit import diagnose
    from civic.diagnose.report import simulation_rmse
    from civic.plant.model import PlantModel

    offset, fit_first, n_init = job
    data_path, model_path, _ = CASCADED
    model = PlantModel.from_toml(model_path)
    rec = data.load(data_path, model)
    n = len(rec.t)
    cut = n // 2 + offset
    parts = {"first": slice(0, cut), "second": slice(cut, n)}

    a, b = ("first", "second") if fit_first else ("second", "first")
    ra, rb = (rec.part(parts[x], f"{rec.path} ({x} part)") for x in (a, b))
    t0 = time.perf_counter()
    d = diagnose(model, ra, n_init=n_init)
    el = time.perf_counter() - t0
    own, _ = simulation_rmse(d.model_improved, ra, n_init, n_init)
    other, _ = simulation_rmse(d.model_improved, rb, n_init, n_init)
    nom, _ = simulation_rmse(model, rb, n_init, n_init)
    return {"offset": offset, "direction": f"{a}->{b}", "fit_rmse": own["y_V"], "transfer_rmse": other["y_V"],
            "nominal_on_other": nom["y_V"], "findings": [f["mechanism"].label for f in d.findings],
            "parameters": [f["fit"].mechanisms[-1].report_parameters() for f in d.findings], "seconds": round(el, 1)}


def transfer(n_init: int = 50, offsets=(0,)) -> dict:
    """`civic diagnose` on each part of the Cascaded Tanks estimation record cut at its middle
    (plus each of `offsets` samples), the improved model scored on the other part (open-loop
    simulation, first `n_init` samples set the state and are not scored, as `civic simulate
    --init-samples`). Several cuts show how far the figure moves with where the record is cut:
    which findings survive elimination on half a record is chaotic. The validation record is
    not used."""
    from multiprocessing import Pool

    import numpy as np

    jobs = [(o, first, n_init) for o in offsets for first in (True, False)]
    out = {}
    with Pool(min(len(jobs), int(os.environ.get("CIVIC_BENCH_PROCS", "2")))) as pool:
        for r in pool.imap(_transfer_job, jobs):
            out[f"{r['offset']:+d} {r['direction']}"] = r
            a, b = r["direction"].split("->")
            print(f"cut {r['offset']:+d}: {a} part -> {b} part: fitted {r['fit_rmse']:.3f} V on its own part, "
                  f"{r['transfer_rmse']:.3f} V on the other (nominal {r['nominal_on_other']:.3f} V); {r['seconds']:.0f} s; "
                  "findings: " + ", ".join(f"{f} {p}" for f, p in zip(r["findings"], r["parameters"])), flush=True)
    for o in offsets:
        pair = [v["transfer_rmse"] for v in out.values() if v["offset"] == o]
        print(f"cut {o:+d}: transfer RMSE (mean of both directions) {np.mean(pair):.3f} V")
    rmse = [v["transfer_rmse"] for v in out.values()]
    mean = float(np.mean(rmse))
    if len(offsets) > 1:
        print(f"over {len(offsets)} cuts: mean {mean:.3f} V, median {np.median(rmse):.3f} V, "
              f"range {min(rmse):.3f}-{max(rmse):.3f} V")
    else:
        print(f"half -> half transfer RMSE (mean of both directions): {mean:.3f} V")
    return {"runs": out, "mean_transfer_rmse": mean}


# ---------------------------------------------------------------------------------------
# Cascaded Tanks: which structure transfers? Fixed candidate sets, no elimination
# ---------------------------------------------------------------------------------------
def _structure_variants(model):
    """Named edits of the free-run candidate list (the catalogue's most general candidate per
    family and component, as `diagnose` fits them jointly before backward elimination)."""
    from civic.diagnose.mechanisms import FlowLaw, Overflow

    def drop(*labels):
        return lambda c: [m for m in c if m.label not in labels]

    def rebound(cond, edit):
        def sel(c):
            out = []
            for m in c:
                if cond(m):
                    params, bounds, fixed = edit(dict(m.params), dict(m.bounds), dict(m.fixed))
                    m = type(m)(m.component, params, bounds, fixed)
                out.append(m)
            return out
        return sel

    def wide_sensor(p, b, f):
        span = 4 * b["offset"][1]
        b.update(offset=(-0.6 * span, 0.6 * span), gain=(0.02, 5.0))
        return p, b, f

    def linear_form(links, keep_exponent=False):
        def sel(c):
            out = []
            for m in c:
                if m.name == "flow_law" and m.component in links:
                    lk = model.find("link", m.component)
                    if keep_exponent:
                        out.append(m)
                    m = FlowLaw(lk.name, {"linear": 0.02 * lk.coeff}, {"linear": (0.0, 2.0 * lk.coeff)},
                                {"form": "linear"})
                out.append(m)
            return out
        return sel

    def t1_rim_x2(p, b, f):
        lo, hi = b["volume"]
        b["volume"] = (lo, 2.0 * hi)
        return p, b, f

    def t2_rim_free(c):
        return [Overflow("T2", {"volume": 1.05 * float(m.fixed["volume"])},
                         {"volume": (float(m.fixed["volume"]), 1.5 * float(m.fixed["volume"]))}, {"to": m.fixed["to"]})
                if m.name == "overflow" and m.component == "T2" and not m.params else m for m in c]

    return {
        "all general candidates (no elimination)": lambda c: c,
        "without spill below the rim": lambda c: [m for m in c if getattr(m, "general_key", "") != "spill_out"],
        "without pump_head": drop("pump_head(P1)"),
        "without pump_dead_zone": drop("pump_dead_zone(P1)"),
        "without pump_head, pump_dead_zone": drop("pump_head(P1)", "pump_dead_zone(P1)"),
        "without sensor_characteristic": drop("sensor_characteristic(y_V)"),
        "without flow_law out1": drop("flow_law(out1, exponent)"),
        "without flow_law out2": drop("flow_law(out2, exponent)"),
        "without both flow laws": lambda c: [m for m in c if m.name != "flow_law"],
        "sensor map, wide bounds": rebound(lambda m: m.name == "sensor_characteristic", wide_sensor),
        "flow laws as added linear term": linear_form({"out1", "out2"}),
        "out2: exponent + linear term": linear_form({"out2"}, keep_exponent=True),
        "T1 split rim bound x2": rebound(lambda m: m.name == "overflow" and "fraction" in m.params, t1_rim_x2),
        "T2 rim free above the clip": t2_rim_free,
    }


def transfer_structures(names=None, n_init: int = 50) -> dict:
    """Each structure variant fitted jointly (multi-start as `diagnose`, no backward elimination)
    on each half of the Cascaded Tanks estimation record and scored on the other half, and
    fitted on the whole record (estimation RMSE). The validation record is not used."""
    import numpy as np

    from civic.diagnose import backward as B
    from civic.diagnose import data
    from civic.diagnose import problem as P
    from civic.diagnose import fit as F
    from civic.diagnose.locate import localise
    from civic.plant.noise import noise_sigma
    from civic.diagnose.mechanisms import CATALOGUE, Coefficient
    from civic.diagnose.report import simulation_rmse
    from civic.plant.model import PlantModel

    data_path, model_path, _ = CASCADED
    model = PlantModel.from_toml(model_path)
    rec = data.load(data_path, model)
    n = len(rec.t)

    recs = {"first": rec.part(slice(0, n // 2), "first"), "second": rec.part(slice(n // 2, n), "second"), "whole": rec}

    def joint_fit(r, select):
        # as diagnose() up to the candidates, then backward_eliminate's joint multi-start fit, refitted on all rows
        engine = P.make_engine(model, r, n_init=n_init)
        prob = P.Problem(model, r, engine, P.Calibration.of(model, bounds=F.FREE_RUN_CAL), np.ones(len(engine.columns)))
        prob.sigma = np.array([max(noise_sigma(engine.Y[:, j]), 1e-3 * (np.ptp(engine.Y[:, j]) or 1.0))
                               for j in range(engine.Y.shape[1])])
        every = np.ones_like(engine.train)
        base = prob.fit([], rows=every)
        loc = localise(model, r, engine, prob.residuals(base.model, base.x0_extra) * prob.sigma, prob.sigma)
        cands = B.general_candidates([c for fam in CATALOGUE if fam is not Coefficient for c in fam.candidates(model, loc)])
        mechs = sorted(select(cands), key=B.free_rim_last)
        singles = [prob.fit([m], rows=every, start_cal=base.cal, start_x0=base.x0_extra, starts=P.extra_starts(m))
                   for m in mechs]
        fits = [prob.fit(mechs, rows=every, start_cal=base.cal, start_x0=base.x0_extra,
                         starts=P.extra_starts(mechs[-1]) if mechs else None)]
        if singles:
            k = int(np.argmin([s.train_sse for s in singles]))
            warm = [singles[k].mechanisms[0] if j == k else m for j, m in enumerate(mechs)]
            fits.append(prob.fit(warm, rows=every, start_cal=singles[k].cal, start_x0=singles[k].x0_extra))
        best = min(fits, key=lambda f: f.train_sse)
        return F._refit_all(prob, best.mechanisms, best).model

    variants = _structure_variants(model)
    out = {}
    for name in names or variants:
        row = {}
        for a, b in (("first", "second"), ("second", "first")):
            m = joint_fit(recs[a], variants[name])
            row[f"{a}->{b}"] = simulation_rmse(m, recs[b], n_init, n_init)[0]["y_V"]
        row["mean_transfer"] = float(np.mean([row["first->second"], row["second->first"]]))
        row["estimation"] = simulation_rmse(joint_fit(rec, variants[name]), rec, n_init, n_init)[0]["y_V"]
        out[name] = row
        print(f"{name:42s} transfer {row['first->second']:.3f} / {row['second->first']:.3f} (mean "
              f"{row['mean_transfer']:.3f}); whole estimation record {row['estimation']:.3f} V", flush=True)
    return out
