"""Recordings for diagnosis: a pcap in wire format or a CSV, in model signal names.

Reading is `civic.plant.simulate.load_recording` (pcap: one plant's messages,
`--plant IP` or the first; CSV: a time column + wire fields or model signal
names). Here checks, the uniform grid (lost messages, `regularise`) and fault codes are added.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from civic.errors import CivicError
from civic.plant.model import PlantModel
from civic.plant.simulate import Recording, load_recording, regularise

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
    return with_unreadable_marked(regularise(rec, model.dt), model)


BEYOND_TANK = 1.5    # a reading this far beyond all the water its tank can hold is a fault code
BEYOND_RANGE = 0.05  # a command this share of its range beyond it is no command


def with_unreadable_marked(rec: Recording, model: PlantModel) -> Recording:
    """Mark the samples in which a sensor reads what no tank can hold: the top of its wire range
    (0xFFFF, a sensor's fault code) or more than BEYOND_TANK times its tank's capacity (or the
    circuit's water), or as far below zero. The comparisons ignore them as they ignore lost
    messages (`rec.gaps`), and the sensor's value there is interpolated from its readable
    neighbours; the inputs were received, so unlike lost messages (`rec.lost`) they do not stop
    an open-loop replay. `rec.unreadable` says which sensor, how many samples, when and what it
    read. A command beyond its range by BEYOND_RANGE of it (6553.5 % is 0xFFFF) says nothing of
    what was applied: those samples count as lost messages, the last readable command held.
    Errors when more than half of the samples of a signal are unreadable."""
    bad = np.zeros(len(rec.t), bool)
    rec.unreadable = []

    def note(name, mask, v, beyond):
        at = rec.t[mask]
        rec.unreadable.append({"signal": name, "samples": int(mask.sum()), "beyond": beyond,
                               "from_s": round(float(at[0]), 3), "to_s": round(float(at[-1]), 3),
                               "values": sorted({float(x) for x in v[mask]})[:5]})
    for s in model.sensors:
        if s.name not in rec.signals or s.quantity != "volume":
            continue
        hold = min(model.tank(s.tank).capacity, model.total_volume or np.inf) * BEYOND_TANK * s.gain
        v = np.asarray(rec.signals[s.name], float)
        mask = np.abs(v - s.offset) > hold
        if s.wire and s.wire in (rec.fields or {}):
            mask |= np.asarray(rec.fields[s.wire]) >= 0xFFFF
        if not mask.any():
            continue
        if mask.sum() > len(mask) // 2:
            raise CivicError(f"{rec.path}: sensor {s.name} reads beyond its tank in more than half of the samples")
        note(s.name, mask, v, "its tank")
        rec.signals[s.name] = np.where(mask, np.interp(rec.t, rec.t[~mask], v[~mask]), v)
        bad |= mask
    lost = rec.gaps.copy()
    for i in model.inputs:
        if i.name not in rec.signals or i.min is None or i.max is None:
            continue
        v = np.asarray(rec.signals[i.name], float)
        slack = BEYOND_RANGE * (i.max - i.min)
        mask = (v > i.max + slack) | (v < i.min - slack)
        if not mask.any():
            continue
        if mask.sum() > len(mask) // 2:
            raise CivicError(f"{rec.path}: input {i.name} is beyond its range in more than half of the samples")
        note(i.name, mask, v, "its range")
        last = np.maximum.accumulate(np.where(mask, -1, np.arange(len(v))))    # the last readable command
        rec.signals[i.name] = v[np.where(last < 0, np.argmin(mask), last)]
        lost |= mask
    rec.lost = lost
    rec.gaps = lost | bad
    return rec


def measured(rec: Recording, model: PlantModel) -> list[str]:
    """The model's sensors present in the recording, in model order."""
    return [s for s in model.signal_names if s in rec.signals]
