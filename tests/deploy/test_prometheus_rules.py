"""deploy/prometheus: the alerting rules are valid, pass their promtool unit tests, and query exported metrics."""
from __future__ import annotations

import re
import shutil
import subprocess

import yaml

from data import ROOT
from needs import PROMETHEUS
from promql import exported_metrics, metric_names

RULES = ROOT / "deploy" / "prometheus" / "civic-alerts.yml"
RULE_TESTS = RULES.with_name("civic-alerts_test.yml")
ALERTS = {"CivicPlantError", "CivicPlantWarningPersists", "CivicPlantVerdictsStopped", "CivicNoDigest",
          "CivicSwitchDisconnected", "CivicWatchDown"}


def promtool(*argv) -> subprocess.CompletedProcess:
    return subprocess.run(["promtool", *map(str, argv)], capture_output=True, text=True, cwd=RULES.parent)


def rules() -> list[dict]:
    return [r for g in yaml.safe_load(RULES.read_text())["groups"] for r in g["rules"]]


def test_the_rules_query_only_metrics_civic_exports():
    exported = set(exported_metrics()) | {"up"}          # up: Prometheus's own, per scrape target
    assert {r["alert"] for r in rules()} == ALERTS
    for r in rules():
        names = metric_names(r["expr"])
        assert names and names <= exported, (r["alert"], names - exported)


def test_every_alert_is_unit_tested_firing_and_silent():
    tests = yaml.safe_load(RULE_TESTS.read_text())["tests"]
    cases = [c for t in tests for c in t["alert_rule_test"]]
    assert {c["alertname"] for c in cases if c["exp_alerts"]} == ALERTS
    assert {c["alertname"] for c in cases if not c["exp_alerts"]} == ALERTS


class TestPromtool:
    pytestmark = PROMETHEUS

    def test_the_rules_are_valid(self):
        res = promtool("check", "rules", RULES.name)
        assert res.returncode == 0 and f"SUCCESS: {len(ALERTS)} rules found" in res.stdout, res.stdout + res.stderr

    def test_the_unit_tests_of_the_rules_pass(self):
        res = promtool("test", "rules", RULE_TESTS.name)
        assert res.returncode == 0 and "SUCCESS" in res.stdout, res.stdout + res.stderr

    def test_the_readmes_prometheus_configs_are_valid(self, tmp_path):
        readme = (ROOT / "README.md").read_text()
        section = readme[readme.index("## Operating CIVIC with Prometheus"):]
        section = section[:section.index("\n## ", 1)]
        configs = re.findall(r"```yaml\n(.*?)```", section, re.S)
        assert len(configs) == 4                          # one switch, many, federation, remote write
        shutil.copy(RULES, tmp_path)                      # as the README says: beside prometheus.yml
        for k, text in enumerate(configs):
            (tmp_path / f"prometheus{k}.yml").write_text(text)
            res = promtool("check", "config", tmp_path / f"prometheus{k}.yml")
            assert res.returncode == 0, text + res.stdout + res.stderr
