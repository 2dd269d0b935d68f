"""Against a real BMv2 only: configure entries/s and BMv2 replay messages/s vs the software model."""
from __future__ import annotations

import os
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def main() -> None:
    missing = [t for t in ("p4c-bm2-ss", "simple_switch_grpc") if shutil.which(t) is None]
    if missing or os.geteuid() != 0:
        why = f"{' and '.join(missing)} not on PATH" if missing else "needs root (network namespace)"
        print(f"configure / BMv2 replay: skipped ({why})")
        return
    from civic.bmv2 import BMv2Switch
    from civic.config import load_monitors
    from civic.pipeline import SwitchModel
    from civic.train import collect_runs, read_labels, train
    from civic.wire import read_pcap

    training = ROOT / "traces" / "training"
    config = load_monitors()
    entries = train(collect_runs(training, read_labels(training / "labels.csv"), config, "lsq"), config, "lsq", True)
    with tempfile.TemporaryDirectory() as tmp:
        build = Path(tmp) / "build"
        build.mkdir()
        subprocess.run(["p4c-bm2-ss", "--std", "p4-16", "--arch", "v1model", "-o", str(build / "civic.json"),
                        "--p4runtime-files", str(build / "civic.p4info.txtpb"),
                        str(ROOT / "p4src" / "v1model" / "civic.p4")], check=True)
        path = Path(tmp) / "entries.json"
        entries.save(path)
        cap = read_pcap(ROOT / "traces" / "diagnose" / "example_none" / "case.pcap")
        with BMv2Switch(build) as sw:
            t0 = time.perf_counter()
            result = sw.configure(path)
            conf_s = time.perf_counter() - t0
            frames = [cap.frame(i) for i in range(len(cap))]
            t0 = time.perf_counter()
            sw.send_frames(frames)
            bmv2_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    SwitchModel(entries).run(cap.messages)
    model_s = time.perf_counter() - t0
    n_entries = result.added + result.modified
    print(f"configure: {n_entries} entries in {conf_s:.2f} s = {n_entries / conf_s:.0f} entries/s")
    print(f"BMv2 replay (lockstep): {len(frames) / bmv2_s:.0f} msg/s; software model {len(frames) / model_s:.0f} msg/s "
          f"(ratio {bmv2_s / model_s:.0f}x)")


if __name__ == "__main__":
    main()
