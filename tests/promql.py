"""Metric names in PromQL expressions (alert rules, dashboard queries) and the names civic exports."""
from __future__ import annotations

import re

# PromQL words that are neither functions (those are followed by a parenthesis) nor metrics
KEYWORDS = {"and", "or", "unless", "bool", "offset", "inf", "nan"}


def metric_names(expr: str) -> set[str]:
    """The metric names an expression selects: identifiers that are no function, keyword or label."""
    expr = re.sub(r"\$\{[^}]*\}|\$\w+", "", expr)                 # Grafana variables
    expr = re.sub(r'"(?:\\.|[^"\\])*"', "", expr)                 # strings
    expr = re.sub(r"\{[^}]*\}|\[[^\]]*\]", "", expr)             # label matchers, ranges
    expr = re.sub(r"\b(by|without|on|ignoring|group_left|group_right)\s*\([^)]*\)", "", expr)   # label lists
    names = re.findall(r"(?<![\w:.])([a-zA-Z_:][\w:]*)(?![\w:]|\s*\()", expr)
    return {n for n in names if n.lower() not in KEYWORDS}


def exported_metrics() -> dict[str, set[str]]:
    """The sample names a WatchCollector serves (one plant, one digest), as Prometheus scrapes them, with
    their label names (Prometheus adds job and instance, and any target labels)."""
    from prometheus_client import CollectorRegistry, generate_latest

    from civic.metrics import WatchCollector
    from civic.watch import WatchState

    state = WatchState(["drain_t3"])
    state.apply_event({"t": 1.0, "plant": "10.0.0.1", "monitor": "drain_t3", "from": None, "to": "normal"}, 1.0)
    state.apply_counts("10.0.0.1", "drain_t3", {1: 5, 2: 0, 3: 0})
    state.last_digest = 1.0
    registry = CollectorRegistry()
    registry.register(WatchCollector(state))
    out: dict[str, set[str]] = {}
    for line in generate_latest(registry).decode().splitlines():
        if line and not line.startswith("#"):
            name, labels = re.match(r"([\w:]+)(\{[^}]*\})?", line).groups()
            out.setdefault(name, set()).update(re.findall(r'(\w+)="', labels or ""))
    return out
