"""Waiting for what another process writes, however slow this machine."""
from __future__ import annotations

import time
from pathlib import Path


def wait_lines(path: Path, n: int, timeout: float, what: str) -> None:
    """Until `path` holds at least n lines; fails saying `what` did not arrive in `timeout` s."""
    deadline = time.monotonic() + timeout
    while not (path.exists() and len(path.read_text().splitlines()) >= n):
        assert time.monotonic() < deadline, f"{what}: fewer than {n} lines in {timeout:g} s"
        time.sleep(0.05)
