"""The BMv2 replay target.

`test_bmv2_matches_model` is the real thing: it compiles p4src/v1model/civic.p4
with p4c-bm2-ss, runs simple_switch_grpc and checks every output frame is
byte-identical to the software model. It is skipped unless both tools are on
PATH and we are root.

The plumbing tests run `civic.switch.bmv2` against a *stand-in process* (a small
Python script installed as `simple_switch_grpc` on a temporary PATH; it is not
a switch and computes no verdicts): it serves the P4Runtime servicer fixture
of tests/switch/p4rt_servicer.py on the address it is given and copies frames from port 1
to port 2, flipping one byte and dropping broadcast frames. That checks the
namespace, the control link, the packet sockets, lockstep ordering, reporting
of frames that were not forwarded, and clean-up, without BMv2.
"""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from civic.errors import CivicError

pytestmark = pytest.mark.bmv2

ROOT = Path(__file__).resolve().parents[2]
TESTS = Path(__file__).resolve().parents[1]
FIXTURE_P4INFO = TESTS / "fixtures" / "civic.p4info.txtpb"
IS_ROOT = hasattr(os, "geteuid") and os.geteuid() == 0
HAVE_IP = shutil.which("ip") is not None
HAVE_BMV2 = shutil.which("p4c-bm2-ss") is not None and shutil.which("simple_switch_grpc") is not None

needs_netns = pytest.mark.skipif(not (IS_ROOT and HAVE_IP and sys.platform == "linux"),
                                 reason="needs root and iproute2 on Linux (network namespaces)")


def netns_names() -> set:
    out = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True).stdout
    return {line.split()[0] for line in out.splitlines() if line.strip()}


def host_links() -> set:
    out = subprocess.run(["ip", "-o", "link", "show"], capture_output=True, text=True).stdout
    return {line.split(":")[1].strip().split("@")[0] for line in out.splitlines()}


def entries_json(tmp_path) -> Path:
    from switch.p4rt_servicer import entries_file
    return entries_file(tmp_path)


# ---------------------------------------------------------------- stand-in process
STAND_IN = textwrap.dedent('''\
    #!{python}
    # Stand-in for simple_switch_grpc in tests/switch/test_bmv2.py: NOT a switch.
    import os, socket, sys, threading, time
    from concurrent import futures
    sys.path.insert(0, {tests!r})
    if "--help" in sys.argv:
        print("stand-in usage: --thrift-port --device-id -i --no-p4"); sys.exit(0)
    with open(os.environ["STAND_IN_PIDFILE"], "a") as f:
        f.write(f"{{os.getpid()}}\\n")
    if os.environ.get("STAND_IN_FAIL"):
        print("Error: stand-in refuses to start (test)", flush=True); sys.exit(3)
    import grpc
    from finsy.proto import p4r_grpc as p4runtime_pb2_grpc
    from switch.p4rt_servicer import P4RuntimeFixture
    ports = dict(a.split("@") for a in [sys.argv[i + 1] for i, x in enumerate(sys.argv) if x == "-i"])
    addr = sys.argv[sys.argv.index("--grpc-server-addr") + 1]
    fx = P4RuntimeFixture(None)
    fx.canonical_only = False                    # current PI: canonical or full-width byte strings
    fx.register_support = False                  # PI has no P4Runtime register access (p4lang/PI#376)
    server = grpc.server(futures.ThreadPoolExecutor(max_workers=4))
    p4runtime_pb2_grpc.add_P4RuntimeServicer_to_server(fx, server)
    server.add_insecure_port(addr)
    server.start()
    rx = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, socket.htons(3)); rx.bind((ports["1"], 0))
    tx = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, 0); tx.bind((ports["2"], 0))
    print("stand-in ready", addr, flush=True)
    while True:
        data, meta = rx.recvfrom(65535)
        if meta[2] == 4 or data[0] == 0xFF:      # outgoing, or broadcast: not forwarded
            continue
        if len(data) >= 62:
            data = data[:61] + bytes([data[61] ^ 0x5A]) + data[62:]
        if data[0] == 0xEE:                      # "bug": a byte a switch must never change
            data = data[:30] + bytes([data[30] ^ 1]) + data[31:]
        tx.send(data)
''')


@pytest.fixture
def stand_in(tmp_path, monkeypatch):
    bindir = tmp_path / "bin"
    bindir.mkdir()
    exe = bindir / "simple_switch_grpc"
    exe.write_text(STAND_IN.format(python=sys.executable, tests=str(TESTS)))
    exe.chmod(0o755)
    pidfile = tmp_path / "pids"
    pidfile.write_text("")
    monkeypatch.setenv("PATH", f"{bindir}{os.pathsep}{os.environ['PATH']}")
    monkeypatch.setenv("STAND_IN_PIDFILE", str(pidfile))
    build = tmp_path / "build"
    build.mkdir()
    (build / "civic.json").write_text('{"stand-in": true}')
    (build / "civic.p4info.txtpb").write_text(FIXTURE_P4INFO.read_text())
    return build, pidfile


@pytest.fixture
def made(monkeypatch):
    """The BMv2Switch objects started during the test (to check their namespace is gone)."""
    from civic.switch.bmv2 import BMv2Switch
    started = []
    orig = BMv2Switch.start

    def spy(self):
        started.append(self)
        return orig(self)

    monkeypatch.setattr(BMv2Switch, "start", spy)
    return started


def left_behind(switches) -> list:
    """Namespaces / host links of these switches that still exist (other test runs may add their own)."""
    ns, links = netns_names(), host_links()
    return [s.netns for s in switches if s.netns in ns] + [s.host_if for s in switches if s.host_if in links]


def alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    # a zombie is not running either
    try:
        return Path(f"/proc/{pid}/stat").read_text().split()[2] != "Z"
    except OSError:
        return False


@needs_netns
def test_plumbing_order_missing_and_cleanup(stand_in, tmp_path, made):
    from frames import plant

    from civic.switch.bmv2 import replay_bmv2
    from civic.wire import read_pcap, write_pcap

    build, pidfile = stand_in
    frames = [bytes(plant(seq=i + 1, l3=5000 + i)) for i in range(12)]
    frames.insert(5, b"\xff" * 6 + frames[0][6:])                  # broadcast: the stand-in drops it
    frames.append(bytes(plant(seq=99)) + b"\xee" * 7)              # trailer bytes survive
    frames.append(b"\xee" + frames[1][1:])                          # the stand-in corrupts this one
    write_pcap(tmp_path / "a.pcap", np.arange(len(frames)) * 0.1, frames)
    write_pcap(tmp_path / "b.pcapng", np.arange(5) * 0.1,                # + no Ethernet header, jumbo frame
               frames[:3] + [b"\x02" * 10, frames[2] + b"\x00" * 30000])
    caps = [read_pcap(tmp_path / "a.pcap"), read_pcap(tmp_path / "b.pcapng")]

    t0 = time.monotonic()
    out = replay_bmv2(caps, entries_json(tmp_path), build, frame_timeout=0.3, startup_timeout=15)
    assert time.monotonic() - t0 < 10     # the corrupted frame costs a short grace, not a timeout

    assert [o.missing for o in out] == [[5], [3]]
    for o, cap in zip(out, caps):
        for i in range(len(cap)):
            sent = cap.frame(i)
            if i in o.missing:
                assert o.frames[i] is None
                continue
            want = sent[:61] + bytes([sent[61] ^ 0x5A]) + sent[62:]
            if sent[0] == 0xEE:
                want = want[:30] + bytes([want[30] ^ 1]) + want[31:]
            assert o.frames[i] == want, i                          # in input order, byte for byte
    a = out[0].capture
    assert len(a) == len(caps[0]) - 1 and a.frame(len(a) - 2).endswith(b"\xee" * 7)
    assert np.array_equal(a.messages["t"], np.delete(caps[0].messages["t"], 5))
    assert np.array_equal(a.messages["verdict"][:5], np.full(5, 0x5A))
    b = out[1].capture                                              # rebuilt without the lost frame, as pcapng
    assert bytes(b.data[:4]) == b"\x0a\x0d\x0d\x0a" and len(b) == 4 and b.frame(3) == out[1].frames[4]
    # nothing left behind
    assert len(made) == 1 and left_behind(made) == []
    pids = [int(p) for p in pidfile.read_text().split()]
    assert len(pids) == 1 and not alive(pids[0])


@needs_netns
def test_stand_in_that_dies_is_reported_and_cleaned_up(stand_in, tmp_path, monkeypatch, made):
    from civic.switch.bmv2 import replay_bmv2
    build, _ = stand_in
    monkeypatch.setenv("STAND_IN_FAIL", "1")
    with pytest.raises(CivicError, match=r"simple_switch_grpc exited with status 3: Error: stand-in refuses"):
        replay_bmv2([], entries_json(tmp_path), build, startup_timeout=10)
    assert len(made) == 1 and made[0].netns.startswith("civic-") and left_behind(made) == []


def test_missing_switch_binary_is_one_line_error(tmp_path, monkeypatch):
    from civic.switch.bmv2 import replay_bmv2
    build = tmp_path / "build"
    build.mkdir()
    (build / "civic.json").write_text("{}")
    (build / "civic.p4info.txtpb").write_text(FIXTURE_P4INFO.read_text())
    monkeypatch.setenv("PATH", str(tmp_path))
    with pytest.raises(CivicError, match="simple_switch_grpc not found on PATH"):
        replay_bmv2([], entries_json(tmp_path), build)


# ---------------------------------------------------------------- real BMv2
def needs_bmv2(test):
    test = pytest.mark.skipif(not IS_ROOT, reason="BMv2 needs root (network namespace)")(test)
    return pytest.mark.skipif(not HAVE_BMV2, reason="p4c-bm2-ss and simple_switch_grpc not both on PATH")(test)


def civic_cli(*argv, check=True) -> subprocess.CompletedProcess:
    res = subprocess.run([sys.executable, "-m", "civic", *map(str, argv)], capture_output=True, text=True,
                         cwd=ROOT)
    if check:
        assert res.returncode == 0, res.stderr
    return res


@pytest.fixture(scope="module")
def bmv2_inputs(tmp_path_factory, trained_entries):
    """Entries and every capture the switch must get right: recordings, edge cases, two 64-plant fleets."""
    from frames import changing_fleet, cooked, edge_frames, junk_frames, mixed_pcapng, plant, sequence_edges

    from civic.wire import write_pcap

    d = tmp_path_factory.mktemp("bmv2_inputs")
    trained_entries.save(d / "entries.json")
    crafted, extra = [], junk_frames() + edge_frames()
    for i, frame in enumerate(sequence_edges()):            # plant messages with junk in between
        crafted.append(frame)
        if i % 3 == 0:
            crafted.append(extra[(i // 3) % len(extra)])
    crafted += extra + [bytes(plant(seq=1000, l3=4000, v2=1000)) + b"\x00" * 6]       # Ethernet trailer
    write_pcap(d / "edges.pcap", np.arange(len(crafted)) * 0.01, crafted)
    civic_cli("simulate", "drain", "--plants", "64", "--seed", "100", "-o", d / "fleet_drain.pcap")
    civic_cli("simulate", "fill", "--plants", "64", "--seed", "200", "-o", d / "fleet_fill.pcap")
    changing_fleet(d / "fleet_changing.pcap", plants=12)
    # Linux cooked captures (tcpdump -i any): the switch gets their Ethernet views
    cooked(ROOT / "traces" / "training" / "fill_error_r1.pcap", d / "cooked_sll.pcap", 1)
    mixed_pcapng(d / "edges.pcap", d / "edges_mixed_sll2.pcapng")
    # 64 plants in closed-loop operation, faults switched on mid-run (fault-free, VM1 and VM2 in turn)
    civic_cli("simulate", "closed-loop", "--controller", "pi", "--plants", "64", "--duration", "100",
              "--onset", "30", "--seed", "300", "-o", d / "fleet_closed_loop.pcap")
    caps = sorted((ROOT / "traces" / "training").glob("*.pcap")) + sorted(
        (ROOT / "traces" / "continuous").glob("*.pcap")) + [d / "fleet_closed_loop.pcap", d / "edges.pcap",
                                                             d / "fleet_drain.pcap", d / "fleet_fill.pcap",
                                                             d / "fleet_changing.pcap", d / "cooked_sll.pcap",
                                                             d / "edges_mixed_sll2.pcapng"]
    return d / "entries.json", caps


@needs_bmv2
def test_bmv2_output_is_byte_identical_to_model(tmp_path, bmv2_inputs, v1model_build):
    """civic replay --target bmv2 and --target model write the same bytes, file for file, and the
    same verdict-change events (BMv2's from its digests)."""
    entries, caps = bmv2_inputs
    civic_cli("replay", *caps, "-o", tmp_path / "model", "--entries", entries, "--target", "model",
              "--events", tmp_path / "model.jsonl")
    res = civic_cli("replay", *caps, "-o", tmp_path / "bmv2", "--entries", entries, "--target", "bmv2",
                    "--pipeline", v1model_build, "--events", tmp_path / "bmv2.jsonl")
    events = (tmp_path / "model.jsonl").read_text()
    assert events == (tmp_path / "bmv2.jsonl").read_text()
    assert events.count("\n") > 30 + 128 + 24 and '"from": "warning"' in events
    assert "did not come out" not in res.stdout
    from civic.wire import read_pcap
    for cap in caps:
        model, bmv2 = (tmp_path / "model" / cap.name).read_bytes(), (tmp_path / "bmv2" / cap.name).read_bytes()
        if model != bmv2:
            a, b = read_pcap(tmp_path / "model" / cap.name), read_pcap(tmp_path / "bmv2" / cap.name)
            first = next((i for i in range(min(len(a), len(b))) if a.frame(i) != b.frame(i)), min(len(a), len(b)))
            pytest.fail(f"{cap.name}: BMv2 differs from the model first at frame {first} "
                        f"({len(a)} model frames, {len(b)} BMv2 frames)")
    # the crafted cases really exercise the switch: verdicts given, and junk left alone
    inp, out = read_pcap(next(c for c in caps if c.name == "edges.pcap")), read_pcap(tmp_path / "bmv2" / "edges.pcap")
    assert np.count_nonzero(out.messages["verdict"]) > 20
    changed = [i for i in range(len(inp)) if inp.frame(i) != out.frame(i)]
    assert all(out.messages["plant"][i] for i in changed)
    # cooked captures keep their link headers and get the verdicts of their Ethernet frames
    mixed = read_pcap(tmp_path / "bmv2" / "edges_mixed_sll2.pcapng")
    assert set(mixed.link.tolist()) == {1, 276}
    assert all(np.array_equal(mixed.messages[k], out.messages[k]) for k in ("plant", "verdict", "udp_csum"))
    sll = read_pcap(tmp_path / "bmv2" / "cooked_sll.pcap")
    assert set(sll.link.tolist()) == {113} and np.count_nonzero(sll.messages["verdict"]) > 100
    fleet = read_pcap(tmp_path / "bmv2" / "fleet_drain.pcap").messages
    assert len(np.unique(fleet["src"][fleet["verdict"] > 0])) == 64
    # the balance monitors gave verdicts on every closed-loop plant, and warnings/errors on some
    loop = read_pcap(tmp_path / "bmv2" / "fleet_closed_loop.pcap").messages
    balance = (loop["verdict"] >> 4) & 0xF
    assert len(np.unique(loop["src"][balance > 0])) == 64
    assert np.any(((loop["verdict"] >> 4) & 3) > 1) and np.any(((loop["verdict"] >> 6) & 3) > 1)


@needs_netns
def test_sigterm_during_replay_still_cleans_up(stand_in, tmp_path):
    """A replay killed with SIGTERM removes its namespace and (stand-in) switch process like any other failure."""
    build, pidfile = stand_in
    script = tmp_path / "run.py"
    script.write_text(textwrap.dedent(f"""\
        import sys
        sys.path.insert(0, {str(ROOT)!r})
        from civic.switch.bmv2 import BMv2Switch
        with BMv2Switch({str(build)!r}, startup_timeout=15) as sw:
            print(sw.netns, sw.host_if, flush=True)
            sys.stdin.readline()          # wait to be killed
        """))
    proc = subprocess.Popen([sys.executable, str(script)], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                            text=True, env=os.environ.copy())
    netns, host_if = proc.stdout.readline().split()
    assert netns in netns_names() and host_if in host_links()
    proc.terminate()
    assert proc.wait(timeout=15) == 128 + 15
    assert netns not in netns_names() and host_if not in host_links()
    pids = [int(p) for p in pidfile.read_text().split()]
    assert len(pids) == 1 and not alive(pids[0])


@pytest.mark.skipif(shutil.which("p4c-bm2-ss") is None, reason="p4c-bm2-ss not on PATH")
def test_pipeline_is_built_when_missing_or_older_than_the_source(tmp_path):
    from civic.switch.bmv2 import P4_SOURCE, build_pipeline
    assert P4_SOURCE == ROOT / "p4src"                         # the default: the checkout's sources
    src = tmp_path / "p4src"
    shutil.copytree(ROOT / "p4src", src)
    build = tmp_path / "build"
    assert build_pipeline(build, src) and (build / "civic.json").is_file()
    assert (build / "civic.p4info.txtpb").read_text().count("CivicIngress.mon0.classify") >= 1
    assert not build_pipeline(build, src)                     # up to date: left alone
    os.utime(src / "tna" / "civic.p4")                         # another target's source: still up to date
    assert not build_pipeline(build, src)
    later = (build / "civic.json").stat().st_mtime + 5
    os.utime(src / "shared" / "headers.p4", (later, later))
    assert build_pipeline(build, src)
