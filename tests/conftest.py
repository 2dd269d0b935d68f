"""Shared fixtures: the bundled recordings and entries trained on them."""
from __future__ import annotations

import pytest

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
    """Entries from `civic train` defaults (lsq, banded) on the bundled recordings."""
    from civic.config import load_monitors
    from civic.train import train

    return train(training_runs["lsq"], load_monitors(), "lsq", True)


@pytest.fixture(scope="session")
def paper_entries(training_runs):
    from civic.config import load_monitors
    from civic.train import train

    return train(training_runs["endpoint"], load_monitors(), "endpoint", False)
