"""Bit-exact software model of the CIVIC switch pipeline (docs/pipeline.md).

One module per P4 control, same names as `p4src/v1model/include/control/`:
plant_lookup, data_collection, slope, classification, verdict. `switch`
strings them together twice: a plain per-message model that mirrors the P4
program step by step, and a vectorized numpy model for bulk replay. Tests
prove both identical on every bundled recording.
"""
from civic.pipeline.switch import MonitorTrace, SwitchModel

__all__ = ["MonitorTrace", "SwitchModel"]
