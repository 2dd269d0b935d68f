"""Independent fits in worker processes: the multi-start joint fits, the candidates of a round, the
folds of a cross-validation. Each worker is forked from the process as it stands, so a task is any
closure over the problem (nothing is pickled but its result) and computes exactly what the same
call computes in the parent: the report and the model file do not depend on `jobs`."""
from __future__ import annotations

import multiprocessing
import os
import signal
from typing import Callable, TypeVar

T = TypeVar("T")

_tasks: list[Callable[[], object]] = []


def available_cpus() -> int:
    """The CPUs this process may run on (its affinity, not the machine's count)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:     # not on Linux
        return os.cpu_count() or 1


def run_all(tasks: list[Callable[[], T]], jobs: int = 1, progress: Callable[[int], None] | None = None) -> list[T]:
    """`[task() for task in tasks]`, run by up to `jobs` forked worker processes (in this process
    with one job or one task, in a pool's worker, or where the system cannot fork). `progress(k)`
    is called here as the k-th result (in order) arrives. An exception in a task is raised here,
    as in the serial loop."""
    global _tasks
    # a pool's worker (daemonic: it may not fork) runs its own task lists itself
    if (jobs <= 1 or len(tasks) <= 1 or multiprocessing.current_process().daemon
            or "fork" not in multiprocessing.get_all_start_methods()):
        out = []
        for k, task in enumerate(tasks):
            out.append(task())
            if progress:
                progress(k + 1)
        return out
    _tasks = tasks
    # Ctrl-C held back while the workers fork: a worker ignores it from its first instruction on
    # (`_start_worker`), and this process gets it once inside the pool's `with` (which ends them)
    signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        pool = multiprocessing.get_context("fork").Pool(min(jobs, len(tasks)), initializer=_start_worker)
    except BaseException:
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
        _tasks = []
        raise
    try:
        with pool:
            signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
            out = []
            for k, res in enumerate(pool.imap(_run, range(len(tasks)))):
                out.append(res)
                if progress:
                    progress(k + 1)
            return out
    finally:
        _tasks = []


def _start_worker() -> None:
    """One BLAS thread per worker: the workers already use every CPU, and OpenBLAS's spinning
    threads would compete with them. Ctrl-C is the parent's to handle (it ends the pool): a
    worker ignores it rather than print its own traceback."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    from threadpoolctl import threadpool_limits
    threadpool_limits(1)


def _run(i: int):
    return _tasks[i]()
