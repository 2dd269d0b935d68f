"""`civic diagnose` speed on 10 Hz closed-loop recordings: 10 min (target < 10 s) and 60 min (< 60 s).

The recordings are made with the closed-loop plant simulator (MPC designed on the
nominal model, plant with a concealed T3 leak and a few % calibration spread), written
to a pcap and diagnosed through the CLI code path (load, diagnose, report, no plot).

Run: python bench/bench_diagnose.py  (or `python -m bench`). Prints one line per case.
"""
from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

TARGETS = {600.0: 10.0, 3600.0: 60.0}


def make_recording(path: Path, duration: float, seed: int = 5) -> None:
    from civic.plant.control import run_closed_loop
    from civic.plant.model import Link, PlantModel
    from civic.plant.simulate import to_wire
    from civic.wire import build_frames, write_pcap

    nominal = PlantModel.from_toml(ROOT / "configs" / "plant.toml")
    plant = nominal.copy()
    plant.set("pump.P1.gain", 0.30 * 1.03)
    plant.set("link.V2.coeff", 0.30 * 0.98)
    plant.links.append(Link("leak", from_="T3", to="T4", coeff=0.012, law="orifice"))
    res = run_closed_loop(plant, duration, controller="mpc", seed=seed, noise=True, controller_model=nominal)
    fields = to_wire(nominal, res.signals)
    cols = ("l1", "l2", "l3", "l4", "p1", "v1", "v2")
    write_pcap(path, 1767225600.0 + res.t, build_frames({c: fields[c] for c in cols}))


def time_diagnose(path: Path) -> tuple[float, dict]:
    from civic.diagnose import data
    from civic.diagnose.fit import diagnose
    from civic.diagnose.report import build_report
    from civic.plant.model import PlantModel

    t0 = time.perf_counter()
    model = PlantModel.from_toml(ROOT / "configs" / "plant.toml")
    rec = data.load(path, model)
    diag = diagnose(model, rec)
    rep = build_report(diag, rec)
    return time.perf_counter() - t0, rep


def main() -> int:
    ok = True
    with tempfile.TemporaryDirectory() as tmp:
        for duration, target in TARGETS.items():
            path = Path(tmp) / f"closed_loop_{int(duration)}s.pcap"
            make_recording(path, duration)
            el, rep = time_diagnose(path)
            found = ", ".join(f"{f['mechanism']} {f['component']}" for f in rep["findings"]) or "none"
            status = "ok" if el < target else "SLOW"
            ok &= el < target
            print(f"diagnose {duration / 60:4.0f} min @ 10 Hz ({int(duration * 10)} messages): "
                  f"{el:6.2f} s (target < {target:g} s, {status}); findings: {found}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
