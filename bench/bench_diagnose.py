"""`civic diagnose` speed: the real Cascaded Tanks record (target < 60 s) and 10 Hz
closed-loop recordings of the four-tank plant, 10 min (target < 10 s) and 60 min (< 60 s).

The four-tank recordings are made with the closed-loop plant simulator (MPC designed on
the nominal model, plant with a concealed T3 leak and a few % calibration spread),
written to a pcap; every case is diagnosed through the CLI code path (load, diagnose,
report, no plot), with a rich progress bar on a terminal.

Run: python bench/bench_diagnose.py  (or `python -m bench`). Prints one line per case, then
the robustness tables below on seed 1 (CIVIC_BENCH_SEEDS=1,2,... for more; ~11 min a seed on
2 cores), misses listed, each run read back from a pcap as with --via-pcap below.

Cascaded Tanks transfer (fit on one half of the estimation record, score on the other):
    python bench/bench_diagnose.py --transfer [OFFSET,OFFSET...]
(the record cut at its middle, or that many samples after it: e.g. -64,-32,0,32,64)
and which structure transfers (fixed candidate sets, fitted jointly without elimination;
~15 min on one core):
    python bench/bench_diagnose.py --structures ["NAME;NAME..."]

Robustness sweep alone, every case printed (--off-grid: at the magnitudes of OFF_GRID instead):
    python bench/bench_diagnose.py --robustness 1,2,3,4,5,6,7,8 [CASE,CASE...] [--off-grid] [--via-pcap]
10 min closed-loop cases, the plant's coefficients off by up to +-4 % (calibration), one
concealed mechanism of the catalogue (one to three magnitudes, small but significant) or none;
prints per case and the rates: clean cases without alarm, and cases where the first
finding names the right mechanism and component and nothing else is found, counting only cases where the
mechanism was active (a rim or a clip the levels never reach changes nothing). Each case also
prints, in sensor noises, how far its effect moves the open-loop replay (against the same plant
without it) and how much of that is left beyond what calibrating the datasheet's coefficients
explains; a miss with less than 3 left is marked as such in the tables (the calibration's
+-5 % can absorb a small effect whole). --via-pcap: each run is written to a pcap and read back
by `civic diagnose`'s loader (wire rounding, the fault-code and frozen-sensor checks), as the
hidden cases are called, instead of handing the simulation's arrays to the diagnosis; a run the
loader leaves samples of out (a simulated run has none) is a miss, its warning lines printed.
CIVIC_BENCH_CONTROLLER=pi runs the sweep under the PI loops instead of the MPC (the
supervisor's setpoints and tests are the same).
"""
from __future__ import annotations

import json
import os
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import civic  # noqa: E402,F401  (before numpy: it pins the CPU code paths, civic/__init__.py)

TARGETS = {600.0: 10.0, 3600.0: 60.0}


def make_recording(path: Path, duration: float, seed: int = 5) -> None:
    from civic.plant.control import run_closed_loop
    from civic.plant.model import Link, PlantModel
    from civic.plant.simulate import write_recording

    nominal = PlantModel.from_toml(ROOT / "configs" / "plant.toml")
    plant = nominal.copy()
    plant.set("pump.P1.gain", 0.30 * 1.03)
    plant.set("link.V2.coeff", 0.30 * 0.98)
    plant.links.append(Link("leak", from_="T3", to="T4", coeff=0.012, law="orifice"))
    res = run_closed_loop(plant, duration, controller="mpc", seed=seed, noise=True, controller_model=nominal)
    write_recording(str(path), nominal, res.t, res.signals)


def time_diagnose(path: Path, model_path: Path = ROOT / "configs" / "plant.toml", n_init: int = 1,
                  progress=None) -> tuple[float, dict]:
    from civic.diagnose import data
    from civic.diagnose.fit import diagnose
    from civic.diagnose.report import build_report
    from civic.plant.model import PlantModel

    t0 = time.perf_counter()
    model = PlantModel.from_toml(model_path)
    rec = data.load(path, model)
    diag = diagnose(model, rec, progress=progress, n_init=n_init)
    rep = build_report(diag, rec, n_init=n_init, skip=0 if n_init == 1 else n_init)
    return time.perf_counter() - t0, rep


CASCADED = (ROOT / "traces" / "cascaded-tanks" / "estimation.csv", ROOT / "configs" / "cascaded-tanks.toml", 60.0)


def main() -> int:
    from rich.console import Console
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    ok = True
    console = Console(stderr=True)
    with tempfile.TemporaryDirectory() as tmp, \
            Progress(TextColumn("{task.fields[case]}"), BarColumn(), TextColumn("{task.description}"),
                     TimeElapsedColumn(), console=console, transient=True) as bar:
        def progress_of(task):
            return lambda k, n, what="": bar.update(task, completed=k / max(n, 1), description=what)

        data_path, model_path, target = CASCADED
        task = bar.add_task("", total=1.0, case="Cascaded Tanks")
        el, rep = time_diagnose(data_path, model_path, n_init=50, progress=progress_of(task))
        bar.remove_task(task)
        after = rep["fit"]["after"]["rmse"]["y_V"]
        held = rep["fit"].get("ablation", {}).get("heldout_rmse", float("nan"))
        ok &= el < target
        print(f"diagnose Cascaded Tanks (1024 samples): {el:6.2f} s (target < {target:g} s, "
              f"{'ok' if el < target else 'SLOW'}); {len(rep['findings'])} findings, "
              f"simulation RMSE {rep['fit']['before']['rmse']['y_V']:.3f} -> {after:.3f} V "
              f"(held-out {held:.3f} V)", flush=True)
        for duration, target in TARGETS.items():
            task = bar.add_task("simulating the plant", total=1.0, case=f"four-tank {duration / 60:g} min")
            path = Path(tmp) / f"closed_loop_{int(duration)}s.pcap"
            make_recording(path, duration)
            el, rep = time_diagnose(path, progress=progress_of(task))
            bar.remove_task(task)
            found = ", ".join(f"{f['mechanism']} {f['component']}" for f in rep["findings"]) or "none"
            status = "ok" if el < target else "SLOW"
            ok &= el < target
            print(f"diagnose {duration / 60:4.0f} min @ 10 Hz ({int(duration * 10)} messages): "
                  f"{el:6.2f} s (target < {target:g} s, {status}); findings: {found}", flush=True)
    # the robustness tables (catalogue families, real-rig physics) on BENCH_SEEDS; the full
    # sweep is --robustness 1,...,8
    seeds = [int(s) for s in os.environ.get("CIVIC_BENCH_SEEDS", BENCH_SEEDS).split(",")]
    print(f"\nrobustness, seeds {','.join(map(str, seeds))} (misses listed):", flush=True)
    robustness(seeds, quiet=True, via_pcap=True)
    return 0 if ok else 1


BENCH_SEEDS = "1"   # seeds of the robustness sweep in `make bench` (CIVIC_BENCH_SEEDS overrides)


# ---------------------------------------------------------------------------------------
# robustness sweep
# ---------------------------------------------------------------------------------------
SWEEP = {
    # case: (mechanism, component, magnitudes)
    "leak_T1": ("leak", "T1", (0.006, 0.010)),
    "leak_T2": ("leak", "T2", (0.006, 0.010)),
    "leak_T3": ("leak", "T3", (0.006, 0.012)),
    "leak_T3_out": ("leak", "T3", (0.008,)),
    "leak_T2_out": ("leak", "T2", (0.010,)),
    "leak_T1_out": ("leak", "T1", (0.002, 0.004)),
    "offset_L1": ("sensor_offset", "L1", (0.2, 0.4)),
    "offset_L3": ("sensor_offset", "L3", (0.2,)),
    "offset_L4": ("sensor_offset", "L4", (0.3, 0.5)),
    "deadtime_P1": ("dead_time", "P1", (1.0, 2.0)),
    "deadtime_V2": ("dead_time", "V2", (2.0,)),
    "head_P1": ("pump_head", "P1", (0.02, 0.04)),
    "overflow_T1": ("overflow", "T1", (9.0,)),
    "spill_T2": ("overflow", "T2", (0.07,)),      # finite spill into T4, 0.07 L/s per L above 8.5 L
    "valve_V1": ("valve_characteristic", "V1", (1.3, 1.5)),
    "valve_V2": ("valve_characteristic", "V2", (1.5,)),
    "saturation_L1": ("sensor_saturation", "L1", (9.0,)),
    "saturation_L2": ("sensor_saturation", "L2", (8.0,)),
    "saturation_L3": ("sensor_saturation", "L3", (7.0,)),
    # real-rig physics (issue #20): a flow law that is not Torricelli, a bent level sensor
    # (calibrated at 5 L), a pump dead zone, an overflow whose spill partly leaves the plant
    "flowlaw_pipe23": ("flow_law", "pipe23", (0.4, 0.55, 0.6)),     # q = c*|dh|**n, n instead of 0.5
    "flowlaw_V2": ("flow_law", "V2", (0.4, 0.45, 0.6, 0.7)),
    "flowlaw_V1": ("flow_law", "V1", (0.6,)),
    "sensorchar_L2": ("sensor_characteristic", "L2", (0.9, 1.05, 1.1)),  # y = 5**(1-n)*V**n
    "sensorchar_L1": ("sensor_characteristic", "L1", (0.85, 0.9, 1.05, 1.1)),   # 0.85: the loop fills T1 to its rim
    "sensorchar_L3": ("sensor_characteristic", "L3", (1.1,)),
    "sensorchar_L4": ("sensor_characteristic", "L4", (0.85,)),  # the reservoir: reads 2-5 L low
    "sensorquad_L2": ("sensor_characteristic", "L2", (0.02,)),  # y = V + c*(V - 5)**2: high both ways from 5 L
    "deadzone_P1": ("pump_dead_zone", "P1", (0.03, 0.05)),     # no flow below this command
    "split_T1": ("overflow", "T1", (0.2, 0.5, 0.8)),            # rim 9 L, this share into T4, rest out
    "split_T2": ("overflow", "T2", (0.5,)),                     # rim 8.5 L (bundled setpoints), idem
    # faults switched on mid-run (at ONSET): a line passes this share less from then on, a leak opens
    "closure_V2": ("closure", "V2", (0.3, 0.55)),      # VM1 on the drain: warning, error
    "closure_P1": ("closure", "P1", (0.2, 0.4)),       # VM2 on the pump line: warning, error
    "leakon_T3": ("leak", "T3", (0.012,)),             # into T4, from ONSET on
    "leakon_T1": ("leak", "T1", (0.01,)),
    "spell_V2": ("closure", "V2", (0.55,)),        # VM1 closed for SPELL only, then opened again
    "spell_P1": ("closure", "P1", (0.4,)),
    "repaired_T3": ("leak", "T3", (0.012,)),       # into T4 from the start, repaired at REPAIRED_AT
    "shift_L1": ("sensor_offset", "L1", (0.2,)),       # a reading steps by this at SHIFT_AT
    "shift_L3": ("sensor_offset", "L3", (0.15,)),
    "shift_L4": ("sensor_offset", "L4", (0.5,)),       # the reservoir's: only the inventory sees it
    "glitch_L1": ("sensor_offset", "L1", (0.3,)),      # a reading off by this for SPELL only
    "glitch_L3": ("sensor_offset", "L3", (0.2,)),
    "righted_L1": ("sensor_offset", "L1", (0.3,)),     # a reading off from the start, set right at REPAIRED_AT
    "drift_L1": ("sensor_offset", "L1", (-0.00075,)),  # a reading drifts by this per s from DRIFT_FROM
    "drift_L3": ("sensor_offset", "L3", (0.00075,)),   # (0.3 L by the end)
    "drift_L4": ("sensor_offset", "L4", (0.0015,)),
    "clean": (None, None, (0.0,)),
}
# --off-grid: every kind at magnitudes between and beyond the sweep's (no magnitude any change was
# tuned on), and an L2 offset the sweep lacks. V2's flow law at 0.5 is Torricelli itself: a clean
# run, whose right answer is no finding (the table counts it against the flow law it names)
OFF_GRID = {
    "leak_T1": (0.008,), "leak_T2": (0.008,), "leak_T3": (0.009,), "leak_T3_out": (0.005,),
    "leak_T2_out": (0.006,), "leak_T1_out": (0.003,),
    "offset_L1": (0.3,), "offset_L2": (0.25,), "offset_L3": (0.3,), "offset_L4": (0.4,),
    "deadtime_P1": (1.5,), "deadtime_V2": (3.0,), "head_P1": (0.03,),
    "overflow_T1": (8.8,), "spill_T2": (0.04,), "valve_V1": (1.4,), "valve_V2": (1.3,),
    "saturation_L1": (8.8,), "saturation_L2": (7.5,), "saturation_L3": (6.5,),
    "flowlaw_pipe23": (0.45, 0.65, 0.7), "flowlaw_V2": (0.42, 0.55, 0.65),
    "sensorchar_L2": (0.85, 0.95), "sensorchar_L1": (0.95,), "sensorchar_L3": (0.9,), "sensorchar_L4": (0.9,),
    "sensorquad_L2": (0.03,), "deadzone_P1": (0.04, 0.07),
    "split_T1": (0.35, 0.65), "split_T2": (0.3, 0.7),
    "closure_V2": (0.4,), "closure_P1": (0.3,), "leakon_T3": (0.008,), "leakon_T1": (0.007,),
    "clean": (0.0,),
}
OFF_GRID_KINDS = {"offset_L2": ("sensor_offset", "L2")}   # (mechanism, component) of cases SWEEP lacks
ONSET = 300.0   # s into the 600 s record
SHIFT_AT = 302.3  # s: a sensor knocked mid-run, between two of the equation error's window starts
DRIFT_FROM = 200.0  # s: a sensor that starts drifting
SPELL = (200.0, 400.0)  # s: a fault switched on, then off again
REPAIRED_AT = 300.0  # s: a leak from the start repaired
EXCESS_BAR = 3.0  # sensor noises: an effect the calibrated datasheet replays closer than this is below the bar

NEW_KINDS = ("flowlaw", "sensorchar", "sensorquad", "deadzone", "split")


SPILL_RIM = 8.5    # L: the rim of the finite spill cases


def split_rim(tank: str) -> float:
    """L: the rim of a split-spill case; T2's setpoints stay below 9 L, so its rim is lower."""
    return 9.0 if tank == "T1" else SPILL_RIM


def sweep_plant(nominal, case: str, mag: float, seed: int):
    """The 'real' plant of a sweep case: calibration spread + the concealed mechanism."""
    import numpy as np

    from civic.plant.model import Link, Overflow

    rng = np.random.default_rng(seed * 1000 + 17)
    m = nominal.copy()
    for path in ("pump.P1.gain", "link.V1.coeff", "link.pipe23.coeff", "link.V2.coeff"):
        m.set(path, float(m.get(path)) * (1 + rng.uniform(-0.04, 0.04)))
    kind, _, comp = case.partition("_")
    if kind in ("leak", "leakon"):
        tank = comp.split("_")[0]
        m.links.append(Link("leak", from_=tank, to="outside" if comp.endswith("out") else "T4", coeff=mag,
                            since=ONSET if kind == "leakon" else 0.0))
    elif kind == "repaired":
        m.links.append(Link("leak", from_=comp, to="T4", coeff=mag, until=REPAIRED_AT))
    elif kind == "spell":
        x = m.find("pump" if comp.startswith("P") else "link", comp)
        x.closure, (x.onset, x.until) = mag, SPELL
    elif kind == "offset":
        m.find("sensor", comp).offset = mag
    elif kind == "shift":
        s = m.find("sensor", comp)
        s.shift, s.since = mag, SHIFT_AT
    elif kind == "glitch":
        s = m.find("sensor", comp)
        s.shift, (s.since, s.until) = mag, SPELL
    elif kind == "righted":
        s = m.find("sensor", comp)
        s.shift, s.until = mag, REPAIRED_AT
    elif kind == "drift":
        s = m.find("sensor", comp)
        s.drift, s.since = mag, DRIFT_FROM
    elif kind == "deadtime":
        m.find("pump" if comp.startswith("P") else "valve", comp).dead_time = mag
    elif kind == "head":
        m.find("pump", comp).head_coeff = mag
    elif kind == "overflow":
        m.tank(comp).overflow = Overflow(to="T4", volume=mag)
    elif kind == "spill":
        area = m.tank(comp).area
        m.links.append(Link("spill", from_=comp, to="T4", coeff=mag * area, law="orifice", exponent=1.0,
                            min_level=SPILL_RIM / area))
    elif kind == "valve":
        m.find("valve", comp).characteristic = mag
    elif kind == "flowlaw":
        m.find("link", comp).exponent = mag
    elif kind == "sensorchar":
        s = m.find("sensor", comp)
        s.exponent = mag
        s.gain = 5.0 ** (1.0 - mag)          # calibrated at 5 L: exact there, bent elsewhere
    elif kind == "sensorquad":
        s = m.find("sensor", comp)
        s.curvature, s.pivot = mag, 5.0
    elif kind == "deadzone":
        m.find("pump", comp).input_offset = mag
    elif kind == "split":
        m.tank(comp).overflow = Overflow(to="T4", volume=split_rim(comp), fraction=mag, rest="outside")
    elif kind == "saturation":
        m.find("sensor", comp).max = mag
    elif kind == "closure":
        x = m.find("pump" if comp.startswith("P") else "link", comp)
        x.closure, x.onset = mag, ONSET
    return m


def sweep_case(job) -> dict:
    import numpy as np

    from civic.diagnose.fit import diagnose
    from civic.plant.control import run_closed_loop
    from civic.plant.model import PlantModel
    from civic.plant.simulate import Recording

    case, mag, seed, via_pcap = job
    nominal = PlantModel.from_toml(ROOT / "configs" / "plant.toml")
    plant = sweep_plant(nominal, case, mag, seed)
    schedule = None
    if case.startswith("spill") or case == "split_T2":
        # the bundled case's setpoints (T2 up to 8.75 L): random ones rarely pass the 8.5 L rim
        from civic.plant.control import schedule_from_operation

        truth = json.loads((ROOT / "traces" / "diagnose" / "example_leak_t3" / "truth.json").read_text())
        schedule = schedule_from_operation(truth["operation"])
    res = run_closed_loop(plant, 600.0, controller=os.environ.get("CIVIC_BENCH_CONTROLLER", "mpc"), seed=seed,
                          noise=True, controller_model=nominal,
                          schedule=schedule)
    if via_pcap:
        # as the hidden cases are called: the run written to a pcap, read back by `civic diagnose`'s loader
        from civic.diagnose import data
        from civic.plant.simulate import unreadable_lines, write_recording

        with tempfile.TemporaryDirectory() as tmp:
            write_recording(f"{tmp}/case.pcap", nominal, res.t, res.signals)
            rec = data.load(f"{tmp}/case.pcap", nominal)
        left_out = unreadable_lines(rec)   # what the loader left out: a simulated run should have none
    else:
        rec = Recording(res.t, res.signals, res.fields, case)
        left_out = []
    d = diagnose(nominal, rec)
    want = SWEEP[case][:2] if case in SWEEP else OFF_GRID_KINDS[case]
    active = True
    if case.startswith("overflow"):
        active = bool(np.max(res.volumes[:, 0]) >= mag - 1e-9)
    elif case.startswith("split"):
        rim = split_rim(want[1])
        active = bool(np.max(res.volumes[:, nominal.tank_names.index(want[1])]) >= rim - 1e-9)
    elif case.startswith("spill"):
        active = bool(np.max(res.volumes[:, nominal.tank_names.index(want[1])]) > SPILL_RIM + 0.05)
    elif case.startswith("saturation"):
        active = bool(np.any(res.signals[want[1]] >= mag - 1e-9))
    named = [(f["mechanism"].name, f["mechanism"].component) for f in d.findings]
    # right: the first finding names the mechanism and component, and nothing else is found
    ok = (not d.mismatch) if want[0] is None or not active else named[:1] == [want] and len(named) == 1
    if ok and want[0] == "leak":     # and where the water goes, and since when
        p = d.findings[0]["fit"].mechanisms[-1].values()
        ok = p["to"] == ("outside" if case.endswith("_out") else "T4")
        named[0] += (p["to"],)
        if case.startswith("leakon"):
            ok = ok and p.get("not_before", -1.0) <= ONSET <= p.get("not_after", -1.0) and "until" not in p
            named[0] += (f"from {p.get('since', 0.0):g} s ({p.get('not_before', 0.0):g}-{p.get('not_after', 0.0):g})",)
        elif case.startswith("repaired"):
            ok = ok and "since" not in p and _ended(p, REPAIRED_AT)
            named[0] += (_until(p),)
        else:
            ok = ok and "since" not in p and "until" not in p
    if ok and want[0] == "sensor_offset":   # from the start, or since when
        p = d.findings[0]["fit"].mechanisms[-1].values()
        if case.startswith(("shift", "drift", "glitch")):
            at = {"shift": SHIFT_AT, "drift": DRIFT_FROM, "glitch": SPELL[0]}[case.partition("_")[0]]
            ok = p.get("not_before", -1.0) <= at <= p.get("not_after", -1.0) and ("drift" in p) == case.startswith("drift")
            ok = ok and (_ended(p, SPELL[1]) if case.startswith("glitch") else "until" not in p)
            named[0] += (("drifting " if "drift" in p else "") + f"from {p.get('since', 0.0):g} s "
                         f"({p.get('not_before', 0.0):g}-{p.get('not_after', 0.0):g})"
                         + (f" {_until(p)}" if "until" in p else ""),)
        elif case.startswith("righted"):
            ok = "since" not in p and _ended(p, REPAIRED_AT)
            named[0] += (_until(p),)
        else:
            ok = "since" not in p and "until" not in p
    if ok and want[0] == "closure":  # and since when (and until when)
        p = d.findings[0]["fit"].mechanisms[-1].values()
        on = SPELL[0] if case.startswith("spell") else ONSET
        ok = p.get("not_before", -1.0) <= on <= p.get("not_after", -1.0)
        ok = ok and (_ended(p, SPELL[1]) if case.startswith("spell") else "until" not in p)
        named[0] += (f"from {p.get('onset', 0.0):g} s ({p.get('not_before', 0.0):g}-{p.get('not_after', 0.0):g})"
                     + (f" {_until(p)}" if "until" in p else ""),)
    return {"case": case, "mag": mag, "seed": seed, "active": active, "ok": ok and not left_out,
            "findings": named + left_out,
            "flagged": d.loc.flagged, "effect": replay_change(plant, sweep_plant(nominal, "clean", 0.0, seed), res),
            "excess": replay_change(plant, d.model_calibrated, res)}


def _ended(p: dict, at: float) -> bool:
    """A finding switched off again, with `at` in the bracket of when."""
    return p.get("until_not_before", -1.0) <= at <= p.get("until_not_after", -1.0)


def _until(p: dict) -> str:
    return f"until {p.get('until', 0.0):g} s ({p.get('until_not_before', 0.0):g}-{p.get('until_not_after', 0.0):g})"


def replay_change(plant, other, res) -> float:
    """How far `other` replays from the real plant: the largest RMS difference, over the level
    sensors, of the two open-loop simulations on the applied inputs from the true initial state,
    in units of that sensor's noise. Against the same plant without the effect: the effect's size
    (the issue's bar is 3); against the diagnosis's calibrated datasheet model: what is left of
    it once the datasheet's coefficients are calibrated."""
    import numpy as np

    from civic.plant.simulate import simulate

    x0 = {n: float(v) for n, v in zip(plant.tank_names, res.volumes[0])}
    inputs = {k: res.signals[k] for k in plant.input_names}
    a, b = simulate(plant, res.t, inputs, x0), simulate(other, res.t, inputs, x0)
    return max(float(np.sqrt(np.mean((a[s.name] - b[s.name]) ** 2))) / s.noise_sigma
               for s in plant.sensors if s.noise_sigma > 0)


def robustness(seeds: list[int], cases: list[str] | None = None, quiet: bool = False,
               off_grid: bool = False, via_pcap: bool = False) -> int:
    from collections import defaultdict
    from multiprocessing import Pool

    grid = OFF_GRID if off_grid else {c: mags for c, (_, _, mags) in SWEEP.items()}
    jobs = [(c, mag, s, via_pcap) for c, mags in grid.items() if not cases or c in cases for mag in mags for s in seeds]

    rates = defaultdict(lambda: [0, 0, 0, 0])
    with Pool(int(os.environ.get("CIVIC_BENCH_PROCS", "2"))) as pool:
        for r in pool.imap_unordered(sweep_case, jobs):
            k = rates[(r["case"], r["mag"])]
            if not r["active"]:
                k[2] += 1
            else:
                k[0] += r["ok"]
                k[1] += 1
                k[3] += not r["ok"] and r["case"] != "clean" and r["excess"] < EXCESS_BAR
            if quiet and r["ok"]:
                continue
            print(f"{'ok ' if r['ok'] else 'BAD'} {r['case']} {r['mag']:g} seed {r['seed']}"
                  f"{'' if r['active'] else ' (inactive)'}: {r['findings'] or 'no finding'}"
                  f"  [replay: effect {r['effect']:.1f} sigma, {r['excess']:.1f} beyond calibration]", flush=True)
    for title, new in (("catalogue families (closed-loop four-tank)", False),
                       ("real-rig physics on the closed-loop four-tank plant (issue #20)", True)):
        rows = [(k, v) for k, v in sorted(rates.items()) if (k[0].split("_")[0] in NEW_KINDS) == new]
        if not rows:
            continue
        print(f"\n{title}: right mechanism and component first, nothing else found (clean: no alarm)")
        for (case, mag), (good, n, idle, below) in rows:
            print(f"  {case:16s} {mag:6g}: {good}/{n}" + (f" ({idle} inactive)" if idle else "")
                  + (f" ({below} missed below the {EXCESS_BAR:g} sigma bar)" if below else ""))
    return 0


# ---------------------------------------------------------------------------------------
# Cascaded Tanks transfer: fit on one half of the estimation record, score on the other
# ---------------------------------------------------------------------------------------
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


if __name__ == "__main__":
    mode, args = (sys.argv[1], sys.argv[2:]) if len(sys.argv) > 1 else (None, [])
    if mode is None:
        sys.exit(main())
    if mode in ("-h", "--help"):
        print(__doc__)
    elif mode == "--transfer":
        transfer(offsets=[int(o) for o in args[0].split(",")] if args else (0,))
    elif mode == "--structures":
        transfer_structures(args[0].split(";") if args else None)
    elif mode == "--robustness" and args:
        rest = [a for a in args[1:] if a not in ("--off-grid", "--via-pcap")]
        sys.exit(robustness([int(s) for s in args[0].split(",")], rest[0].split(",") if rest else None,
                            off_grid="--off-grid" in args, via_pcap="--via-pcap" in args))
    else:
        sys.exit(f"bench_diagnose: unknown arguments {' '.join(sys.argv[1:])!r} (--help lists the modes)")
