"""deploy/grafana/civic.json: a Grafana dashboard whose queries select only metrics and labels civic exports."""
from __future__ import annotations

import json
import re

from data import ROOT
from promql import exported_metrics, metric_names

DASHBOARD = ROOT / "deploy" / "grafana" / "civic.json"
TARGET_LABELS = {"job", "instance"}          # Prometheus's, on every scraped series
DATASOURCE = {"type": "prometheus", "uid": "${datasource}"}


def dashboard() -> dict:
    return json.loads(DASHBOARD.read_text())


def targets(dash):
    return [(p, t) for p in dash["panels"] for t in p["targets"]]


def test_the_datasource_is_a_variable_every_panel_uses():
    dash = dashboard()
    variables = {v["name"]: v for v in dash["templating"]["list"]}
    assert variables["datasource"]["type"] == "datasource" and variables["datasource"]["query"] == "prometheus"
    assert all(p["datasource"] == DATASOURCE for p in dash["panels"])
    assert all(t["datasource"] == DATASOURCE for _, t in targets(dash))
    assert all(v["datasource"] == DATASOURCE for v in variables.values() if v["type"] == "query")
    ids = [p["id"] for p in dash["panels"]]
    assert len(set(ids)) == len(ids)


def test_every_query_selects_exported_metrics_by_their_labels():
    exported = exported_metrics() | {"up": set()}              # up: Prometheus's own, per scrape target
    for panel, target in targets(dashboard()):
        names = metric_names(target["expr"])
        assert names and names <= set(exported), (panel["title"], names - set(exported))
        labels = set.union(TARGET_LABELS, *(exported[n] for n in names))
        used = set(re.findall(r"\{\{\s*(\w+)\s*\}\}", target["legendFormat"]))
        for group in re.findall(r"\b(?:by|without)\s*\(([^)]*)\)", target["expr"]):
            used |= {g.strip() for g in group.split(",")}
        for matchers in re.findall(r"\{([^{}]*)\}", re.sub(r"\$\{\w+\}", "", target["expr"])):
            used |= set(re.findall(r"(\w+)\s*[=!]~?", matchers))
        assert used <= labels, (panel["title"], used - labels)


def test_every_variable_lists_an_exported_label():
    exported = exported_metrics()
    queries = [v["query"]["query"] for v in dashboard()["templating"]["list"] if v["type"] == "query"]
    assert queries
    for q in queries:
        metric, label = re.fullmatch(r"label_values\((\w+)(?:\{[^}]*\})?,\s*(\w+)\)", q).groups()
        assert metric in exported and label in exported[metric] | TARGET_LABELS, q


def test_the_panels_the_operator_needs_are_there():
    kinds = {(p["type"], n) for p, t in targets(dashboard()) for n in metric_names(t["expr"])}
    exprs = " ".join(t["expr"] for _, t in targets(dashboard()))
    assert ("state-timeline", "civic_class") in kinds                      # class timeline per plant and monitor
    assert "rate(civic_verdicts_total" in exprs and "sum by (class)" in exprs    # verdict rates by class
    assert ("timeseries", "civic_last_digest_age_seconds") in kinds
    assert ("state-timeline", "civic_switch_up") in kinds and ("state-timeline", "up") in kinds
