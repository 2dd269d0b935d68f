"""deploy/prometheus: the alerting rules are valid, pass their promtool unit tests, and query exported metrics."""
from __future__ import annotations

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
