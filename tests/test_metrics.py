"""civic.metrics: what a scrape serves is METRICS, each documented, civic_switch_up follows the watch's connection."""
from __future__ import annotations

import re

import civic.metrics
from data import ROOT
from promql import exported_metrics


def test_the_exported_metrics_are_metrics_and_documented():
    assert set(exported_metrics()) == set(civic.metrics.METRICS)
    readme = (ROOT / "README.md").read_text()
    for name in civic.metrics.METRICS:
        assert re.search(rf"^{name}[{{ ]", civic.metrics.__doc__, re.M) and f"| `{name}` |" in readme, name


def test_switch_up_follows_the_state():
    from prometheus_client import CollectorRegistry

    from civic.watch import WatchState

    state = WatchState(["drain_t3"])
    registry = CollectorRegistry()
    registry.register(civic.metrics.WatchCollector(state))
    assert registry.get_sample_value("civic_switch_up") == 0
    state.switch_up = True
    assert registry.get_sample_value("civic_switch_up") == 1
