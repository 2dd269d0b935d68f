"""Replay recordings through a switch target and write them back with verdicts."""
from __future__ import annotations

from pathlib import Path

import numpy as np
from rich.progress import Progress

from civic.entries import Entries
from civic.errors import CivicError
from civic.pipeline import SwitchModel
from civic.wire import Capture, read_pcap


def replay_model(capture: Capture, entries: Entries) -> np.ndarray:
    """Verdicts of a freshly reset software switch for every frame of a capture."""
    return SwitchModel(entries).run(capture.messages)


def replay_files(inputs: list[Path], outputs: list[Path], entries: Entries, entries_path: str,
                 target: str = "model", pipeline: str = "build/v1model") -> dict:
    """Each input through a freshly reset switch; output frames in order, verdicts written."""
    stats = {"frames": 0, "plant": 0, "evaluated": 0}
    captures = []
    with Progress(transient=True) as progress:
        task = progress.add_task("replaying", total=len(inputs))
        for src, dst in zip(inputs, outputs):
            cap = read_pcap(src, entries.udp_port, entries.plant_prefix)
            if target == "model":
                cap.set_verdicts(replay_model(cap, entries))
                cap.write(dst)
            else:
                captures.append((cap, dst))
            stats["frames"] += len(cap)
            stats["plant"] += int(cap.messages["plant"].sum())
            stats["evaluated"] += int(np.count_nonzero(cap.messages["verdict"][cap.messages["plant"]]))
            progress.advance(task)
    if target == "bmv2":
        stats["evaluated"] = replay_on_bmv2(captures, entries_path, pipeline)
    return stats


def replay_on_bmv2(captures: list[tuple[Capture, Path]], entries_path: str, pipeline: str) -> int:
    try:
        from civic.bmv2 import replay_bmv2
    except ImportError as exc:
        raise CivicError(f"the bmv2 target is not available: {exc}") from exc
    evaluated = 0
    for cap, dst in captures:
        frames = replay_bmv2(cap, entries_path, pipeline)
        Path(dst).write_bytes(frames)
        evaluated += 0
    return evaluated
