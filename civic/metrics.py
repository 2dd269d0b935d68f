"""Prometheus metrics of a `civic watch` session (prometheus_client, its own registry).

civic_verdicts_total{plant,monitor,class}  verdicts, read from the switch's monK.verdicts counters
civic_class{plant,monitor}                 current class: 0 none yet, 1 normal, 2 warning, 3 error
civic_events_total                         verdict changes received as digests
civic_last_digest_age_seconds              seconds since the last digest (NaN before the first)
civic_switch_up                            1 while the watch is connected to the switch (P4Runtime stream open,
                                           CIVIC pipeline checked), 0 while it is not (lost, reconnecting)

The verdict counters keep their last value while the switch is unreachable; a plant whose verdicts
stopped is one whose civic_verdicts_total no longer increase (deploy/prometheus/civic-alerts.yml).
"""
from __future__ import annotations

import math
import time

from civic.errors import CivicError
from civic.wire import CLASS_CODES

METRICS = ("civic_verdicts_total", "civic_class", "civic_events_total", "civic_last_digest_age_seconds",
           "civic_switch_up")


class WatchCollector:
    """Builds the metrics from a WatchState at every scrape."""

    def __init__(self, state):
        self.state = state

    def collect(self):
        from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily

        cells = sorted(list(self.state.cells.items()))
        verdicts = CounterMetricFamily("civic_verdicts", "Verdicts the switch gave, per plant, monitor and class",
                                       labels=["plant", "monitor", "class"])
        current = GaugeMetricFamily("civic_class", "Current class per plant and monitor "
                                    "(0 none yet, 1 normal, 2 warning, 3 error)", labels=["plant", "monitor"])
        for (plant, monitor), cell in cells:
            for name, code in CLASS_CODES.items():
                verdicts.add_metric([plant, monitor, name], cell.counts.get(code, 0))
            current.add_metric([plant, monitor], cell.cls)
        yield verdicts
        yield current
        yield CounterMetricFamily("civic_events", "Verdict changes received from the switch",
                                  value=self.state.events_total)
        last = self.state.last_digest
        yield GaugeMetricFamily("civic_last_digest_age_seconds", "Seconds since the last verdict-change digest",
                                value=time.time() - last if last is not None else math.nan)
        yield GaugeMetricFamily("civic_switch_up", "1 while the watch is connected to the switch, 0 while not",
                                value=int(self.state.switch_up))


def serve(state, port: int):
    """Start the metrics HTTP server on `port` (all interfaces); returns a function that stops it."""
    from prometheus_client import CollectorRegistry, start_http_server

    registry = CollectorRegistry()
    registry.register(WatchCollector(state))
    try:
        started = start_http_server(port, registry=registry)
    except OSError as exc:
        raise CivicError(f"--metrics-port {port}: {exc.strerror}") from None
    server = started[0] if isinstance(started, tuple) else None
    return server.shutdown if server is not None else (lambda: None)
