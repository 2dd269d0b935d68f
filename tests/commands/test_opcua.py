"""civic monitor --opcua on live frames: an OPC UA client in the same network namespace, asyncua's
(Python) or node-opcua's (JavaScript, another stack), browses Plants/<ip>/<monitor>, subscribes to
every Class and to the verdict-change events, and sees the changes civic replay --events gives for
the same frames, in order."""
from __future__ import annotations

import json
import shutil
import signal
import subprocess
import sys
import time
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import pytest

from civic.pipeline.stream import StreamingSwitch
from civic.wire import read_pcap, write_pcap
from data import ROOT, TRAINING
from frames import interleave
import veth
from waiting import wait_lines

pytestmark = pytest.mark.skipif(veth.why_not() is not None, reason=veth.why_not() or "")

ENDPOINT = "opc.tcp://127.0.0.1:4840/civic"
TESTS = Path(__file__).resolve().parents[1]
NODE_CLIENT = TESTS / "opcua_node"
CLIENTS = {"asyncua": [sys.executable, str(TESTS / "opcua_client.py")],
           "node-opcua": ["node", str(NODE_CLIENT / "client.js")]}
NODE = [pytest.mark.opcua_node,
        pytest.mark.skipif(not (shutil.which("node") and (NODE_CLIENT / "node_modules" / "node-opcua-client").is_dir()),
                           reason="node and tests/opcua_node/node_modules (make test runs npm ci there) needed")]
CONTINUOUS = ROOT / "traces" / "continuous"
SEVERITY = {"normal": 100, "warning": 500, "error": 900}


def split(pcap: Path, at: int) -> tuple[Path, Path]:
    """Frames [:at] and [at:] as two captures."""
    cap = read_pcap(pcap)
    t = cap.messages["t"]
    out = []
    for part, rows in (("a", range(at)), ("b", range(at, len(cap)))):
        path = pcap.with_name(f"{pcap.stem}-{part}.pcap")
        write_pcap(path, t[list(rows)], [cap.frame(i) for i in rows])
        out.append(path)
    return out[0], out[1]


def replay_events(pcap: Path, entries: Path, out: Path) -> list[dict]:
    subprocess.run([sys.executable, "-m", "civic", "replay", str(pcap), "-o", str(out.with_name(out.stem + "-out.pcap")),
                    "--entries", str(entries), "--events", str(out)], check=True, capture_output=True)
    return [json.loads(line) for line in open(out)]


def result_line(out: str) -> str:
    """The client's JSON result: node-opcua may log notices to stdout, before it or after it."""
    lines = [line for line in out.splitlines() if line.startswith('{"changes"')]
    assert lines, "the client printed no result:\n" + out
    return lines[-1]


def cell(ev: dict) -> str:
    return f"{ev['plant']}/{ev['monitor']}"


def alarm(ev: dict) -> list | None:
    """The event the server raises for a change (None: none)."""
    if ev["to"] == "normal" and ev["from"] in (None, "normal"):
        return None
    text = f"{ev['plant']} {ev['monitor']}: {ev['from'] or 'none'} -> {ev['to']}"
    return [SEVERITY[ev["to"]], text + (" (cleared)" if ev["to"] == "normal" else ""), ev["plant"], ev["monitor"],
            ev["from"] or "none", ev["to"]]


@pytest.mark.parametrize("stack", ["asyncua", pytest.param("node-opcua", marks=NODE)])
def test_a_subscribed_client_sees_every_change_in_order_and_the_model_counts(stack, trained_entries, tmp_path):
    entries = tmp_path / "entries.json"
    trained_entries.save(entries)
    runs = [[TRAINING / f"drain_v075_{c}.pcap" for c in ("error_r3", "normal_r1", "warning_r2", "error_r1")],
            [TRAINING / f"fill_{c}.pcap" for c in ("warning_r2", "normal_r3", "error_r2", "normal_r4")],
            [CONTINUOUS / "cl_fault_free.pcap", CONTINUOUS / "cl_vm1_error_onset420.pcap"]]
    both = interleave(runs, tmp_path, name="runs.pcap")        # each plant a run of recordings, one after another
    once = read_pcap(interleave([r[0] for r in runs], tmp_path, name="once.pcap"))
    at = int(np.searchsorted(read_pcap(both).messages["t"], once.messages["t"].max(), side="right"))
    rec, rest = split(both, at)           # the first recording of each plant, then the others
    first = replay_events(rec, entries, tmp_path / "first.jsonl")
    want = replay_events(both, entries, tmp_path / "twice.jsonl")
    assert want[:len(first)] == first
    second = want[len(first):]
    names = [m.name for m in trained_entries.monitors]
    plants = sorted({e["plant"] for e in first})
    cells = [f"{p}/{m}" for p in plants for m in names]     # every plant has every monitor, from its first message
    assert {cell(e) for e in want} < set(cells) and len(second) > 5           # some monitors never judge a plant
    (tmp_path / "cells.json").write_text(json.dumps(cells))

    got_events = tmp_path / "got.jsonl"
    with veth.VethPair() as pair:
        monitor = pair.popen(sys.executable, "-m", "civic", "monitor", "--iface", pair.b, "--entries", str(entries),
                             "--opcua", ENDPOINT, "--events", str(got_events), "--duration", "120",
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        client = None
        try:
            line = monitor.stderr.readline()
            assert line.startswith("monitoring") and f"OPC UA on {ENDPOINT}" in line, line + monitor.stderr.read()
            pair.send(rec, rate=20000)
            # the monitor writes each line before it hands the change to the OPC UA server; a
            # client subscribing earlier would see 'none' first
            wait_lines(got_events, len(first), 60.0, "the monitor's events")
            client = pair.popen(*CLIENTS[stack], ENDPOINT, str(tmp_path / "cells.json"),
                                stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
            lines = iter(client.stdout.readline, "")       # node-opcua may print notices first
            assert any(line.strip() == "subscribed" for line in lines), "the client ended before subscribing"
            pair.send(rest, rate=20000)
            wait_lines(got_events, len(want), 60.0, "the monitor's events")
            time.sleep(2.5)                            # counts: every 1 s from the switch, 0.25 s to the tags
            out, err = client.communicate("done\n", timeout=60)
            assert client.returncode == 0, err
        finally:
            if client is not None and client.poll() is None:
                client.kill()
            monitor.send_signal(signal.SIGINT)
            _, merr = monitor.communicate(timeout=60)
    assert monitor.returncode == 0, merr
    assert "0 dropped" in merr, merr
    seen = json.loads(result_line(out))

    # every change of the second pass, per (plant, monitor) in order, after the value the first pass left
    for c in cells:
        before = ([e["to"] for e in first if cell(e) == c] or ["none"])[-1]
        assert seen["changes"][c] == [before] + [e["to"] for e in second if cell(e) == c], c
    # alarm events: one per change into warning or error and per return to normal, in order
    assert seen["events"] == [a for a in map(alarm, second) if a is not None]
    assert any(a[0] == 900 for a in seen["events"]) and any(a[0] == 100 for a in seen["events"])

    # final tags: the last change and the model's verdict counts
    live = [json.loads(line) for line in open(got_events)]
    assert [{k: v for k, v in e.items() if k != "t"} for e in live] == [{k: v for k, v in e.items() if k != "t"}
                                                                        for e in want]
    switch = StreamingSwitch(trained_entries)
    switch.run_capture(read_pcap(both))                   # the model's counts over both parts
    for c in cells:
        tags = seen["final"][c]
        plant, name = c.split("/")
        slot, m = int(plant.rsplit(".", 1)[1]), names.index(name)
        if not any(cell(e) == c for e in live):             # never judged: there, with no verdict
            assert (tags["Class"], tags["ClassCode"], tags["Normal"], tags["Warning"], tags["Error"]) == \
                ("none", 0, 0, 0, 0) and not switch.counts[m, slot].any()
            continue
        last = [e for e in live if cell(e) == c][-1]
        assert (tags["Class"], tags["ClassCode"]) == (last["to"], {"normal": 1, "warning": 2, "error": 3}[last["to"]])
        assert (tags["Slope"], tags["Level"]) == (last["slope"], last["level"])
        since = datetime.fromisoformat(tags["Since"].replace("Z", "+00:00")).replace(tzinfo=timezone.utc).timestamp()
        assert abs(since - last["t"]) < (1e-5 if stack == "asyncua" else 1e-3)     # a JS Date holds ms
        assert [tags["Normal"], tags["Warning"], tags["Error"]] == [int(switch.counts[m, slot, k]) for k in (1, 2, 3)]
        assert sum(switch.counts[m, slot, 1:]) > 0
