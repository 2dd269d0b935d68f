"""The report a person reads: each finding's meaning and its alternatives on the console."""
from __future__ import annotations

import json
from io import StringIO

from rich.console import Console

from civic.cli import main
from civic.diagnose.report import print_summary
from data import DIAGNOSE


def test_the_console_says_what_a_finding_means_and_what_it_cannot_be_told_from(tmp_path):
    out = tmp_path / "r.json"
    assert main(["diagnose", str(DIAGNOSE / "example_leak_t3" / "case.pcap"), "--json", str(out), "-q"]) == 0
    report = json.loads(out.read_text())
    finding = report["findings"][0]
    assert finding["description"].startswith("q = 0.012") and finding["description"].endswith("from T3 to T4")
    assert finding["description"] in finding["evidence"]
    text = StringIO()
    print_summary(report, Console(file=text, width=200))
    assert f"1. {finding['description']}" in text.getvalue()
    assert "cannot tell" not in text.getvalue()          # the held-out data separated every other candidate
    # an alternative the held-out data did not separate is said, with the experiment that would
    finding["alternatives"] = [{"mechanism": "sensor_offset", "component": "L4", "heldout_dbic_vs_chosen": 4.2,
                                "description": "L4 reads +0.3 off", "experiment": "an inventory after a drain"}]
    text = StringIO()
    print_summary(report, Console(file=text, width=300))
    assert ("the record cannot tell it from sensor_offset L4 (held-out BIC +4.2 from the chosen one's: L4 reads +0.3 off); "
            "to tell them apart: an inventory after a drain") in text.getvalue()
