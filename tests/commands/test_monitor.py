"""civic monitor on live frames: a recording replayed into one end of a veth pair in a network
namespace, monitored at the other end, gives the verdicts and events of civic replay --target model."""
from __future__ import annotations

import json
import subprocess
import sys

import pytest

from civic.wire import read_pcap
from data import ROOT, TRAINING
from frames import interleave
import veth

pytestmark = pytest.mark.skipif(veth.why_not() is not None, reason=veth.why_not() or "")


def start(pair, *args) -> subprocess.Popen:
    """civic monitor inside the namespace, once it captures."""
    proc = pair.popen(sys.executable, "-m", "civic", "monitor", "--iface", pair.b, *args,
                      stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    line = proc.stderr.readline()
    assert line.startswith("monitoring"), line + proc.stderr.read()
    return proc


def finish(proc) -> str:
    """Its summary once --duration is up."""
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err
    return err


def without_t(path):
    return [{k: v for k, v in json.loads(line).items() if k != "t"} for line in open(path)]


@pytest.mark.parametrize("written", ["live.pcap", "live.pcapng"])
def test_live_frames_give_the_verdicts_and_events_of_replay(trained_entries, tmp_path, written):
    entries = tmp_path / "entries.json"
    trained_entries.save(entries)
    rec = interleave([TRAINING / "drain_v075_error_r3.pcap", TRAINING / "drain_v075_normal_r1.pcap",
                      ROOT / "traces" / "continuous" / sorted(p.name for p in (ROOT / "traces" / "continuous")
                                                                .glob("*.pcap"))[0]], tmp_path)
    replayed, want = tmp_path / "replayed.pcap", tmp_path / "want.jsonl"
    subprocess.run([sys.executable, "-m", "civic", "replay", str(rec), "-o", str(replayed), "--entries",
                    str(entries), "--events", str(want)], check=True, capture_output=True)
    live, got = tmp_path / written, tmp_path / "got.jsonl"
    with veth.VethPair() as pair:
        proc = start(pair, "--entries", str(entries), "--events", str(got), "--write", str(live), "--duration", "10")
        pair.send(rec, rate=20000)
        err = finish(proc)
    assert "0 dropped" in err, err
    assert without_t(got) == without_t(want) and len(without_t(want)) > 5
    src, out, ref = read_pcap(rec), read_pcap(live), read_pcap(replayed)
    assert len(out) == len(src), err
    assert live.read_bytes()[:4] == (b"\x0a\x0d\x0d\x0a" if written.endswith("ng") else b"\xd4\xc3\xb2\xa1")
    assert [out.frame(i) for i in range(len(out))] == [ref.frame(i) for i in range(len(ref))]
    assert sum(src.frame(i) != ref.frame(i) for i in range(len(src))) > 0      # verdicts were written


def test_a_missing_interface_is_one_line_and_exit_2(trained_entries, tmp_path):
    entries = tmp_path / "entries.json"
    trained_entries.save(entries)
    proc = subprocess.run([sys.executable, "-m", "civic", "monitor", "--iface", "civic-nosuch", "--entries",
                           str(entries), "--duration", "1"], capture_output=True, text=True)
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines() == ["civic monitor: error: cannot capture on 'civic-nosuch': No such device"]
    proc = subprocess.run([sys.executable, "-m", "civic", "monitor", "--iface", "any", "--entries",
                           str(entries), "--duration", "1"], capture_output=True, text=True)
    assert proc.returncode == 2
    [line] = proc.stderr.strip().splitlines()
    assert line.startswith("civic monitor: error: cannot capture on 'any': name the one interface")
