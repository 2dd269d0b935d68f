"""Plant simulator speed: plant-seconds per wall-second (open loop, MPC closed loop) vs scipy solve_ivp.

Run: python bench/bench_plant.py  (or `make bench`). Prints one line per case.
"""
from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def _inputs(n, seed=0, hold=50):
    rng = np.random.default_rng(seed)
    return {k: np.repeat(rng.uniform(0, 1, n // hold + 1), hold)[:n] for k in ("p1", "v1", "v2")}


def _best(fn, repeat=3):
    best = math.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def solve_ivp_baseline(model, t, u, x0):
    """The same datasheet ODE with scipy's RK45 (inputs held per sample, dead time by lookup)."""
    from scipy.integrate import solve_ivp

    C = {lk.name: lk.coeff * (1 - lk.closure) for lk in model.links}
    pump = model.pumps[0]
    A = [tk.area for tk in model.tanks]
    tau_v = [v.tau for v in model.valves]
    dt = model.dt
    n = len(t)
    P, V1, V2 = u["p1"], u["v1"], u["v2"]

    def held(arr, tt):
        return arr[min(max(int(tt / dt + 1e-9), 0), n - 1)]

    def rhs(tt, x):
        v1, v2, v3, v4, a1, a2 = x
        h1, h2, h3 = v1 / A[0], v2 / A[1], v3 / A[2]
        q_p = pump.gain * (1 - pump.closure) * held(P, tt - pump.dead_time) if v4 >= pump.min_source_volume else 0.0
        d12 = h1 - h2
        d23 = h2 - h3
        q12 = C["V1"] * a1 * math.copysign(math.sqrt(abs(d12)), d12)
        q23 = C["pipe23"] * math.copysign(math.sqrt(abs(d23)), d23)
        q34 = C["V2"] * a2 * math.sqrt(max(h3, 0.0))
        return [q_p - q12, q12 - q23, q23 - q34, q34 - q_p,
                (held(V1, tt) - a1) / tau_v[0], (held(V2, tt) - a2) / tau_v[1]]

    return solve_ivp(rhs, (t[0], t[-1]), x0, t_eval=t, max_step=dt, rtol=1e-6, atol=1e-9)


def main() -> None:
    from civic.plant.control import run_closed_loop
    from civic.plant.model import PlantModel
    from civic.plant.simulate import simulate

    model = PlantModel.from_toml(ROOT / "configs" / "plant.toml")
    n = 6000
    t = np.arange(n) * model.dt
    u = _inputs(n)
    x0 = {"T1": 6.0, "T2": 5.0, "T3": 4.0, "T4": 25.0}
    simulate(model, t, u, x0)                                # compile once
    wall = _best(lambda: simulate(model, t, u, x0))
    ol = t[-1] / wall
    print(f"plant open loop   : {n} samples ({t[-1]:.0f} s) in {wall * 1e3:7.1f} ms "
          f"= {ol:9.0f} plant-s/wall-s")
    nb = 600
    tb = t[:nb]
    ub = {k: v[:nb] for k, v in u.items()}
    xb = [6.0, 5.0, 4.0, 25.0, ub["v1"][0], ub["v2"][0]]
    wb = _best(lambda: solve_ivp_baseline(model, tb, ub, xb), repeat=1)
    base = tb[-1] / wb
    print(f"solve_ivp baseline: {nb} samples ({tb[-1]:.0f} s) in {wb * 1e3:7.1f} ms "
          f"= {base:9.0f} plant-s/wall-s   (civic is {ol / base:.0f}x faster)")
    dur = 600.0
    wm = _best(lambda: run_closed_loop(model, dur, controller="mpc", seed=1), repeat=1)
    print(f"closed loop (MPC) : {dur:.0f} s in {wm:7.2f} s = {dur / wm:9.0f} plant-s/wall-s "
          f"(1 h of plant in {3600 / (dur / wm):.1f} s; {dur / wm / base:.1f}x the open-loop solve_ivp rate)")


if __name__ == "__main__":
    main()
