"""Where `civic replay --target model` spends its time: each step of replay_stream, timed on a
1 M-message capture of two interleaved plants (best of 5), as in docs/performance.md.

python -m bench.profile_replay
"""
from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from bench.bench_replay import N_MESSAGES, make_capture, train_entries

STEPS = ("read + record offsets", "parser (plant mask)", "switch kernel (incl. verdict + checksum)",
         "events + counts", "write")
REPEAT = 5


def profile(path: Path, entries, out: Path) -> dict:
    from civic.events import event
    from civic.pcap_chunks import PcapChunks
    from civic.pipeline.stream import StreamingSwitch, changes

    names = [m.name for m in entries.monitors]
    spent = dict.fromkeys(STEPS, 0.0)
    switch = StreamingSwitch(entries)
    chunks = PcapChunks(path, entries.udp_port, entries.plant_prefix)
    with open(out, "wb") as fh:
        fh.write(chunks.header)
        it = iter(chunks)
        while True:
            t0 = time.perf_counter()
            chunk = next(it, None)
            t1 = time.perf_counter()
            if chunk is None:
                break
            plant = chunk.plant
            t2 = time.perf_counter()
            rows = switch.process(chunk.buf, chunk.offset, plant)
            t3 = time.perf_counter()
            _ = int(np.count_nonzero(plant))
            if len(rows):
                t = chunk.times(rows[:, 0])
                _ = [event(c, t[j], names) for j, c in enumerate(changes(rows, chunk.heads["src"], chunk.heads["seq"]))]
            t4 = time.perf_counter()
            fh.write(chunk.records())
            t5 = time.perf_counter()
            for step, took in zip(STEPS, (t1 - t0, t2 - t1, t3 - t2, t4 - t3, t5 - t4)):
                spent[step] += took
    return spent


def main() -> None:
    from civic.entries import load_entries

    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        entries = load_entries(train_entries(tmp / "entries.json"))
        make_capture(tmp / "in.pcap", N_MESSAGES)
        profile(tmp / "in.pcap", entries, tmp / "out.pcap")             # compiled and warm
        runs = [profile(tmp / "in.pcap", entries, tmp / "out.pcap") for _ in range(REPEAT)]
    best = {s: min(r[s] for r in runs) for s in STEPS}
    total = sum(best.values())
    print(f"| step ({N_MESSAGES} messages) | ms | share |\n|---|---:|---:|")
    for s in STEPS:
        print(f"| {s} | {best[s] * 1e3:.0f} | {best[s] / total:.0%} |")
    print(f"| total | {total * 1e3:.0f} | {N_MESSAGES / total / 1e6:.2f} M msg/s |")


if __name__ == "__main__":
    main()
