"""BMv2 only: replay msg/s of civic.p4 vs a port-forwarding program, pipelined vs lockstep, configure entries/s,
and on closed-loop operation what the balance monitors cost (civic.p4 with and without them).

Every figure is measured in this run, and every ratio is between two figures of
this run: the forwarding program (bench/p4/forward.p4) is the harness's and
BMv2's own cost, so civic.p4 / forward.p4 is what CIVIC's pipeline costs.
"""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PLANTS = 64


def timed_send(sw, frames, window) -> tuple[float, list]:
    t0 = time.perf_counter()
    out = sw.send_frames(frames, window=window)
    return time.perf_counter() - t0, out


def main() -> None:
    missing = [t for t in ("p4c-bm2-ss", "simple_switch_grpc") if shutil.which(t) is None]
    if missing or os.geteuid() != 0:
        why = f"{' and '.join(missing)} not on PATH" if missing else "needs root (network namespace)"
        print(f"BMv2 replay / configure: skipped ({why})")
        return
    from rich.console import Console

    from civic.switch.bmv2 import WINDOW, BMv2Switch, compile_v1model
    from civic.config import load_monitors
    from civic.entries import Entries
    from civic.pipeline import SwitchModel
    from civic.train import collect_runs, read_labels, train
    from civic.wire import read_pcap

    console = Console(stderr=True)
    training = ROOT / "traces" / "training"
    config = load_monitors()
    from civic.envelope import calibrated
    labels = read_labels(training / "labels.csv")
    entries = train(collect_runs(training, labels, config, "lsq"), config, "lsq", True,
                    calibrated(training, labels, config))         # civic train's default tables
    with tempfile.TemporaryDirectory() as tmp, console.status("BMv2 benchmark") as status:
        tmp = Path(tmp)
        civic_build, fwd_build = tmp / "civic", tmp / "forward"
        compile_v1model(ROOT / "p4src" / "v1model" / "civic.p4", civic_build)
        compile_v1model(ROOT / "bench" / "p4" / "forward.p4", fwd_build)
        path = tmp / "entries.json"
        entries.save(path)
        fleet = tmp / "fleet.pcap"
        subprocess.run([sys.executable, "-m", "civic", "simulate", "drain", "--plants", str(PLANTS), "--seed", "1",
                        "-o", str(fleet)], check=True, capture_output=True)
        cap = read_pcap(fleet)
        frames = [cap.frame(i) for i in range(len(cap))]
        expect = read_pcap(fleet)
        expect.set_verdicts(SwitchModel(entries).run(expect.messages))

        loop = tmp / "loop.pcap"
        subprocess.run([sys.executable, "-m", "civic", "simulate", "closed-loop", "--controller", "pi", "--plants",
                        str(PLANTS), "--duration", "40", "--onset", "10", "--seed", "2", "-o", str(loop)],
                       check=True, capture_output=True)
        loop_cap = read_pcap(loop)
        loop_frames = [loop_cap.frame(i) for i in range(len(loop_cap))]
        loop_expect = read_pcap(loop)
        loop_expect.set_verdicts(SwitchModel(entries).run(loop_expect.messages))
        tests_only = tmp / "tests_only.json"
        Entries(monitors=entries.monitors[:2], training=entries.training).save(tests_only)

        status.update("forward.p4")
        with BMv2Switch(fwd_build) as sw:
            fwd_s, _ = timed_send(sw, frames, WINDOW)
            loop_fwd_s, _ = timed_send(sw, loop_frames, WINDOW)
        status.update("civic.p4: configure")
        with BMv2Switch(civic_build) as sw:
            t0 = time.perf_counter()
            result = sw.configure(path)
            install_s = time.perf_counter() - t0
            t0 = time.perf_counter()
            again = sw.configure(path)
            noop_s = time.perf_counter() - t0
            status.update(f"civic.p4: {len(frames)} messages, {WINDOW} in flight")
            civic_s, out = timed_send(sw, frames, WINDOW)
            identical = all(out[i] == expect.frame(i) for i in range(len(frames)))
            sw.configure(path, reset=True)
            status.update(f"civic.p4: {len(frames)} messages, lockstep")
            lock_s, out1 = timed_send(sw, frames, 1)
            identical = identical and all(out1[i] == expect.frame(i) for i in range(len(frames)))
            status.update(f"civic.p4: closed loop, {len(loop_frames)} messages, every monitor")
            sw.configure(path, reset=True)
            loop_s, out2 = timed_send(sw, loop_frames, WINDOW)
            loop_identical = all(out2[i] == loop_expect.frame(i) for i in range(len(loop_frames)))
            status.update("civic.p4: closed loop, the test monitors only")
            sw.configure(tests_only, reset=True)
            loop_tests_s, _ = timed_send(sw, loop_frames, WINDOW)
    t0 = time.perf_counter()
    SwitchModel(entries).run(cap.messages)
    model_s = time.perf_counter() - t0

    n = len(frames)
    written = result.added + result.modified + result.unchanged
    checked = again.unchanged
    assert again.writes == 0, "the re-run wrote to the switch"
    print(f"{PLANTS}-plant capture, {n} messages; BMv2 output byte-identical with the model: {identical}")
    print(f"  forward.p4 (baseline), {WINDOW} in flight   {n / fwd_s:>9.0f} msg/s")
    print(f"  civic.p4, {WINDOW} in flight              {n / civic_s:>9.0f} msg/s   "
          f"= {fwd_s / civic_s:.2f}x the baseline (pipeline cost {civic_s / fwd_s:.1f}x)")
    print(f"  civic.p4, lockstep (1 in flight)      {n / lock_s:>9.0f} msg/s   "
          f"pipelined is {lock_s / civic_s:.2f}x lockstep")
    print(f"  software model (vectorized)           {n / model_s:>9.0f} msg/s   = {civic_s / model_s:.0f}x BMv2")
    m = len(loop_frames)
    print(f"{PLANTS}-plant closed-loop capture (faults switched on mid-run), {m} messages; BMv2 byte-identical "
          f"with the model: {loop_identical}")
    print(f"  forward.p4 (baseline), {WINDOW} in flight   {m / loop_fwd_s:>9.0f} msg/s")
    print(f"  civic.p4, test monitors only          {m / loop_tests_s:>9.0f} msg/s   "
          f"= {loop_fwd_s / loop_tests_s:.2f}x the baseline")
    print(f"  civic.p4, test + balance monitors     {m / loop_s:>9.0f} msg/s   "
          f"= {loop_fwd_s / loop_s:.2f}x the baseline; the balance monitors cost {loop_s / loop_tests_s:.2f}x")
    print(f"configure: full install {written} entries in {install_s:.2f} s = {written / install_s:.0f} entries/s; "
          f"no-op re-run ({checked} entries read and compared, nothing written) {noop_s:.2f} s "
          f"= {checked / noop_s:.0f} entries/s")


if __name__ == "__main__":
    main()
