"""Recordings for diagnosis: a pcap in wire format or a CSV, in model signal names.

Reading is `civic.plant.simulate.load_recording` (pcap: one plant's messages,
`--plant IP` or the first; CSV: a time column + wire fields or model signal
names). Here checks are added; the uniform grid (lost messages) and fault codes are
`civic.plant.simulate`'s `regularise` and `with_unreadable_marked`, as `civic simulate --like` reads.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from civic.errors import CivicError
from civic.plant.model import PlantModel
from civic.plant.simulate import Recording, load_recording, regularise, with_unreadable_marked

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


def measured(rec: Recording, model: PlantModel) -> list[str]:
    """The model's sensors present in the recording, in model order."""
    return [s for s in model.signal_names if s in rec.signals]
