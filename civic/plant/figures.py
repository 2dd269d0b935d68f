"""Figures for the docs: simulated drain tests next to recorded ones.

python -m civic.plant.figures  ->  docs/img/drain_sim_vs_recorded.png
"""
from __future__ import annotations

from pathlib import Path


ROOT = Path(__file__).resolve().parents[2]


def save_figure(fig, path, title: str | None = None, dpi: int = 110) -> None:
    """tight_layout + savefig + close; an unwritable path is a one-line CivicError."""
    import matplotlib.pyplot as plt

    from civic.errors import CivicError

    if title is not None:
        fig.suptitle(title)
    fig.tight_layout()
    try:
        fig.savefig(path, dpi=dpi)
    except OSError as exc:
        raise CivicError(f"cannot write {path}: {exc.strerror}") from exc
    finally:
        plt.close(fig)


def drain_sim_vs_recorded(path=ROOT / "docs" / "img" / "drain_sim_vs_recorded.png", run: str = "r1") -> Path:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from civic.plant.model import PlantModel
    from civic.plant.procedures import FAULT_CLASSES, lsq_slopes, make_procedure, run_procedure
    from civic.plant.simulate import load_recording

    model = PlantModel.from_toml(ROOT / "configs" / "plant.toml")
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4.2))
    for i, (cls, c) in enumerate(FAULT_CLASSES["drain"].items()):
        rec = load_recording(ROOT / "traces" / "training" / f"drain_v075_{cls}_{run}.pcap", model)
        sim = run_procedure(make_procedure(model, "drain", 7.5, {"vm1": c}), noise=False)
        col = f"C{i}"
        a1.plot(rec.t, rec.signals["L3"], ".", ms=2.5, color=col, alpha=0.5)
        a1.plot(sim["t"], sim["L3"], "-", color=col, lw=1.6, label=f"{cls} (VM1 {c:.2f})")
        for sig, style in ((rec.signals, "."), (sim, "-")):
            s = lsq_slopes(sig["L3"], 20, model.dt)
            ok = (sig["v2"] >= 0.8) & (sig["L3"] > 3.0)
            a2.plot(sig["L3"][ok], s[ok] * 1000, style, color=col, ms=2.5, lw=1.6,
                    alpha=0.5 if style == "." else 1.0)
    a1.set_xlabel("t (s)")
    a1.set_ylabel("L3 (L)")
    a1.set_title("Drain test: recorded (dots) vs simulated (lines)")
    a1.axvline(3.0, color="0.6", lw=0.8, ls="--")
    a1.legend(fontsize=8)
    a2.set_xlabel("L3 (L)")
    a2.set_ylabel("20-sample LSQ slope of L3 (mL/s)")
    a2.set_title("Monitor slope vs level (drain_t3 window)")
    a2.invert_xaxis()
    fig.suptitle("civic simulate (datasheet model, configs/plant.toml) vs traces/training", fontsize=10)
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return Path(path)


if __name__ == "__main__":
    print(drain_sim_vs_recorded())
