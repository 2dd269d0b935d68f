"""civic monitor --opcua with a 64-plant fleet: does the OPC UA server keep up in real time?

Each of 64 gateways runs a normal, a warning and an error drain test in turn (10 Hz each, 640
messages/s, every plant's class changing twice). The fleet is sent into a veth pair (a network
namespace of its own) at its real-time rate and 10x / 50x faster, while `civic monitor --opcua`
serves it and an asyncua client, subscribed to the verdict-change events on the Server object
before the first frame, records when each event arrives. Printed per speed: events expected (from
`civic replay --events`) and received, latency capture -> client (median, 99th percentile, max),
and the server's start: from `civic monitor` starting to a client's session, and the server's own
start() until it listens. Needs root (skipped otherwise).
"""
from __future__ import annotations

import json
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))        # the veth helper and the fleet the tests use
import veth  # noqa: E402

from bench.bench_replay import train_entries  # noqa: E402

PLANTS = 64
SPEEDS = (1, 10, 50)
ENDPOINT = "opc.tcp://127.0.0.1:4840/civic"

CLIENT = """
import asyncio, json, sys, time
from asyncua import Client, ua

class Got:
    def __init__(self): self.seen = []
    def event_notification(self, ev):
        self.seen.append((time.time(), ev.Time.timestamp(), ev.Plant, ev.Monitor, ev.To))

async def main(endpoint):
    client = Client(endpoint)
    t0 = time.time()
    while True:
        try:
            await client.connect()
            break
        except OSError:
            await asyncio.sleep(0.02)
    connected = time.time() - t0
    ns = await client.get_namespace_index("urn:civic")
    etype = await client.nodes.base_event_type.get_child(f"{ns}:CivicVerdictChangeEventType")
    got = Got()
    sub = await client.create_subscription(50, got)
    await sub.subscribe_events(client.get_node(ua.ObjectIds.Server), etype, queuesize=100000)
    print(json.dumps({"connected_after": connected}), flush=True)
    await asyncio.get_running_loop().run_in_executor(None, sys.stdin.readline)
    await asyncio.sleep(1.0)
    print(json.dumps({"seen": got.seen}), flush=True)
    await client.disconnect()

asyncio.run(main(sys.argv[1]))
"""


def run_speed(pair, fleet: Path, entries: Path, frames: int, span: float, speed: int) -> dict:
    started = time.time()
    monitor = pair.popen(sys.executable, "-m", "civic", "monitor", "--iface", pair.b, "--entries", str(entries),
                         "--opcua", ENDPOINT, "--duration", str(span / speed + 60), stdout=subprocess.DEVNULL,
                         stderr=subprocess.PIPE, text=True)
    client = pair.popen(sys.executable, "-c", CLIENT, ENDPOINT, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                        stderr=subprocess.PIPE, text=True)
    try:
        ready = json.loads(client.stdout.readline())
        to_session = time.time() - started
        line = monitor.stderr.readline()
        if not line.startswith("monitoring"):
            raise SystemExit(f"civic monitor did not start: {line}{monitor.stderr.read()}")
        pair.send(fleet, rate=frames / span * speed)
        client.stdin.write("done\n")
        client.stdin.flush()
        seen = json.loads(client.stdout.readline())["seen"]
    finally:
        for proc in (client, monitor):
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
        client.communicate(timeout=30)
        monitor.communicate(timeout=30)
    lat = np.array([recv - t for recv, t, *_ in seen]) if seen else np.array([np.nan])
    return {"received": len(seen), "seen": [tuple(s[2:]) for s in seen], "p50": np.median(lat),
            "p99": np.percentile(lat, 99), "max": lat.max(), "to_session": to_session,
            "connected_after": ready["connected_after"]}


def server_start_s(repeats: int = 3) -> float:
    """OpcUaServer start() until it listens, best of `repeats` (address space cached after the first)."""
    from civic.opcua import OpcUaServer
    from civic.watch import WatchState

    best = np.inf
    for _ in range(repeats):
        server = OpcUaServer("opc.tcp://127.0.0.1:48499/civic")
        t = time.perf_counter()
        server.start()
        server.serve(WatchState(["m0"]))
        best = min(best, time.perf_counter() - t)
        server.close()
    return best


def main() -> None:
    # civic monitor is stopped with SIGINT, a user's Ctrl-C. A bench started in the background of
    # a non-interactive shell ignores SIGINT and its children inherit that: the monitor then ran
    # on and the run failed after 30 s (as tests/conftest.py says for the tests). A handled
    # signal is reset to the default in a child.
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    why = veth.why_not()
    if why:
        print(f"civic monitor --opcua: skipped ({why})")
        return
    from civic.wire import read_pcap
    from frames import changing_fleet

    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        entries = train_entries(tmp / "entries.json")
        fleet = changing_fleet(tmp / "fleet.pcap", plants=PLANTS)
        cap = read_pcap(fleet)
        t = cap.messages["t"]
        span = float(t[-1] - t[0])
        subprocess.run([sys.executable, "-m", "civic", "replay", str(fleet), "-o", str(tmp / "out.pcap"),
                        "--entries", str(entries), "--events", str(tmp / "events.jsonl")], check=True,
                       capture_output=True)
        events = [json.loads(line) for line in open(tmp / "events.jsonl")]
        raised = [(e["plant"], e["monitor"], e["to"]) for e in events
                  if not (e["to"] == "normal" and e["from"] in (None, "normal"))]
        print(f"OPC UA server start until it listens: {server_start_s() * 1000:.0f} ms (best of 3)")
        print(f"fleet: {PLANTS} plants, {len(cap)} messages over {span:.0f} s ({len(cap) / span:.0f} msg/s), "
              f"{len(events)} verdict changes, {len(raised)} of them raise or clear an alarm event")
        with veth.VethPair() as pair:
            for speed in SPEEDS:
                r = run_speed(pair, fleet, entries, len(cap), span, speed)
                complete = sorted(r["seen"]) == sorted(raised)
                print(f"  {speed:>3}x real time ({len(cap) / span * speed:>6.0f} msg/s): events {r['received']}/"
                      f"{len(raised)}{'' if complete else ' (NOT the expected set)'}, latency capture -> client "
                      f"median {r['p50'] * 1000:.0f} ms, p99 {r['p99'] * 1000:.0f} ms, max {r['max'] * 1000:.0f} ms; "
                      f"session {r['to_session']:.2f} s after the command started")


if __name__ == "__main__":
    main()
