"""Process pools that are safe with the Rust core, and that stop cleanly.

The Rust core keeps a rayon thread pool; a process forked after that pool started inherits its
locks but not its threads and can deadlock on the first parallel call. Worker processes are
therefore always started with the "spawn" method.

Stopping: when the consumer stops early (Ctrl-C, SIGTERM, an exception), queued jobs are
cancelled and running workers terminated (SIGTERM: a job unwinds, so atomic writes remove their
temporary files; then SIGKILL after a grace period). Workers ignore SIGINT (the main process
decides) and die with the main process even when it is killed (Linux ``PR_SET_PDEATHSIG``, and a
thread that watches the parent pid everywhere).
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


def _worker_init(parent_pid: int) -> None:
    """In each worker: SIGINT ignored, SIGTERM unwinds the job, die with the parent."""
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
    here. Closing the generator early (or an exception, Ctrl-C, in it) cancels the queued jobs
    and terminates the running workers before it returns.
    """
    from tqdm import tqdm

    jobs = list(jobs)
    with tqdm(total=len(jobs), desc=desc, unit="scan", disable=not progress) as bar:
        if workers > 1 and len(jobs) > 1:
            from concurrent.futures import ProcessPoolExecutor, as_completed

            ex = ProcessPoolExecutor(max_workers=min(workers, len(jobs)), mp_context=spawn_context(),
                                     initializer=_worker_init, initargs=(os.getpid(),))
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
