"""Replay recordings through a switch target and write them back with verdicts."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from civic.entries import Entries
from civic.events import digest_changes, event, place
from civic.errors import CivicError
from civic.pcap_chunks import PcapChunks
from civic.pipeline.stream import StreamingSwitch, changes
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
        task = progress.add_task("replaying", total=sum(p.stat().st_size for p in inputs if p.exists()))
        for src, dst in zip(inputs, outputs):
            if target == "model":  # a freshly reset software switch per input, the file streamed
                add = replay_stream(src, dst, StreamingSwitch(entries), entries, events, names,
                                    lambda n: progress.advance(task, n))
                for k, v in add.items():
                    stats[k] = max(stats.get(k, v), v) if k == "t_end" else stats[k] + v
                continue
            cap = read_pcap(src, entries.udp_port, entries.plant_prefix)
            stats["frames"] += len(cap)
            stats["plant"] += int(cap.messages["plant"].sum())
            if len(cap):
                stats["t_end"] = max(stats.get("t_end", 0.0), float(cap.messages["t"].max()))
            captures.append((cap, dst))
            progress.advance(task, Path(src).stat().st_size)
    if target == "bmv2":
        stats["evaluated"], stats["missing"] = replay_on_bmv2(captures, entries_path, pipeline, events, names)
    return stats


def replay_stream(src: Path, dst: Path, switch: StreamingSwitch, entries: Entries, events: list | None = None,
                  names: list[str] = (), advance=lambda n: None) -> dict:
    """One recording through the streaming switch, chunk by chunk (bounded memory), into dst."""
    chunks = PcapChunks(src, entries.udp_port, entries.plant_prefix)
    stats = {"frames": 0, "plant": 0}
    index = 0
    last = None                                 # the last chunk that held frames
    try:
        out = open(dst, "wb")
    except OSError as exc:
        raise CivicError(f"cannot write {dst}: {exc.strerror}") from exc
    try:
        with out:
            out.write(chunks.header)
            advance(len(chunks.header))
            for chunk in chunks:
                plant = chunk.plant
                rows = switch.process(chunk.buf, chunk.offset, plant)
                out.write(chunk.records())
                stats["frames"] += len(chunk)
                stats["plant"] += int(np.count_nonzero(plant))
                if events is not None and len(rows):
                    heads = chunk.heads
                    t = chunk.times(rows[:, 0])
                    events += [event(c, t[j], names) for j, c in
                               enumerate(changes(rows, heads["src"], heads["seq"], index))]
                index += len(chunk)
                last = chunk if len(chunk) else last
                advance(chunk.end)
    except CivicError:                   # a corrupt or truncated input: no partial output left behind
        Path(dst).unlink(missing_ok=True)
        raise
    stats["evaluated"] = switch.given
    if last is not None:                        # records are in capture order: the end is in the last chunk
        stats["t_end"] = float(last.times().max())
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
