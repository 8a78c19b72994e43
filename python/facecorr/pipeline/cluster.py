"""Many scans on a Dask cluster: the local batch's jobs and files, the work on the cluster's workers.

``facecorr batch IN OUT --scheduler ADDRESS`` plans on the client exactly as the local batch does
(:func:`.batch.plan_batch`: the same jobs, so the same resumability) and runs one Dask task per scan.

Where the files go
    A task reads its scan from the path the client sees, made absolute: the workers must see
    IN_DIR at that same path (a shared filesystem; checked on every worker before the work). With
    ``ship_bytes`` the client reads each scan and sends its bytes along instead (the scheduler
    relays them; nothing needs to be shared). The worker registers the scan with the local batch's
    own code (:func:`.batch.register_scan`, then :func:`.batch.save_registration` into a private
    temporary folder on the worker) and returns the files' bytes; the client writes them into OUT
    as one atomic group. So OUT need not be shared, the files are those the local batch writes,
    and a result in OUT is always complete: a dead worker, a lost connection or Ctrl-C leave
    nothing half-written.

Failures
    A scan that cannot be registered is a failure row, as in the local batch (failures.json). A
    worker that dies while it registers a scan: the scheduler runs the task again on another
    worker, up to ``distributed.scheduler.allowed-failures`` times (3 by default), after which the
    scan is a failure row (a scan that kills every worker trying it must not stop the batch). A
    task that raises (its own errors are rows, so this is an infrastructure fault) is retried by
    Dask (:data:`TASK_RETRIES`); a future lost otherwise (cancelled by a scheduler restart, its
    result unreadable) is submitted again, up to :data:`RESUBMITS` times.

Flow
    At most a window of tasks is in flight (:func:`_window`: twice the cluster's threads, at
    least 8), so the client holds few shipped scans and results at a time, and a cluster that
    grows (dask-jobqueue's ``adapt``) is given more work as it grows.

Workers
    A worker process keeps the template and the landmark model loaded across its scans (process
    caches, warmed on every worker before the first task). ``"local"`` starts a LocalCluster of
    ``workers`` processes with one thread each; their ``FACECORR_THREADS`` is the client's if set,
    else the machine's cores shared between them, and Dask's profiler is off in them. Workers of
    a remote cluster use their own environment's ``FACECORR_THREADS`` (2 by default) and Dask
    config (``DASK_DISTRIBUTED__WORKER__PROFILE__ENABLED=False`` saves them the profiler).
"""

from __future__ import annotations

import os
import time
from contextlib import contextmanager
from pathlib import Path

from ..errors import FacecorrError
from .batch import (BatchJob, check_register_outputs, failure_row, packaged_model, register_scan, save_registration,
                    status_row)

#: Times Dask re-runs a task that raised (an infrastructure fault: scan errors are rows).
TASK_RETRIES = 1
#: Times a future lost otherwise (cancelled, unreadable result) is submitted again.
RESUBMITS = 2
#: Seconds between two looks at the cluster's size (the window of tasks in flight follows it).
WINDOW_REFRESH_S = 2.0
#: Seconds to wait for a remote scheduler to answer.
CONNECT_TIMEOUT_S = 30


def _import_distributed():
    try:
        import distributed
    except ImportError:
        raise FacecorrError("--scheduler needs Dask's distributed scheduler: pip install 'facecorr[dask]'") from None
    return distributed


def local_threads(workers: int) -> str:
    """FACECORR_THREADS for the processes of a LocalCluster: the client's if set, else the
    machine's cores shared between ``workers`` processes (at least 1)."""
    given = os.environ.get("FACECORR_THREADS")
    if given:
        return given
    return str(max(1, (os.cpu_count() or 1) // max(1, workers)))


@contextmanager
def connect(scheduler: str, *, workers: int = 2):
    """A ``distributed.Client`` for ``scheduler``, closed (with its cluster) on exit.

    ``scheduler``: ``"local"`` (a LocalCluster of ``workers`` processes, one thread each), a
    scheduler address (``tcp://host:8786``, ``host:8786``) or a scheduler file (``*.json``, as
    ``dask scheduler --scheduler-file`` writes). Raises FacecorrError when Dask is missing or the
    scheduler cannot be reached."""
    import logging

    distributed = _import_distributed()
    cluster = None
    if scheduler == "local":
        if workers < 1:
            raise FacecorrError("--workers must be at least 1")
        import dask

        # The workers' statistical profiler samples the scan's thread 100 times a second (for the
        # dashboard, which a batch does not start): about 10 % of a worker's CPU. The event loops'
        # tick watch (20 ms) and system monitor (0.5 s) feed the dashboard too; slower, they halve
        # an idle cluster's CPU (BENCHMARKS.md). The scheduler and the workers take the config
        # as it is when the cluster is made.
        quiet_loops = {"distributed.worker.profile.enabled": False, "distributed.admin.tick.interval": "500ms",
                       "distributed.admin.system-monitor.interval": "2s"}
        with dask.config.set(quiet_loops):
            cluster = distributed.LocalCluster(
                n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None,
                # without a dashboard the scheduler still serves HTTP (health checks), by default
                # on port 8787: when another cluster holds it, Dask warns on stderr; any free port
                scheduler_kwargs={"dashboard_address": ":0"},
                env={"FACECORR_THREADS": local_threads(workers)},
                # the batch reports what matters itself (failures.json, the bar); Dask's warnings
                # (a worker restarted, a slow event loop) would only break the bar
                silence_logs=logging.ERROR)
        try:
            client = distributed.Client(cluster)
        except BaseException:
            cluster.close()
            raise
    else:
        kw = ({"scheduler_file": scheduler} if scheduler.endswith(".json") else {"address": scheduler})
        if "scheduler_file" in kw and not Path(scheduler).is_file():
            raise FacecorrError(f"{scheduler}: no such scheduler file")
        try:
            client = distributed.Client(**kw, timeout=CONNECT_TIMEOUT_S)
        except (OSError, TimeoutError, ValueError) as e:
            msg = str(e).splitlines()[0] if str(e) else type(e).__name__
            raise FacecorrError(f"cannot connect to the Dask scheduler {scheduler}: {msg}") from None
    aborted = False
    try:
        yield client
    except BaseException:
        aborted = True
        raise
    finally:
        try:
            if aborted and cluster is not None:
                _stop_local_workers(cluster)
            client.close()
        finally:
            if cluster is not None:
                cluster.close()


#: Seconds a LocalCluster's worker busy with a scan gets to stop when the batch is stopped, before
#: its process is killed (a scan cannot be interrupted; the worker writes nothing into OUT).
STOP_GRACE_S = 0.5


def _stop_local_workers(cluster) -> None:
    """Stop a LocalCluster's worker processes at once (a normal close waits 4 s for a running scan)."""
    import asyncio

    async def close_all(nannies):
        await asyncio.gather(*(n.close(timeout=STOP_GRACE_S) for n in nannies), return_exceptions=True)

    try:
        cluster.sync(close_all, list(cluster.workers.values()))
    except Exception:  # noqa: BLE001 - the normal close below still stops them, more slowly
        pass


def _warm_up(probe: str | None) -> dict:
    """On a worker: load what every scan needs (kept for the next scans) and report what the
    client checks: facecorr's version, and whether ``probe`` (a scan path) can be read here."""
    from .._core import __version__
    from ..template import load_template
    from . import correspond  # noqa: F401 - the stages' imports, once

    load_template()
    packaged_model()
    return {"version": __version__, "readable": probe is None or os.access(probe, os.R_OK)}


def check_workers(client, probe: str | None, *, what: str = "the input folder",
                  fix: str = ", or pass --ship-bytes") -> None:
    """Warm up the cluster's current workers and check them: they run this facecorr, and they can
    read ``probe`` (the first scan, when the workers read scans by path; ``what`` names its
    folder and ``fix`` ends the message, for the model build's results). Raises FacecorrError.
    Workers that join later are warmed by their first scan."""
    from .._core import __version__

    try:
        reports = client.run(_warm_up, probe)
    except Exception as e:  # noqa: BLE001 - whatever a worker raised: facecorr missing, broken, ...
        msg = str(e).splitlines()[0] if str(e) else ""
        raise FacecorrError(f"the Dask workers cannot run facecorr ({type(e).__name__}: {msg}): "
                            "install the same facecorr on every worker") from None
    other = {a: r["version"] for a, r in reports.items() if r["version"] != __version__}
    if other:
        addr, v = next(iter(other.items()))
        raise FacecorrError(f"the Dask worker {addr} runs facecorr {v}, this client {__version__}: "
                            "results would differ; install the same version everywhere")
    blind = sorted(a for a, r in reports.items() if not r["readable"])
    if blind:
        raise FacecorrError(f"{len(blind)} Dask worker(s) ({blind[0]}, ...) cannot read {probe}: the workers need "
                            f"{what} at the same path (a shared filesystem){fix}")


def _worker_address() -> str | None:
    try:
        from distributed import get_worker

        return get_worker().address
    except (ImportError, ValueError):
        return None


def _scratch_dir() -> str | None:
    """The worker's own scratch folder (Dask removes what a killed worker left there), else None."""
    try:
        from distributed import get_worker

        return get_worker().local_directory
    except (ImportError, ValueError, AttributeError):
        return None


def register_on_worker(job, scan_bytes=None, points=None) -> dict:
    """A Dask task: register one scan and return its row (:func:`.batch.status_row` or
    :func:`.batch.failure_row`) with ``"files"``, the bytes of the job's outputs
    (:attr:`.batch.BatchJob.outputs`: mesh, json (, picture) (, neutral shape)) as the local batch
    writes them, and ``"worker"``, this worker's address. Never raises.

    ``job``: a :class:`.batch.BatchJob` whose scan path the worker can read, unless
    ``scan_bytes`` (the scan file's content) is given; ``points``: a PointSet or None."""
    import tempfile

    job = BatchJob(*job)
    scan = job.scan
    t0 = time.perf_counter()
    names = {}
    try:
        with tempfile.TemporaryDirectory(prefix="facecorr-", dir=_scratch_dir()) as tmp:
            tmp = Path(tmp)
            src = Path(scan)
            if scan_bytes is not None:
                src = tmp / "in" / src.name
                src.parent.mkdir()
                src.write_bytes(scan_bytes)
                names[str(src)] = str(scan)
            private = {p: tmp / "out" / Path(p).name for p in job.outputs}
            names.update({str(o): str(p) for p, o in private.items()})
            mesh, result = register_scan(src, units=job.units, points=points, model=packaged_model())
            save_registration(mesh, result, private[job.out_mesh], private[job.out_json],
                              private.get(job.png) if job.png else None, title=src.name, picture="thumbnail",
                              neutral=private.get(job.neutral) if job.neutral else None)
            files = [o.read_bytes() for o in private.values()]
        row = status_row(scan, t0, result)
        row["files"] = files
    except Exception as e:  # noqa: BLE001 - one bad scan must not stop the batch
        row = failure_row(scan, e)
        for private_name, public in names.items():  # messages name the user's paths, never ours
            row["error"] = row["error"].replace(private_name, public)
    row["worker"] = _worker_address()
    return row


def _window(client) -> int:
    """Tasks to keep in flight: twice the cluster's threads (each has the next scan queued), >= 8."""
    try:
        threads = sum(client.nthreads().values())
    except Exception:  # noqa: BLE001 - a scheduler that does not answer now: keep going with the floor
        threads = 0
    return max(8, 2 * threads)


def _write_files(job, files) -> None:
    """Write a result's files onto the job's outputs, as one atomic group."""
    from ..io.atomic import atomic_paths

    with atomic_paths(*BatchJob(*job).outputs) as tmps:
        for tmp, data in zip(tmps, files, strict=True):
            tmp.write_bytes(data)


def cluster_results(jobs, client, *, ship_bytes: bool = False, points=None, progress: bool = True,
                    desc: str = "registering"):
    """Yield one row per job as its scan finishes on ``client``'s cluster, its files written
    (rows as :func:`.batch.register_job` returns them, plus ``"worker"``; in completion order).

    ``jobs``: from :func:`.batch.plan_batch`; ``ship_bytes``: send each scan's bytes instead of its
    path; ``points``: a PointSet read off every result. One tqdm bar over the futures. Closing the
    generator early (Ctrl-C, an exception) cancels every future still in flight; results written
    so far are complete, nothing else is written."""
    from distributed import KilledWorker, as_completed
    from tqdm import tqdm

    jobs = [BatchJob(*j) for j in jobs]
    if not ship_bytes and jobs:
        check_workers(client, os.path.abspath(jobs[0][0]))
    else:
        check_workers(client, None)
    todo = [(j, 0) for j in reversed(jobs)]  # (job, resubmissions so far), next job last
    inflight = {}  # future -> (job, resubmissions)
    # results are fetched in the background as tasks finish (no round trip per scan here)
    done = as_completed(loop=client.loop, with_results=True, raise_errors=False)

    def submit(job, attempt):
        """Submit ``job``; a row at once when it cannot even be sent (outputs refused, unreadable scan)."""
        scan = job[0]
        try:
            check_register_outputs(scan, job.out_mesh, job.out_json, job.png, job.neutral)
            data = Path(scan).read_bytes() if ship_bytes else None
        except (FacecorrError, OSError) as e:
            if isinstance(e, OSError):
                e = FacecorrError(f"{scan}: cannot read: {e.strerror or e}")
            return failure_row(scan, e)
        remote = job._replace(scan=os.path.abspath(scan))
        f = client.submit(register_on_worker, remote, data, points, pure=False, retries=TASK_RETRIES,
                          key=f"facecorr-register-{Path(scan).stem}-{os.urandom(6).hex()}")
        inflight[f] = (job, attempt)
        done.add(f)
        return None

    def outcome(f, result, job, attempt):
        """The row of a completed future, or None when it was submitted again."""
        scan = job[0]
        if f.status == "finished":
            if not isinstance(result, dict):  # the result could not be fetched
                return _again(job, attempt, RuntimeError(f"its result was lost ({type(result).__name__})"))
            row = dict(result)
            files = row.pop("files", None)
            row["scan"] = str(scan)
            if row["ok"]:
                try:
                    _write_files(job, files)
                except FacecorrError as e:
                    return {**failure_row(scan, e), "worker": row.get("worker")}
            return row
        if f.status == "error":
            e = f.exception()
            if isinstance(e, KilledWorker):
                return failure_row(scan, RuntimeError(
                    "the Dask workers registering it died, every time it was tried (a crash, or out of memory?)"))
            return _again(job, attempt, e)
        return _again(job, attempt, RuntimeError(f"its Dask task was {f.status}"))

    def _again(job, attempt, e):
        if attempt < RESUBMITS:
            todo.append((job, attempt + 1))
            return None
        return failure_row(job[0], e)

    bar = tqdm(total=len(jobs), desc=desc, unit="scan", disable=not progress)
    window, window_at = _window(client), time.monotonic()
    try:
        while todo or inflight:
            if time.monotonic() - window_at > WINDOW_REFRESH_S:  # the cluster may have grown
                window, window_at = _window(client), time.monotonic()
            while todo and len(inflight) < window:
                row = submit(*todo.pop())
                if row is not None:
                    bar.update()
                    yield row
            if not inflight:
                continue
            f, result = next(done)
            job, attempt = inflight.pop(f)
            row = outcome(f, result, job, attempt)
            f.release()
            if row is not None:
                bar.update()
                yield row
    finally:
        bar.close()
        if inflight:  # stopped early: nothing more is computed for us (a running task finishes, unread)
            try:
                client.cancel(list(inflight), force=True)
            except Exception:  # noqa: BLE001 - a closing or lost client: its futures die with it
                pass
