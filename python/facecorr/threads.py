"""Process pools that are safe with the Rust core, and that stop cleanly.

The Rust core keeps a rayon thread pool; a process forked after that pool started inherits its
locks but not its threads and can deadlock on the first parallel call. Worker processes are
therefore always started with the "spawn" method.

Stopping: when the consumer stops early (Ctrl-C, SIGTERM, an exception), queued jobs are
cancelled and running workers terminated (SIGTERM: a job unwinds, so atomic writes remove their
temporary files; then SIGKILL after a grace period). Workers ignore SIGINT (the main process
decides) and die with the main process even when it is killed (Linux ``PR_SET_PDEATHSIG``, and a
thread that watches the parent pid everywhere).

Threads: each worker gets the machine's cores shared between the workers (:func:`worker_threads`:
``FACECORR_THREADS`` if the user set it, else cores // workers, at least 1) for the Rust pool, the
BLAS and OpenMP pools (set in the worker before any kernel runs), so ``--workers 2`` on 2 cores
runs 2 threads, not 2 processes x (2 Rust + 2 BLAS) threads (BENCHMARKS.md, "Throughput").
"""

import multiprocessing
import os
import signal
import sys
import threading
import time

#: Seconds a terminated worker gets to unwind before it is killed.
TERMINATE_GRACE_S = 3.0

_in_job = False


class _WorkerTerminated(BaseException):
    """Raised in a worker's job by SIGTERM (a BaseException: job code catching Exception lets it pass)."""


#: The environment variables that size the BLAS / OpenMP pools of libraries loaded later.
_BLAS_ENV = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def machine_cores() -> int:
    """Cores this process may run on (its CPU affinity where the OS tells it, else the CPU count)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def worker_threads(workers: int) -> int:
    """Threads each of ``workers`` worker processes should use: ``FACECORR_THREADS`` when the user
    set it to a positive integer, else the cores shared between the workers (at least 1)."""
    given = os.environ.get("FACECORR_THREADS", "").strip()
    if given.isdigit() and int(given) > 0:
        return int(given)
    return max(1, machine_cores() // max(1, int(workers)))


def limit_threads(n: int) -> None:
    """Size this process's thread pools to ``n``: facecorr's Rust pool (``FACECORR_THREADS``, read
    when the pool starts, so before the first kernel call), the BLAS / OpenMP pools of libraries
    already loaded (threadpoolctl) and of those loaded later (their environment variables). A
    variable the user set is left alone."""
    n = max(1, int(n))
    os.environ.setdefault("FACECORR_THREADS", str(n))
    for k in _BLAS_ENV:
        os.environ.setdefault(k, str(n))
    try:
        from threadpoolctl import threadpool_limits

        threadpool_limits(limits=n)
    except Exception:  # noqa: BLE001 - only a speed matter: never fail a worker over it
        pass


def spawn_context():
    """The multiprocessing context facecorr's process pools use ("spawn")."""
    return multiprocessing.get_context("spawn")


def _on_sigterm(signum, frame):
    if _in_job:
        raise _WorkerTerminated()
    os._exit(128 + signal.SIGTERM)


def _watch_parent(parent_pid: int) -> None:
    while True:
        time.sleep(0.5)
        if os.getppid() != parent_pid:
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(TERMINATE_GRACE_S)
            os._exit(128 + signal.SIGTERM)


def _worker_init(parent_pid: int, threads: int | None = None) -> None:
    """In each worker: SIGINT ignored, SIGTERM unwinds the job, die with the parent; ``threads``
    sizes its thread pools (:func:`limit_threads`)."""
    if threads is not None:
        limit_threads(threads)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, _on_sigterm)
    if sys.platform.startswith("linux"):
        try:
            import ctypes

            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(1, int(signal.SIGTERM), 0, 0, 0)  # PR_SET_PDEATHSIG
        except Exception:  # noqa: BLE001 - the watcher thread below covers it
            pass
    if os.getppid() != parent_pid:  # the parent died before we got here
        os._exit(128 + signal.SIGTERM)
    threading.Thread(target=_watch_parent, args=(parent_pid,), daemon=True, name="facecorr-parent-watch").start()


def _call(fn, job):
    """Run one job in a worker; SIGTERM during it unwinds it (cleanups run), then the worker exits."""
    global _in_job
    _in_job = True
    try:
        return fn(job)
    except _WorkerTerminated:
        os._exit(128 + signal.SIGTERM)
    finally:
        _in_job = False


def _abort(ex) -> None:
    """Cancel the queued jobs and stop the running workers (SIGTERM, then SIGKILL after a grace)."""
    procs = list((getattr(ex, "_processes", None) or {}).values())
    ex.shutdown(wait=False, cancel_futures=True)
    for p in procs:
        try:
            p.terminate()
        except (OSError, ValueError):
            pass
    deadline = time.monotonic() + TERMINATE_GRACE_S
    for p in procs:
        try:
            p.join(max(0.0, deadline - time.monotonic()))
            if p.is_alive():
                p.kill()
                p.join(1.0)
        except (OSError, ValueError, AssertionError):
            pass


def process_iter(fn, jobs, *, workers=2, desc="working", progress=True, ordered=True):
    """Yield ``fn(j)`` for each job, computed in ``workers`` spawned processes, with a progress bar.

    ``ordered`` yields in job order, else as each finishes (a batch can record results as they
    come). ``fn`` must be a module-level function (picklable); with one worker or one job it runs
    here (with this process's threads), else each worker gets :func:`worker_threads` threads.
    Closing the generator early (or an exception, Ctrl-C, in it) cancels the queued jobs and
    terminates the running workers before it returns.
    """
    from tqdm import tqdm

    jobs = list(jobs)
    with tqdm(total=len(jobs), desc=desc, unit="scan", disable=not progress) as bar:
        if workers > 1 and len(jobs) > 1:
            from concurrent.futures import ProcessPoolExecutor, as_completed

            n_proc = min(workers, len(jobs))
            ex = ProcessPoolExecutor(max_workers=n_proc, mp_context=spawn_context(), initializer=_worker_init,
                                     initargs=(os.getpid(), worker_threads(n_proc)))
            finished = False
            try:
                futures = [ex.submit(_call, fn, j) for j in jobs]
                for f in (futures if ordered else as_completed(futures)):
                    r = f.result()
                    bar.update()
                    yield r
                finished = True
            finally:
                if finished:
                    ex.shutdown(wait=True)
                else:
                    _abort(ex)
        else:
            for j in jobs:
                r = fn(j)
                bar.update()
                yield r


def process_map(fn, jobs, *, workers=2, desc="working", progress=True) -> list:
    """``[fn(j) for j in jobs]`` over ``workers`` spawned processes (in order), with a progress bar."""
    return list(process_iter(fn, jobs, workers=workers, desc=desc, progress=progress))
