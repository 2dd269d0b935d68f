"""Shared fixtures: the bundled recordings and entries trained on them."""
from __future__ import annotations

import signal

import civic  # noqa: F401  (first: it pins the CPU code paths before numpy loads)
import pytest

# The live tests stop the commands they start with SIGINT, as a user's Ctrl-C. A run started in
# the background of a non-interactive shell ignores SIGINT, every child inherits that, and the
# commands never stop (`civic monitor` timed out after SIGINT). A handled signal is reset to
# the default in a child, so handling it here gives every command its Ctrl-C back.
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)

from data import TRAINING


@pytest.fixture(scope="session")
def training_runs():
    from civic.config import load_monitors
    from civic.train import collect_runs, read_labels

    labels = read_labels(TRAINING / "labels.csv")
    config = load_monitors()
    return {est: collect_runs(TRAINING, labels, config, est) for est in ("endpoint", "lsq")}


@pytest.fixture(scope="session")
def trained_entries(training_runs):
    """Entries from `civic train` defaults (lsq, banded, calibrated) on the bundled recordings."""
    from civic.config import load_monitors
    from civic.envelope import calibrated
    from civic.train import read_labels, train

    config = load_monitors()
    return train(training_runs["lsq"], config, "lsq", True,
                 calibrated(TRAINING, read_labels(TRAINING / "labels.csv"), config))


@pytest.fixture(scope="session")
def paper_entries(training_runs):
    from civic.config import load_monitors
    from civic.train import train

    return train(training_runs["endpoint"], load_monitors(), "endpoint", False)


@pytest.fixture(scope="session")
def v1model_build(tmp_path_factory):
    """p4src/v1model/civic.p4 compiled by p4c-bm2-ss (civic.json + P4Info), once per session."""
    import shutil

    from civic.switch.bmv2 import compile_v1model
    from data import ROOT
    if shutil.which("p4c-bm2-ss") is None:
        pytest.skip("p4c-bm2-ss not on PATH (install the P4 toolchain, see p4src/README.md)")
    build = tmp_path_factory.mktemp("v1model")
    messages = compile_v1model(ROOT / "p4src" / "v1model" / "civic.p4", build)
    assert "warning" not in messages.lower(), messages
    return build


# ------------------------------------------------------------------ CI: the switch and Prometheus tests must run
# marker -> the tools whose presence makes a skip of such a test a failure under CI; none for prometheus:
# .ci/run installs it, so under CI its tests must run everywhere
TOOLCHAIN = {"bmv2": ("p4c-bm2-ss", "simple_switch_grpc"), "tofino": ("bf-p4c",), "prometheus": (),
             "opcua_node": ("node", "npm")}
_CI_SKIPS: list = []


def _ci_requires(marker: str) -> bool:
    """CI is set and the marker's tools are on PATH: a skipped test of that kind is then a failure."""
    import os
    import shutil
    return bool(os.environ.get("CI")) and all(shutil.which(t) for t in TOOLCHAIN[marker])


def pytest_runtest_logreport(report):
    if report.skipped and any(m in report.keywords and _ci_requires(m) for m in TOOLCHAIN):
        reason = report.longrepr[2] if isinstance(report.longrepr, tuple) else str(report.longrepr)
        _CI_SKIPS.append(f"{report.nodeid}: {reason}")


def pytest_sessionfinish(session, exitstatus):
    # CI installs the toolchain and Prometheus (.ci/run); a skip there means they were never checked
    if _CI_SKIPS and session.exitstatus == 0:
        session.exitstatus = 1


def pytest_terminal_summary(terminalreporter, exitstatus, config):
    if _CI_SKIPS:
        terminalreporter.section("CI: switch, Prometheus and OPC UA client tests must not skip", sep="!", red=True)
        for line in _CI_SKIPS:
            terminalreporter.write_line(line)
