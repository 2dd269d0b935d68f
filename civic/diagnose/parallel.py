"""Independent fits in worker processes: the multi-start joint fits, the candidates of a round, the
folds of a cross-validation. Each worker is forked from the process as it stands, so a task is any
closure over the problem (nothing is pickled but its result) and computes exactly what the same
call computes in the parent: the report and the model file do not depend on `jobs`."""
from __future__ import annotations

import ctypes
import multiprocessing
import os
import signal
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from typing import Callable, TypeVar

from civic.errors import CivicError

T = TypeVar("T")

PR_SET_PDEATHSIG = 1        # linux/prctl.h: the signal a process gets when its parent ends

_tasks: list[Callable[[], object]] = []
_in_worker = False          # set in each worker: a worker runs its own task lists itself


def available_cpus() -> int:
    """The CPUs this process may run on (its affinity, not the machine's count)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:     # not on Linux
        return os.cpu_count() or 1


def run_all(tasks: list[Callable[[], T]], jobs: int = 1, progress: Callable[[int], None] | None = None) -> list[T]:
    """`[task() for task in tasks]`, run by up to `jobs` forked worker processes (in this process
    with one job or one task, in a worker of ours or of a daemonic pool, or where the system
    cannot fork or start a pool). `progress(k)` is called here as the k-th result (in order)
    arrives. An exception in a task is raised here, as in the serial loop; a worker that died
    mid-task (killed, out of memory) is a `CivicError`, not a wait for ever."""
    global _tasks
    if (jobs <= 1 or len(tasks) <= 1 or _in_worker or multiprocessing.current_process().daemon
            or "fork" not in multiprocessing.get_all_start_methods()):
        return _here(tasks, progress)
    _tasks = tasks
    # Ctrl-C held back while the workers fork (all of them at the first submit, with the fork
    # context): a worker ignores it from its first instruction on (`_start_worker`), and this
    # process gets it once they run, and ends them
    signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    pool, done = None, False
    try:
        try:
            pool = ProcessPoolExecutor(min(jobs, len(tasks)), mp_context=multiprocessing.get_context("fork"),
                                       initializer=_start_worker, initargs=(os.getpid(),))
            futures = [pool.submit(_run, i) for i in range(len(tasks))]
        except OSError:
            # no POSIX semaphores (a container without /dev/shm) or no process to spare (a limit
            # on processes): the same fits, in this process
            if pool is not None:
                _close(pool, False)
            pool, futures = None, None
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
        if futures is None:
            return _here(tasks, progress)
        out = []
        for k, future in enumerate(futures):
            out.append(future.result())
            if progress:
                progress(k + 1)
        done = True
        return out
    except BrokenProcessPool:
        raise CivicError("a worker process of the diagnosis ended unexpectedly (killed, or out of memory?); "
                         "run again, or with --jobs 1") from None
    finally:
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
        if pool is not None:
            _close(pool, done)
        _tasks = []


def _here(tasks: list[Callable[[], T]], progress: Callable[[int], None] | None) -> list[T]:
    """The serial loop run_all stands for."""
    out = []
    for k, task in enumerate(tasks):
        out.append(task())
        if progress:
            progress(k + 1)
    return out


def _close(pool: ProcessPoolExecutor, done: bool) -> None:
    """Shut the pool down; after a failure or Ctrl-C its workers are ended first, not waited for
    (their tasks' results are of no use). The executor has no public call for that before
    Python 3.14 (`terminate_workers`): its process table is read."""
    if not done:
        for worker in list((pool._processes or {}).values()):
            worker.terminate()
    pool.shutdown(wait=True, cancel_futures=True)


def _start_worker(parent: int) -> None:
    """One BLAS thread per worker: the workers already use every CPU, and OpenBLAS's spinning
    threads would compete with them. Ctrl-C is the parent's to handle (it ends the workers): a
    worker ignores it rather than print its own traceback. A worker ends with its parent
    (`_end_with`)."""
    global _in_worker
    _in_worker = True
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    _end_with(parent)
    from threadpoolctl import threadpool_limits
    threadpool_limits(1)


def _end_with(parent: int) -> None:
    """Linux: the kernel kills this worker when `parent` ends, however it ends (kill, SIGTERM from
    `timeout` or a service manager, the OOM killer), which leaves it no chance to end its workers:
    none is left computing, or waiting for work, as an orphan. Elsewhere nothing is done."""
    try:
        prctl = ctypes.CDLL(None, use_errno=True).prctl
    except (OSError, AttributeError):
        return
    prctl(PR_SET_PDEATHSIG, signal.SIGKILL)
    if os.getppid() != parent:          # it ended before the request was made
        os._exit(1)


def _run(i: int):
    return _tasks[i]()
