"""Recordings for diagnosis: a pcap in wire format or a CSV, in model signal names.

Reading is `civic.plant.simulate.load_recording` (pcap: one plant's messages,
`--plant IP` or the first; CSV: a time column + wire fields or model signal
names). Here only checks and the uniform grid (lost messages) are added.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from civic.errors import CivicError
from civic.plant.model import PlantModel
from civic.plant.simulate import Recording, load_recording

PCAP_MAGICS = (0xA1B2C3D4, 0xA1B23C4D, 0xD4C3B2A1, 0x4D3CB2A1, 0x0A0D0D0A)


def is_pcap(path: str | Path) -> bool:
    try:
        with open(path, "rb") as fh:
            head = fh.read(4)
    except OSError:
        return False
    return len(head) == 4 and int.from_bytes(head, "little") in PCAP_MAGICS


def load(path: str | Path, model: PlantModel, plant: str | None = None) -> Recording:
    """Load RECORDING for `model`; checks that its inputs and at least one sensor are there."""
    path = str(path)
    if not Path(path).exists():
        raise CivicError(f"{path}: no such file")
    if not is_pcap(path):
        if plant is not None:
            raise CivicError("--plant applies to pcap recordings only")
        if not path.endswith(".csv"):
            raise CivicError(f"{path}: neither a pcap nor a .csv recording")
    return check(load_recording(path, model, plant=plant), model)


def check(rec: Recording, model: PlantModel) -> Recording:
    n = len(rec.t)
    if n < 20:
        raise CivicError(f"{rec.path}: only {n} samples, too few to diagnose")
    missing = [k for k in model.input_names if k not in rec.signals]
    if missing:
        raise CivicError(f"{rec.path}: recording lacks the model's input(s) {', '.join(missing)}")
    if not any(s in rec.signals for s in model.signal_names):
        raise CivicError(f"{rec.path}: recording has none of the model's sensors "
                         f"({', '.join(model.signal_names)})")
    dt = np.diff(rec.t)
    if np.any(dt <= 0):
        raise CivicError(f"{rec.path}: time stamps are not increasing")
    med = float(np.median(dt))
    if abs(med - model.dt) > 0.05 * model.dt:
        raise CivicError(f"{rec.path}: sample time {med:g} s differs from the model's dt = {model.dt:g} s")
    for k, v in rec.signals.items():
        if not np.all(np.isfinite(v)):
            raise CivicError(f"{rec.path}: signal {k} has NaN/infinite values")
    return regularise(without_unreadable(rec, model), model.dt)


BEYOND_TANK = 1.5    # a reading this far beyond all the water its tank can hold is a fault code


def without_unreadable(rec: Recording, model: PlantModel) -> Recording:
    """The recording without the samples in which a sensor reads what no tank can hold: the top of
    its wire range (0xFFFF, a sensor's fault code) or more than BEYOND_TANK times its tank's
    capacity (or the circuit's water), or as far below zero. Those samples are left out as lost
    messages are; `rec.unreadable` says which, per sensor. Errors when more than half are."""
    bad = np.zeros(len(rec.t), bool)
    unreadable = []
    for s in model.sensors:
        if s.name not in rec.signals or s.quantity != "volume":
            continue
        tank = model.tank(s.tank)
        hold = min(tank.capacity, model.total_volume or np.inf) * BEYOND_TANK * s.gain
        v = np.asarray(rec.signals[s.name], float)
        mask = (v - s.offset > hold) | (v - s.offset < -hold)
        if s.wire and s.wire in (rec.fields or {}):
            mask |= np.asarray(rec.fields[s.wire]) >= 0xFFFF
        if mask.any():
            at = rec.t[mask]
            unreadable.append({"signal": s.name, "samples": int(mask.sum()), "from_s": round(float(at[0]), 3),
                               "to_s": round(float(at[-1]), 3), "values": sorted({float(x) for x in v[mask]})[:5]})
            bad |= mask
    if bad.sum() > len(bad) // 2:
        raise CivicError(f"{rec.path}: more than half of the samples have a sensor reading beyond any tank "
                         f"({', '.join(u['signal'] for u in unreadable)})")
    if not bad.any():
        rec.unreadable = []
        return rec
    keep = ~bad
    out = Recording(rec.t[keep], {k: np.asarray(v)[keep] for k, v in rec.signals.items()},
                    {k: np.asarray(v)[keep] for k, v in (rec.fields or {}).items()}, rec.path)
    out.unreadable = unreadable
    return out


SHORT_GAP = 2     # samples: a run of lost messages this short is interpolated, not a gap


def regularise(rec: Recording, dt: float) -> Recording:
    """Put the samples on the uniform grid k*dt. Missing samples (lost messages): a run of up to
    SHORT_GAP is interpolated linearly in the signals (the fields hold their last value); longer
    runs hold the last value and are flagged in `rec.gaps` (the comparisons ignore them). Every
    5 s balance window touching a flagged sample is left out: with 1 % of the messages lost one
    by one, that was 40 % of them."""
    k = np.rint(np.asarray(rec.t, float) / dt).astype(np.int64)
    k -= k[0]
    n = int(k[-1]) + 1
    if n == len(k) and np.all(np.diff(k) == 1):
        rec.gaps = np.zeros(n, bool)
        return rec
    keep = np.concatenate(([True], np.diff(k) > 0))      # duplicates: first one wins
    k = k[keep]
    if n > 4 * len(k):
        raise CivicError(f"{rec.path}: more than 3/4 of the samples are missing")
    src = np.searchsorted(k, np.arange(n), side="right") - 1  # last received sample
    grid = np.arange(n)
    run = np.diff(k)[np.minimum(src, len(k) - 2)] - 1          # length of the run a sample is in
    gaps = np.ones(n, bool)
    gaps[k] = False
    short = gaps & (run <= SHORT_GAP)
    gaps &= ~short
    signals = {}
    for name, v in rec.signals.items():
        v = np.asarray(v, float)[keep]
        signals[name] = np.where(short, np.interp(grid, k, v), v[src])
    fields = {name: np.asarray(v)[keep][src] for name, v in (rec.fields or {}).items()}
    out = Recording(grid * dt, signals, fields, rec.path)
    out.gaps = gaps
    out.unreadable = getattr(rec, "unreadable", [])
    return out


def measured(rec: Recording, model: PlantModel) -> list[str]:
    """The model's sensors present in the recording, in model order."""
    return [s for s in model.signal_names if s in rec.signals]
