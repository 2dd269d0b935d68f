"""Replay recordings through a switch target and write them back with verdicts."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from civic.entries import Entries
from civic.events import digest_changes, event, place
from civic.pipeline import SwitchModel
from civic.report import progress_bar
from civic.wire import Capture, read_pcap


def with_verdict(capture: Capture) -> int:
    """How many plant messages of a capture carry a verdict."""
    msgs = capture.messages
    return int(np.count_nonzero(msgs["verdict"][msgs["plant"]]))


def replay_files(inputs: list[Path], outputs: list[Path], entries: Entries, entries_path: str,
                 target: str = "model", pipeline: str = "build/v1model", events: list | None = None) -> dict:
    """Each input through a freshly reset switch; output frames in order, verdicts written.

    events: a list that receives the verdict-change events (civic.events), inputs in order; on
    BMv2 they come from the switch's digests."""
    stats = {"frames": 0, "plant": 0, "evaluated": 0}
    names = [m.name for m in entries.monitors]
    captures = []
    with progress_bar() as progress:
        task = progress.add_task("replaying", total=len(inputs))
        for src, dst in zip(inputs, outputs):
            cap = read_pcap(src, entries.udp_port, entries.plant_prefix)
            stats["frames"] += len(cap)
            stats["plant"] += int(cap.messages["plant"].sum())
            if len(cap):
                stats["t_end"] = max(stats.get("t_end", 0.0), float(cap.messages["t"].max()))
            if target == "model":  # a freshly reset software switch per input
                msgs = cap.messages
                if events is None:
                    cap.set_verdicts(SwitchModel(entries).run(msgs))
                else:                    # the verdicts and their changes from one pass
                    verdicts, changes = SwitchModel(entries).run_with_changes(msgs)
                    events += [event(c, msgs["t"][c.index], names) for c in changes]
                    cap.set_verdicts(verdicts)
                cap.write(dst)
                stats["evaluated"] += with_verdict(cap)
            else:
                captures.append((cap, dst))
            progress.advance(task)
    if target == "bmv2":
        stats["evaluated"], stats["missing"] = replay_on_bmv2(captures, entries_path, pipeline, events, names)
    return stats


def replay_on_bmv2(captures: list[tuple[Capture, Path]], entries_path: str, pipeline: str,
                   events: list | None = None, names: list[str] = ()) -> tuple[int, int]:
    """All captures through one BMv2 switch (registers reset between captures); write the outputs."""
    from civic.switch.bmv2 import build_pipeline, replay_bmv2

    if build_pipeline(pipeline):
        print(f"compiled p4src/v1model/civic.p4 -> {pipeline}")
    with progress_bar() as progress:
        task = progress.add_task("BMv2", total=sum(len(c) for c, _ in captures))
        results = replay_bmv2([c for c, _ in captures], entries_path, pipeline,
                              progress=lambda n: progress.update(task, completed=n))
    evaluated = missing = 0
    for (cap, dst), res in zip(captures, results):
        if events is not None:
            msgs = cap.messages
            changes = place([digest_changes(d, len(names)) for d in res.digests], msgs)
            events += [event(c, msgs["t"][c.index], names) for c in changes]
        res.capture.write(dst)
        evaluated += with_verdict(res.capture)
        missing += len(res.missing)
    return evaluated, missing
