"""`civic watch` on a real simple_switch_grpc (BMv2): digests become the model's events, the switch's
counters the output capture's verdict counts, and a Prometheus scrape shows the same numbers."""
from __future__ import annotations

import asyncio
import json
import os
import re
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import numpy as np
import pytest

from civic.wire import CLASS_CODES, OFF_VERDICT, int_to_ip, monitor_verdict, read_pcap
from frames import changing_fleet
from needs import BMV2
from waiting import wait_lines

pytestmark = BMV2

ROOT = Path(__file__).resolve().parents[2]
ENV = {**os.environ, "COLUMNS": "200"}


def civic(*argv) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "civic", *map(str, argv)], capture_output=True, text=True,
                          cwd=ROOT, env=ENV)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def scrape(port: int) -> dict:
    text = urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=5).read().decode()
    out = {}
    for line in text.splitlines():
        m = re.match(r"^(civic_\w+)(\{[^}]*\})? (\S+)$", line)
        if m:
            labels = tuple(sorted(re.findall(r'(\w+)="([^"]*)"', m.group(2) or "")))
            out[(m.group(1), labels)] = float(m.group(3))
    return out


def read_tags(endpoint: str, cells) -> dict:
    """{(plant, monitor): (Class, ClassCode, Normal, Warning, Error)} read with asyncua's client."""
    from asyncua import Client

    async def read():
        async with Client(endpoint) as client:
            ns = await client.get_namespace_index("urn:civic")
            out = {}
            for plant, monitor in cells:
                node = await client.nodes.objects.get_child([f"{ns}:Plants", f"{ns}:{plant}", f"{ns}:{monitor}"])
                out[(plant, monitor)] = tuple([await (await node.get_child(f"{ns}:{n}")).read_value()
                                               for n in ("Class", "ClassCode", "Normal", "Warning", "Error")])
            return out
    return asyncio.run(read())


def verdicts_key(cls: str, monitor: str, plant: str) -> tuple:
    return ("civic_verdicts_total", (("class", cls), ("monitor", monitor), ("plant", plant)))


def expected_counts(out: list[bytes], src: np.ndarray, names: list[str]) -> dict:
    """{civic_verdicts_total key: n}: the verdicts written into the frames that came out of the switch."""
    verdicts = np.array([int.from_bytes(f[OFF_VERDICT:OFF_VERDICT + 2], "big") for f in out])
    counted = {}
    for k, name in enumerate(names):
        code = monitor_verdict(verdicts, k)
        for plant in np.unique(src):
            for cls, c in CLASS_CODES.items():
                counted[verdicts_key(cls, name, int_to_ip(int(plant)))] = int(np.sum((src == plant) & (code == c)))
    return counted


def without_t(events):
    return [{k: v for k, v in e.items() if k != "t"} for e in events]


@pytest.fixture
def switch():
    from civic.switch.bmv2 import BMv2Switch
    with BMv2Switch(None, controller=False) as sw:
        yield sw


def test_watch_reports_the_switchs_digests_counters_and_metrics(switch, v1model_build, trained_entries, tmp_path):
    entries = tmp_path / "entries.json"
    trained_entries.save(entries)
    capture = changing_fleet(tmp_path / "fleet.pcap", plants=6)
    res = civic("replay", capture, "-o", tmp_path / "model.pcap", "--entries", entries,
                "--events", tmp_path / "model.jsonl")
    assert res.returncode == 0, res.stderr
    want = [json.loads(ln) for ln in (tmp_path / "model.jsonl").read_text().splitlines()]
    drain = [e for e in want if e["monitor"] == "drain_t3"]
    assert len(drain) == 18 and sum(e["from"] is not None for e in drain) == 12   # every plant changes twice
    assert len(want) > 18            # the balance monitors judge the drain tests too (and see the clogs)

    res = civic("configure", "--switch", switch.address, "--entries", entries, "--pipeline", v1model_build)
    assert res.returncode == 0, res.stderr
    port = free_port()
    opcua = f"opc.tcp://127.0.0.1:{free_port()}/civic"
    events = tmp_path / "watch.jsonl"
    watch = subprocess.Popen([sys.executable, "-m", "civic", "watch", "--switch", switch.address,
                              "--entries", entries, "--events", events, "--metrics-port", str(port),
                              "--duration", "120", "--plot", tmp_path / "timeline.png", "--opcua", opcua],
                             cwd=ROOT, env=ENV, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 30
        while True:                                   # ready when the metrics endpoint answers
            try:
                scrape(port)
                break
            except OSError:
                assert watch.poll() is None, watch.communicate()
                assert time.monotonic() < deadline, "civic watch did not start"
                time.sleep(0.2)
        cap = read_pcap(capture)
        out = switch.send_frames([cap.frame(i) for i in range(len(cap))], frame_timeout=1.0)
        assert all(f is not None for f in out)
        wait_lines(events, len(want), 20.0, "the watch's events from the switch's digests")
        counted = expected_counts(out, read_pcap(capture).messages["src"], [m.name for m in trained_entries.monitors])
        deadline = time.monotonic() + 30             # counters are polled every second, however loaded the machine
        while True:
            metrics = scrape(port)
            if all(metrics.get(k, 0.0) == n for k, n in counted.items()) or time.monotonic() > deadline:
                break
            time.sleep(0.5)
        last = {(e["plant"], e["monitor"]): e["to"] for e in want}
        tagged = {(plant, monitor): (cls, CLASS_CODES[cls], *[counted[verdicts_key(c, monitor, plant)]
                                                               for c in ("normal", "warning", "error")])
                  for (plant, monitor), cls in last.items()}
        while True:                                   # the tags follow the counts within COUNTS_S
            tags = read_tags(opcua, set(last))
            if tags == tagged or time.monotonic() > deadline:
                break
            time.sleep(0.5)
    finally:
        watch.send_signal(signal.SIGINT)              # Ctrl-C ends it cleanly
        stdout, stderr = watch.communicate(timeout=20)
    assert watch.returncode == 0, stderr
    assert "Traceback" not in stderr and f"stopped: {len(want)} verdict changes from 6 plants" in stderr

    got = [json.loads(ln) for ln in events.read_text().splitlines()]
    assert without_t(got) == without_t(want)          # t: when the digest arrived, not capture time
    assert (tmp_path / "timeline.png").stat().st_size > 10_000

    # the switch's counters == the verdicts in what came out of the switch
    for key, n in counted.items():
        assert metrics.get(key, 0.0) == n, key
    assert metrics[("civic_events_total", ())] == len(want)
    assert metrics[("civic_last_digest_age_seconds", ())] >= 0
    assert metrics[("civic_switch_up", ())] == 1
    for (plant, monitor), cls in last.items():
        assert metrics[("civic_class", (("monitor", monitor), ("plant", plant)))] == CLASS_CODES[cls]
    # the same over OPC UA: the class of the last digest and the switch's counters
    for cell, value in tagged.items():
        assert tags[cell] == value, cell


def test_watch_an_unreachable_switch_is_one_line(tmp_path):
    res = civic("watch", "--switch", "127.0.0.1:1", "--timeout", "1", "--duration", "1")
    assert res.returncode == 2 and len(res.stderr.strip().splitlines()) == 1, res.stderr
    assert "cannot reach switch 127.0.0.1:1" in res.stderr and "Traceback" not in res.stderr


def test_watch_a_switch_without_civics_pipeline_is_one_line(switch, tmp_path):
    def one_line(res, words):
        assert res.returncode == 2 and len(res.stderr.strip().splitlines()) == 1, res.stderr
        assert words in res.stderr and "Traceback" not in res.stderr, res.stderr

    one_line(civic("watch", "--switch", switch.address, "--duration", "1"), "runs no pipeline")
    from civic.switch.connection import SwitchConnection
    from civic.switch.pipeline import load_pipeline
    from civic.switch.bmv2 import compile_v1model
    compile_v1model(ROOT / "bench" / "p4" / "forward.p4", tmp_path / "fwd")
    pipe = load_pipeline(tmp_path / "fwd")
    with SwitchConnection(switch.address) as conn:
        conn.set_pipeline(pipe.get_pipeline_config())
    one_line(civic("watch", "--switch", switch.address, "--duration", "1"),
             "not a CIVIC pipeline with verdict digests")
