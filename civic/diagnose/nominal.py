"""Fit a *nominal* model's coefficients on the normal regime of a recording only.

A nominal model should describe the plant where its datasheet structure holds; fitted
on a whole record that also visits a regime the structure lacks (a tank spilling, a
sensor at its clip value), its coefficients absorb that regime and hide it from
`civic diagnose`. Here the fit uses only the segments in which every measured signal
stays below `below` (a fraction of its clip value), each segment simulated from its own
first sample with the unmeasured tanks' initial volumes as nuisance parameters (the
excluded stretches would otherwise carry a wrong state into the next segment).

    python -m civic.diagnose.nominal MODEL.toml RECORDING.csv PATH [PATH ...] [--below 0.85]

prints the fitted values (e.g. pump.P1.gain link.out1.coeff link.out2.coeff tank.T1.area).
"""
from __future__ import annotations

import argparse

import numpy as np
from scipy.optimize import least_squares

from civic.plant.model import PlantModel
from civic.plant.simulate import Recording, measured_state, simulate


def normal_segments(model: PlantModel, rec: Recording, below: float = 0.85, min_len: int = 40) -> list:
    """[(start, stop)] sample ranges where every measured sensor stays below `below` x its max."""
    ok = np.ones(len(rec.t), bool)
    for s in model.sensors:
        if s.name in rec.signals and s.max is not None:
            ok &= np.asarray(rec.signals[s.name], float) < below * s.max
    edges = np.flatnonzero(np.diff(np.concatenate(([0], ok.astype(np.int8), [0]))))
    return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2]) if b - a >= min_len]


def fit_nominal(model: PlantModel, rec: Recording, paths: list[str], below: float = 0.85,
                min_len: int = 40) -> tuple[PlantModel, dict]:
    """Coefficients `paths` (within x0.3..x3 of the model's) fitted on the normal segments."""
    segs = normal_segments(model, rec, below, min_len)
    sensed = [s for s in model.sensors if s.name in rec.signals]
    unmeasured = [t.name for t in model.tanks if t.name not in {s.tank for s in sensed}]
    x_nom = np.array([float(model.get(p)) for p in paths])
    caps = [20.0 * model.tank(t).area for t in unmeasured]

    def build(x):
        m = model.copy()
        for p, v in zip(paths, x):
            m.set(p, float(v))
        return m

    def resid(z):
        m = build(z[:len(paths)])
        out, pos = [], len(paths)
        for a, b in segs:
            sig = {k: np.asarray(v)[a:b] for k, v in rec.signals.items()}
            x0 = measured_state(m, sig, 1)
            x0.update({t: float(v) for t, v in zip(unmeasured, z[pos:pos + len(unmeasured)])})
            pos += len(unmeasured)
            sim = simulate(m, np.arange(b - a) * m.dt, {k: sig[k] for k in m.input_names}, x0)
            out += [sim[s.name] - sig[s.name] for s in sensed]
        return np.concatenate(out)

    nu = len(unmeasured) * len(segs)
    z0 = np.concatenate([x_nom, np.tile(np.array(caps) * 0.3, len(segs))])
    lo = np.concatenate([0.3 * x_nom, np.zeros(nu)])
    hi = np.concatenate([3.0 * x_nom, np.tile(caps, len(segs))])
    sol = least_squares(resid, z0, bounds=(lo, hi), x_scale=np.maximum(np.abs(z0), 1e-3))
    info = {"segments_s": [[a * model.dt, b * model.dt] for a, b in segs],
            "rmse": float(np.sqrt(np.mean(sol.fun ** 2))),
            "values": {p: float(v) for p, v in zip(paths, sol.x)}}
    return build(sol.x[:len(paths)]), info


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("model")
    ap.add_argument("recording")
    ap.add_argument("paths", nargs="+")
    ap.add_argument("--below", type=float, default=0.85)
    a = ap.parse_args(argv)
    from civic.diagnose.data import load

    m = PlantModel.from_toml(a.model)
    fitted, info = fit_nominal(m, load(a.recording, m), a.paths, a.below)
    print(info)


if __name__ == "__main__":
    main()
