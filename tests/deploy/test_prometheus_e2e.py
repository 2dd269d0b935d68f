"""A real Prometheus scrapes `civic watch` on BMv2 fed a recording: its query API returns the verdict counts
and final classes the software model computes for the same frames, the rules fire CivicPlantError for
exactly the plants the model ends in error, and every Grafana dashboard query answers with data. When the
switch goes away, civic_switch_up drops to 0 and CivicSwitchDisconnected goes pending."""
from __future__ import annotations

import json
import re
import shutil
import signal
import subprocess
import sys
import time
import urllib.parse
import urllib.request

import numpy as np
import pytest

from civic.pipeline import SwitchModel
from civic.pipeline.plant_lookup import plant_slot
from civic.wire import CLASS_CODES, int_to_ip, read_pcap
from commands.test_watch_bmv2 import ENV, civic, free_port, scrape, switch  # noqa: F401 (switch: fixture)
from data import ROOT
from frames import changing_fleet
from needs import BMV2

pytestmark = [*BMV2, pytest.mark.skipif(shutil.which("prometheus") is None,
                                        reason="prometheus not on PATH (Debian: apt-get install prometheus)")]

RULES = ROOT / "deploy" / "prometheus" / "civic-alerts.yml"
DASHBOARD = ROOT / "deploy" / "grafana" / "civic.json"
SETTLE_S = 30          # counters are read every second, scraped every second; rules evaluated every second


def query(port: int, expr: str) -> dict:
    """Instant query: labels (without job/instance/switch) -> value."""
    url = f"http://127.0.0.1:{port}/api/v1/query?" + urllib.parse.urlencode({"query": expr})
    body = json.loads(urllib.request.urlopen(url, timeout=5).read())
    assert body["status"] == "success", body
    drop = {"__name__", "job", "instance", "switch"}
    return {tuple(sorted((k, v) for k, v in r["metric"].items() if k not in drop)): float(r["value"][1])
            for r in body["data"]["result"]}


def expected(capture, entries) -> tuple[dict, dict, int]:
    """The model's verdict counts {(class, monitor, plant): n}, final classes {(monitor, plant): code} and
    number of verdict changes, as `civic replay --target model` computes them."""
    msgs = read_pcap(capture, entries.udp_port, entries.plant_prefix).messages
    model = SwitchModel(entries)
    counts = model.verdict_counts(msgs)
    changes = model.verdict_changes(msgs)
    names = [m.name for m in entries.monitors]
    plants = {int(plant_slot(s)): int_to_ip(int(s)) for s in np.unique(msgs["src"][msgs["plant"]])}
    verdicts = {(("class", cls), ("monitor", name), ("plant", ip)): float(counts[m, slot, code])
                for m, name in enumerate(names) for slot, ip in plants.items() if counts[m, slot].any()
                for cls, code in CLASS_CODES.items()}
    final = {(("monitor", names[c.monitor]), ("plant", int_to_ip(c.plant))): float(c.cls) for c in changes}
    return verdicts, final, len(changes)


def test_prometheus_scraping_the_watch_sees_the_models_verdicts(switch, v1model_build, trained_entries,  # noqa: F811
                                                                 tmp_path):
    entries = tmp_path / "entries.json"
    trained_entries.save(entries)
    capture = changing_fleet(tmp_path / "fleet.pcap", plants=4)
    verdicts, final, changes = expected(capture, trained_entries)
    assert {v for v in final.values()} == {1.0, 2.0, 3.0} and sum(verdicts.values()) > 1000
    errors = {(("alertname", "CivicPlantError"), ("alertstate", "firing"), *k, ("severity", "critical"))
              for k, v in final.items() if v == CLASS_CODES["error"]}
    assert errors
    want = {"verdicts": verdicts, "class": final, "error alerts": errors}

    res = civic("configure", "--switch", switch.address, "--entries", entries, "--pipeline", v1model_build)
    assert res.returncode == 0, res.stderr
    metrics_port, prom_port = free_port(), free_port()
    config = tmp_path / "prometheus.yml"            # JSON is YAML
    config.write_text(json.dumps({
        "global": {"scrape_interval": "1s", "evaluation_interval": "1s"},
        "rule_files": [str(RULES)],
        "scrape_configs": [{"job_name": "civic", "static_configs": [
            {"targets": [f"127.0.0.1:{metrics_port}"], "labels": {"switch": "bmv2"}}]}],
    }))
    procs = []                                      # (process, the signal that ends it cleanly)
    log = (tmp_path / "prometheus.log").open("w")
    try:
        procs.append((subprocess.Popen(
            [sys.executable, "-m", "civic", "watch", "--switch", switch.address, "--entries", entries,
             "--metrics-port", str(metrics_port), "--duration", "300"],
            cwd=ROOT, env=ENV, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL), signal.SIGINT))
        procs.append((subprocess.Popen(
            ["prometheus", f"--config.file={config}", f"--storage.tsdb.path={tmp_path / 'tsdb'}",
             f"--web.listen-address=127.0.0.1:{prom_port}"],
            stdout=subprocess.DEVNULL, stderr=log), signal.SIGTERM))
        deadline = time.monotonic() + 30
        while True:                                 # both up, and Prometheus has scraped the watch
            try:
                scrape(metrics_port)
                if query(prom_port, 'up{job="civic"}') == {(): 1.0}:
                    break
            except OSError:
                pass
            assert all(p.poll() is None for p, _ in procs), (tmp_path / "prometheus.log").read_text()[-2000:]
            assert time.monotonic() < deadline, "civic watch or prometheus did not start"
            time.sleep(0.5)

        cap = read_pcap(capture)
        out = switch.send_frames([cap.frame(i) for i in range(len(cap))], frame_timeout=1.0)
        assert all(f is not None for f in out)

        deadline = time.monotonic() + SETTLE_S
        while True:
            got = {
                "verdicts": query(prom_port, "civic_verdicts_total"),
                "class": query(prom_port, "civic_class"),
                "error alerts": set(query(prom_port, 'ALERTS{alertname="CivicPlantError", alertstate="firing"}')),
            }
            if got == want or time.monotonic() > deadline:
                break
            time.sleep(1)
        assert got["verdicts"] == want["verdicts"]
        assert got["class"] == want["class"]
        assert got["error alerts"] == want["error alerts"]
        assert query(prom_port, "civic_switch_up") == {(): 1.0}
        assert query(prom_port, "civic_events_total") == {(): float(changes)}
        for panel in json.loads(DASHBOARD.read_text())["panels"]:    # every dashboard query has data
            for target in panel["targets"]:
                expr = re.sub(r"\$\w+", ".*", target["expr"].replace("$__rate_interval", "10s"))
                assert query(prom_port, expr), (panel["title"], expr)

        switch.proc.terminate()                     # the switch goes away: the watch says so, keeps the counts
        switch.proc.wait(timeout=10)
        disconnected = {(("alertname", "CivicSwitchDisconnected"), ("alertstate", "pending"), ("severity", "critical"))}
        deadline = time.monotonic() + SETTLE_S
        while set(query(prom_port, 'ALERTS{alertname="CivicSwitchDisconnected"}')) != disconnected:
            assert time.monotonic() < deadline, query(prom_port, "civic_switch_up")
            time.sleep(1)
        assert query(prom_port, "civic_switch_up") == {(): 0.0}
        assert query(prom_port, "civic_verdicts_total") == verdicts
    finally:
        for p, stop in procs:
            p.send_signal(stop)
        for p, _ in procs:
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
        log.close()
