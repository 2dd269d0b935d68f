"""Bit-exact software model of the CIVIC switch pipeline (docs/pipeline.md).

One module per stage of `p4src/v1model/include/control/`: plant_lookup
(plant_lookup.p4), data_collection and classification (the registers and the
precondition/classify tables of monitor.p4), slope (slope.p4), verdict
(verdict.p4). `switch`
strings them together twice: a plain per-message model that mirrors the P4
program step by step, and a vectorized numpy model for bulk replay. Tests
prove both identical on every bundled recording.
"""
from civic.pipeline.switch import MonitorTrace, SwitchModel

__all__ = ["MonitorTrace", "SwitchModel"]
