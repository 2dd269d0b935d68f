"""civic monitor on live frames: the rate it sustains without loss, next to offline replay.

A capture is sent into one end of a veth pair (in a network namespace of its own) while
`civic monitor` captures the other end; the rate is plant messages taken / sending time, for
a run in which the kernel dropped nothing. Sent paced, from fast to slow, until a run is
lossless. Needs root (skipped otherwise).
"""
from __future__ import annotations

import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))        # the veth helper the tests use
import veth  # noqa: E402

from bench.bench_replay import make_capture, train_entries  # noqa: E402

MESSAGES = 300_000
RATES = (0, 400_000, 200_000, 100_000, 50_000)          # 0: as fast as the sender goes


def monitor_run(pair, capture: Path, entries: Path, rate: float) -> tuple[float, int, int]:
    """(send rate reached, plant messages the monitor took, kernel drops) of one run."""
    proc = pair.popen(sys.executable, "-m", "civic", "monitor", "--iface", pair.b, "--entries", str(entries),
                      "--duration", str(MESSAGES / max(rate, 100_000) + 8), stdout=subprocess.DEVNULL,
                      stderr=subprocess.PIPE, text=True)
    if not proc.stderr.readline().startswith("monitoring"):
        raise SystemExit(f"civic monitor did not start: {proc.stderr.read()}")
    sent = pair.send(capture, rate)
    err = proc.communicate()[1]
    m = re.search(r"\((\d+) plant messages\) in [\d.]+ s, (\d+) dropped", err)
    if proc.returncode or not m:
        raise SystemExit(f"civic monitor failed: {err}")
    return sent, int(m.group(1)), int(m.group(2))


def main() -> None:
    why = veth.why_not()
    if why:
        print(f"civic monitor: skipped ({why})")
        return
    from civic.entries import load_entries
    from civic.pipeline.stream import StreamingSwitch
    from civic.wire import read_pcap

    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        entries = train_entries(tmp / "entries.json")
        capture = tmp / "live.pcap"
        make_capture(capture, MESSAGES)
        cap = read_pcap(capture)
        switch = StreamingSwitch(load_entries(entries))
        switch.run_capture(read_pcap(capture))                  # compiled and warm
        t0 = time.perf_counter()
        switch.reset()
        switch.run_capture(cap)
        offline = len(cap) / (time.perf_counter() - t0)
        with veth.VethPair() as pair:
            for rate in RATES:
                sent, taken, drops = monitor_run(pair, capture, entries, rate)
                lossless = drops == 0 and taken == MESSAGES
                print(f"  sent {MESSAGES} at {sent / 1e3:.0f} k msg/s"
                      f"{' (sender flat out)' if not rate else ''}: took {taken}, kernel drops {drops}")
                if lossless:
                    break
    if lossless:
        print(f"civic monitor sustains {sent / 1e3:.0f} k msg/s without loss "
              f"{'(the sender is the limit)' if not rate else ''}; "
              f"offline streaming on the same capture: {offline / 1e6:.2f} M msg/s")
    else:
        print(f"civic monitor lost frames at every rate down to {RATES[-1] / 1e3:.0f} k msg/s")


if __name__ == "__main__":
    main()
