"""Independent fits in forked workers (civic/diagnose/parallel.py): the same results as in one
process, in order, with errors raised where the serial loop raises them."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from civic.cli import main
from civic.diagnose.parallel import run_all

ROOT = Path(__file__).resolve().parents[2]
CASE = ROOT / "traces" / "diagnose" / "example_leak_t3" / "case.pcap"


def test_tasks_run_in_workers_and_come_back_in_order():
    seen = []
    out = run_all([lambda k=k: (k, os.getpid()) for k in range(6)], jobs=2, progress=seen.append)
    assert [k for k, _ in out] == list(range(6))
    assert all(pid != os.getpid() for _, pid in out)         # forked, not run here
    assert seen == list(range(1, 7))
    assert run_all([os.getpid, os.getpid], jobs=1) == [os.getpid()] * 2


def test_a_tasks_error_is_raised_here():
    def fails():
        raise RuntimeError("no start converged")
    with pytest.raises(RuntimeError, match="no start converged"):
        run_all([lambda: 1, fails, lambda: 3], jobs=2)


def test_where_no_process_can_be_forked_the_tasks_run_here(monkeypatch):
    """A limit on processes (fork fails with EAGAIN) or no POSIX semaphores: the same results, from
    this process, instead of an error."""
    def no_fork():
        raise BlockingIOError(11, "Resource temporarily unavailable")
    monkeypatch.setattr(os, "fork", no_fork)
    seen = []
    assert run_all([lambda k=k: (k, os.getpid()) for k in range(4)], jobs=2, progress=seen.append) == \
        [(k, os.getpid()) for k in range(4)]
    assert seen == [1, 2, 3, 4]


def test_a_worker_runs_its_own_task_lists_itself():
    """A task that fans out again (a cross-validation inside a candidate's task) runs its list in
    its worker: no pool of pools, no more processes than jobs."""
    def nested():
        return run_all([os.getpid, os.getpid], jobs=2)
    out = run_all([nested, nested], jobs=2)
    assert all(len(set(pids)) == 1 and pids[0] != os.getpid() for pids in out)


def test_cross_validation_folds_in_workers_fit_what_one_process_fits():
    """The free run's blocked CV (three folds) on the Cascaded Tanks record: each fold fitted in a
    worker gives the fit one process gives, to the last bit."""
    from civic.diagnose import data
    from civic.diagnose.compare import SimulationError
    from civic.diagnose.mechanisms.flow_law import EXPONENT_BOUNDS, FlowLaw
    from civic.diagnose.problem import Calibration, Problem
    from civic.plant.model import PlantModel

    model = PlantModel.from_toml(ROOT / "configs" / "cascaded-tanks.toml")
    rec = data.load(ROOT / "traces" / "cascaded-tanks" / "estimation.csv", model)
    engine = SimulationError(model, rec, horizon_s=None, n_init=50)
    law = FlowLaw("out2", {"exponent": 0.52}, {"exponent": EXPONENT_BOUNDS}, {"form": "exponent"})
    fits = []
    for jobs in (1, 2):
        prob = Problem(model, rec, engine, Calibration.of(model, bounds=(0.1, 5.0)), np.full(1, 0.05), jobs=jobs)
        fits.append(prob.evaluate([law], budget=3))
    one, two = fits
    assert len(one.fold_sse) == 3
    assert one.fold_sse == two.fold_sse and one.val_bic == two.val_bic
    assert np.array_equal(one.cal, two.cal) and one.fold_params == two.fold_params


def test_the_report_does_not_depend_on_jobs(tmp_path):
    """`civic diagnose --jobs`: the bundled leak case, its candidates fitted in one process and in
    two workers, gives the same report and the same improved model, byte for byte."""
    out = {}
    for jobs in ("1", "2"):
        rep, model = tmp_path / f"rep{jobs}.json", tmp_path / f"improved{jobs}.toml"
        assert main(["diagnose", str(CASE), "--json", str(rep), "--write-model", str(model), "-q",
                     "--jobs", jobs]) == 0
        out[jobs] = rep.read_text(), model.read_text()
    assert out["1"] == out["2"]
    assert [f["mechanism"] for f in json.loads(out["1"][0])["findings"]] == ["leak"]


def test_jobs_below_one_is_a_one_line_error(capsys):
    assert main(["diagnose", str(CASE), "--jobs", "0", "-q"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "--jobs must be >= 1" in err


def test_ctrl_c_ends_the_workers_with_one_line(tmp_path):
    """Ctrl-C reaches the whole process group: the command says 'interrupted' (exit 130), its
    workers print nothing and none is left running."""
    proc, workers = _started_with_workers(tmp_path / "r.json")
    os.killpg(proc.pid, signal.SIGINT)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 130
    assert err.strip() == "civic diagnose: interrupted"
    assert not (tmp_path / "r.json").exists()
    time.sleep(0.5)
    assert not [w for w in workers if _running(w)]


def test_a_worker_killed_from_outside_is_a_one_line_error(tmp_path):
    """A worker gone mid-task (the OOM killer, kill -9) took its task with it: the command says so
    in one line (exit 2), ends the other worker and writes no report, instead of waiting for that
    result for ever."""
    proc, workers = _started_with_workers(tmp_path / "r.json")
    os.kill(int(workers[0]), signal.SIGKILL)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 2, err
    assert err.strip().count("\n") == 0 and "worker process of the diagnosis ended unexpectedly" in err
    assert not (tmp_path / "r.json").exists()
    assert not any(_running(pid) for pid in workers)


def test_the_workers_end_with_the_command_however_it_ends(tmp_path):
    """The command killed outright (SIGKILL: no handler runs, nothing can end the workers from
    inside it): its workers end too, none left computing or waiting for work as an orphan."""
    proc, workers = _started_with_workers(tmp_path / "r.json")
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait(timeout=60)           # not communicate: an orphan would hold its pipes open
    deadline = time.monotonic() + 10
    while [w for w in workers if _running(w)] and time.monotonic() < deadline:
        time.sleep(0.05)
    left = [w for w in workers if _running(w)]
    for w in left:                  # not left behind by a failing run either
        os.kill(int(w), signal.SIGKILL)
    proc.communicate()
    assert not left


def _started_with_workers(report: Path) -> tuple[subprocess.Popen, list[str]]:
    """`civic diagnose --jobs 2` on the leak case, in a session of its own, once both its workers run."""
    proc = subprocess.Popen([sys.executable, "-m", "civic.cli", "diagnose", str(CASE), "-q", "--jobs", "2",
                             "--json", str(report)], cwd=ROOT, start_new_session=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    while proc.poll() is None and not _group(proc.pid) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert proc.poll() is None, "finished before its workers started"
    return proc, _group(proc.pid)


def _group(pgid: int) -> list[str]:
    """The command's two workers once both run: the live children of process group `pgid`'s
    leader with its command line (not a helper a library runs for a moment, such as the ldconfig
    behind ctypes' find_library)."""
    try:
        leader = Path(f"/proc/{pgid}/cmdline").read_bytes()
    except OSError:
        return []
    kids = [p.name for p in Path("/proc").iterdir() if p.name.isdigit()
            and _stat(p.name)[1:3] == [str(pgid), str(pgid)] and _running(p.name) and _cmdline(p.name) == leader]
    return kids if len(kids) >= 2 else []


def _cmdline(pid: str) -> bytes:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes()
    except OSError:
        return b""


def _stat(pid: str) -> list[str]:
    """/proc/PID/stat's fields after the command name (state, ppid, pgrp, ...); [] once gone."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return []


def _running(pid: str) -> bool:
    """Whether the process lives (a zombie waiting to be reaped does not)."""
    return _stat(pid)[:1] not in ([], ["Z"])
