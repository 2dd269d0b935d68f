"""Marks for tests that need the real BMv2 switch or Prometheus (skipped, with the reason, where they cannot run)."""
from __future__ import annotations

import os
import shutil

import pytest

BMV2 = [
    pytest.mark.bmv2,
    pytest.mark.skipif(not (shutil.which("p4c-bm2-ss") and shutil.which("simple_switch_grpc")),
                       reason="p4c-bm2-ss and simple_switch_grpc not both on PATH"),
    pytest.mark.skipif(not (hasattr(os, "geteuid") and os.geteuid() == 0),
                       reason="BMv2 needs root (network namespace)"),
]

PROMETHEUS = [
    pytest.mark.prometheus,
    pytest.mark.skipif(not (shutil.which("promtool") and shutil.which("prometheus")),
                       reason="promtool and prometheus not both on PATH (Debian: apt-get install prometheus)"),
]
