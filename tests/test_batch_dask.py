"""`facecorr batch --scheduler`: a real Dask scheduler and worker processes on loopback.

The Dask batch must write exactly the local batch's files (the meshes, pictures and JSONs compared
byte for byte and field for field, the timings aside), report a bad scan in failures.json, resume,
survive a worker killed in the middle of a scan, and stop cleanly on Ctrl-C. Every run uses
FACECORR_THREADS=1: facecorr's results are bitwise reproducible with one thread per process (with
more, parallel sums change the last bits from run to run, in the local batch too).
"""

import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

import distributed

SCANS = [(1, "NE", 0), (2, "HA", 4), (3, "SU", 4)]
BROKEN = "broken.ply"


@pytest.fixture(scope="module")
def scans(tmp_path_factory):
    """An input folder: three synthetic scans (one in a subfolder) and a broken file."""
    from facecorr.synth import generate_scan

    src = tmp_path_factory.mktemp("in")
    gen = tmp_path_factory.mktemp("gen")
    for k, (subject, expr, level) in enumerate(SCANS):
        rec = generate_scan(gen, subject=subject, expression=expr, level=level, seed=5, spacing=1.5)  # 16k vertices
        dst = src / ("sub" if k == 0 else "") / Path(rec["scan"]).name
        dst.parent.mkdir(exist_ok=True)
        shutil.copy(rec["scan"], dst)
    (src / BROKEN).write_bytes(b"ply\nformat ascii 1.0\nelement vertex 3\n")
    points = tmp_path_factory.mktemp("pts") / "points.json"
    points.write_text(json.dumps({"a_vertex": 10, "in_a_face": {"face": 7, "bary": [0.2, 0.3, 0.5]}}))
    return src, points


def _env():
    return {**os.environ, "FACECORR_THREADS": "1"}


def _batch_cli(*args, timeout=180):
    return subprocess.run([sys.executable, "-m", "facecorr.cli", "batch", *map(str, args)], capture_output=True,
                          text=True, env=_env(), timeout=timeout)


@pytest.fixture(scope="module")
def reference(scans, tmp_path_factory):
    """The local batch's output on the same folder (2 spawned workers), with the neutral shapes."""
    src, points = scans
    out = tmp_path_factory.mktemp("ref")
    r = _batch_cli(src, out, "--workers", "2", "--png", "--neutral", "--landmark-set", points)
    assert r.returncode == 2 and "3 registered, 0 already done, 1 failed" in r.stdout, r.stdout + r.stderr
    return out


@pytest.fixture(scope="module")
def cluster():
    """A scheduler (in this process) and 2 worker processes (one thread each) on loopback."""
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None,
                                  env={"FACECORR_THREADS": "1"}, silence_logs=40) as c, distributed.Client(c) as client:
        yield c, client


def _main(capsys, *args):
    from facecorr.cli import main

    rc = main([str(a) for a in args])
    return rc, capsys.readouterr()


def _results(out: Path) -> dict:
    """relative path -> bytes of every file under ``out``."""
    return {str(p.relative_to(out)): p.read_bytes() for p in sorted(out.rglob("*")) if p.is_file()}


def _assert_same_results(out: Path, ref: Path, only=None, png=True, neutral=True):
    """``out`` holds the files of ``ref`` (or of the stems in ``only``; without the pictures unless
    ``png``, without the neutral shapes unless ``neutral``): meshes and pictures byte-equal, JSONs
    equal field by field but for the timings, failures.json equal; no other file."""
    got, want = _results(out), _results(ref)
    if not png:
        want = {k: v for k, v in want.items() if not k.endswith(".png")}
    if not neutral:
        want = {k: v for k, v in want.items() if not k.endswith("_neutral.ply")}
    if only is not None:
        stem = lambda k: Path(k).stem.removesuffix("_neutral")  # noqa: E731
        want = {k: v for k, v in want.items() if stem(k) in only}
        got = {k: v for k, v in got.items() if stem(k) in only}
    assert sorted(got) == sorted(want)
    assert not [k for k in got if Path(k).name.startswith(".")], "temporary files left"
    for name, data in want.items():
        if name.endswith(".json") and name != "failures.json":
            a, b = json.loads(got[name]), json.loads(data)
            assert a.pop("timings_s").keys() == b.pop("timings_s").keys()
            assert a == b, name
        else:
            assert got[name] == data, f"{name} differs from the local batch's"


def _log(path: Path) -> list:
    return [json.loads(line) for line in path.read_text().splitlines()]


def test_dask_batch_writes_the_local_batch_files_then_resumes_shipping_bytes(scans, reference, cluster, tmp_path,
                                                                             capsys):
    src, points = scans
    local, client = cluster
    address = local.scheduler_address
    assert len(list(reference.rglob("*_neutral.ply"))) == 3
    out, log = tmp_path / "out", tmp_path / "run.log"
    rc, cap = _main(capsys, "batch", src, out, "--scheduler", address, "--png", "--landmark-set", points,
                    "--log", log)
    assert rc == 2 and "3 registered, 0 already done, 1 failed" in cap.out, cap
    assert "registering" in cap.err  # the progress bar
    _assert_same_results(out, reference, neutral=False)
    failures = json.loads((out / "failures.json").read_text())
    assert [f["scan"] for f in failures] == [str(src / BROKEN)] and "bad input" in failures[0]["error"]
    lines = _log(log)
    assert sorted(ln["scan"] for ln in lines) == sorted(str(p) for p in src.rglob("*.ply"))
    workers = set(client.scheduler_info()["workers"])
    for ln in lines:
        if ln["scan"].endswith(BROKEN):
            assert ln["status"] == "failed" and ln["error"] == failures[0]["error"]
            continue
        res = json.loads((out / Path(ln["scan"]).relative_to(src).with_suffix(".json")).read_text())
        assert ln["status"] == "ok" and ln["mhd"] == res["mhd"] and ln["flags"] == res["flags"]
        assert ln["timings_s"] == res["timings_s"] and ln["worker"] in workers and ln["seconds"] > 0
    # resume with --neutral, now without a shared filesystem (the scheduler named by a scheduler
    # file this time): one result gone, and no scan has its neutral shape yet, so every scan is
    # redone from shipped bytes, its files written as one group; they are the local batch's files
    gone = next(out.glob("*SU04*.ply"))
    gone.unlink()
    sched = tmp_path / "scheduler.json"
    sched.write_text(json.dumps({"address": address}))  # what `dask scheduler --scheduler-file` writes, in part
    rc, cap = _main(capsys, "batch", src, out, "--scheduler", sched, "--png", "--landmark-set", points,
                    "--ship-bytes", "--neutral", "--log", log, "--quiet")
    assert rc == 2 and cap.out == "", cap.out  # --quiet: only the errors (on stderr)
    assert BROKEN in cap.err and "registering" not in cap.err, cap.err
    _assert_same_results(out, reference)
    redone = _log(log)[len(lines):]
    assert sorted(Path(ln["scan"]).name for ln in redone) == sorted(p.name for p in src.rglob("*.ply"))
    # the broken scan's message names the user's path, never the worker's private copy
    assert [ln["error"] for ln in redone if ln["status"] == "failed"] == [failures[0]["error"]]
    # now complete: only the broken scan is tried again
    rc, cap = _main(capsys, "batch", src, out, "--scheduler", address, "--png", "--landmark-set", points,
                    "--neutral")
    assert rc == 2 and "0 registered, 3 already done, 1 failed" in cap.out, cap
    _assert_same_results(out, reference)


def _kill_a_busy_worker(client, pids, killed, stop):
    """Wait until a worker has been registering a scan for 1 s, then SIGKILL its process."""
    while not stop.is_set():
        busy = {a: ks for a, ks in client.processing().items() if ks and a in pids}
        if busy:
            addr, keys = next(iter(busy.items()))
            time.sleep(1.0)
            now = set(client.processing().get(addr, ()))
            if now & set(keys):
                os.kill(pids[addr], signal.SIGKILL)
                # every task the worker held dies with it (on a loaded machine the scheduler may
                # have given it the next scan during the second waited)
                killed.append((addr, sorted(now | set(keys))))
                return
        time.sleep(0.05)


def _run_killing_a_worker(client, capsys, src, out, log, points):
    pids = client.run(os.getpid)
    killed, stop = [], threading.Event()
    t = threading.Thread(target=_kill_a_busy_worker, args=(client, pids, killed, stop), daemon=True)
    t.start()
    try:
        rc, cap = _main(capsys, "batch", src, out, "--scheduler", client.scheduler_info()["address"],
                        "--landmark-set", points, "--log", log)
    finally:
        stop.set()
        t.join()
    assert killed, "no worker was killed: the batch ended first"
    client.wait_for_workers(2, timeout=60)  # the nanny restarts the killed one
    return rc, cap, killed[0]


def test_a_worker_killed_mid_scan_is_retried_elsewhere_or_reported(scans, reference, cluster, tmp_path, capsys):
    src, points = scans
    local, client = cluster
    # a dead worker's scans are run again by another worker: the results are complete and exact
    out, log = tmp_path / "out", tmp_path / "run.log"
    rc, cap, (addr, keys) = _run_killing_a_worker(client, capsys, src, out, log, points)
    assert rc == 2 and "3 registered, 0 already done, 1 failed" in cap.out, cap
    _assert_same_results(out, reference, png=False, neutral=False)
    finished_by = {Path(ln["scan"]).stem: ln.get("worker") for ln in _log(log)}
    lost = [stem for stem in finished_by if any(f"-{stem}-" in k for k in keys)]
    assert lost and all(finished_by[s] != addr for s in lost), (lost, finished_by, addr)
    # a scan that kills every worker trying it is a failure row, not the end of the batch
    # (allowed-failures 0: the first death is the last one allowed)
    saved = local.scheduler.allowed_failures
    local.scheduler.allowed_failures = 0
    try:
        out2, log2 = tmp_path / "out2", tmp_path / "run2.log"
        rc, cap, (addr, keys) = _run_killing_a_worker(client, capsys, src, out2, log2, points)
    finally:
        local.scheduler.allowed_failures = saved
    died = {ln["scan"]: ln["error"] for ln in _log(log2) if "workers registering it died" in ln.get("error", "")}
    assert died and all(any(f"-{Path(s).stem}-" in k for k in keys) for s in died), (died, keys)
    failures = {f["scan"]: f["error"] for f in json.loads((out2 / "failures.json").read_text())}
    assert set(failures) == set(died) | {str(src / BROKEN)}
    assert f"{3 - len(set(died) - {str(src / BROKEN)})} registered" in cap.out, cap.out
    survivors = {Path(s).stem for s in map(str, src.rglob("*.ply"))} - {Path(s).stem for s in failures}
    _assert_same_results(out2, reference, only=survivors, png=False, neutral=False)


def test_ctrl_c_on_a_local_cluster_leaves_only_complete_results(scans, reference, tmp_path):
    """`--scheduler local` started by the batch itself; SIGINT after the first result."""
    src, points = scans
    out = tmp_path / "out"
    p = subprocess.Popen([sys.executable, "-m", "facecorr.cli", "batch", str(src), str(out), "--scheduler", "local",
                          "--workers", "2", "--landmark-set", str(points)],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=_env(),
                         # Ctrl-C's default action even when the suite runs as a background job
                         # (started with SIGINT ignored, which Python would keep)
                         preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    kids, t0 = set(), time.monotonic()
    while not (out.exists() and [j for j in out.rglob("*.json") if j.name != "failures.json"]):
        kids.update(int(x) for x in subprocess.run(["ps", "--ppid", str(p.pid), "-o", "pid="], capture_output=True,
                                                   text=True).stdout.split())
        assert p.poll() is None, p.communicate()
        assert time.monotonic() - t0 < 90
        time.sleep(0.05)
    p.send_signal(signal.SIGINT)
    ts = time.monotonic()
    _, err = p.communicate(timeout=30)
    assert p.returncode == 130 and time.monotonic() - ts < 5, (p.returncode, time.monotonic() - ts, err)
    assert err.strip().splitlines()[-1] == "facecorr: interrupted", err
    done = {Path(k).stem for k in _results(out) if k.endswith(".json") and k != "failures.json"}
    assert 1 <= len(done) < 3, done
    _assert_same_results(out, reference, only=done, png=False, neutral=False)
    deadline = time.monotonic() + 5
    while [k for k in kids if os.path.exists(f"/proc/{k}")] and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not [k for k in kids if os.path.exists(f"/proc/{k}")], "worker processes outlived the batch"


def test_workers_that_cannot_read_the_scans_are_refused(cluster, tmp_path):
    from facecorr.errors import FacecorrError
    from facecorr.pipeline.cluster import check_workers

    _, client = cluster
    with pytest.raises(FacecorrError, match="cannot read .*missing.ply: the workers need the input folder .*--ship-bytes"):
        check_workers(client, str(tmp_path / "missing.ply"))


def test_cluster_usage_errors_are_one_line(tmp_path, scans, monkeypatch, capsys):
    import facecorr.pipeline.cluster as cl

    src, _ = scans
    rc, cap = _main(capsys, "batch", src, tmp_path / "o", "--ship-bytes")
    assert rc == 2 and "--ship-bytes needs --scheduler" in cap.err
    monkeypatch.setattr(cl, "CONNECT_TIMEOUT_S", 1)
    t0 = time.monotonic()
    rc, cap = _main(capsys, "batch", src, tmp_path / "o", "--scheduler", "tcp://127.0.0.1:9")
    assert rc == 2 and "cannot connect to the Dask scheduler tcp://127.0.0.1:9" in cap.err, cap.err
    assert time.monotonic() - t0 < 15 and len(cap.err.strip().splitlines()) == 1
    rc, cap = _main(capsys, "batch", src, tmp_path / "o", "--scheduler", str(tmp_path / "nope.json"))
    assert rc == 2 and "no such scheduler file" in cap.err
    assert not (tmp_path / "o").exists()
