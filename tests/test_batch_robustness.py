"""`facecorr batch` stopped by SIGINT, SIGTERM and SIGKILL at several moments: only complete
results are left (no temporary files), no worker outlives the batch, and a re-run completes it."""

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

N_SCANS = 6


@pytest.fixture(scope="module")
def scans(tmp_path_factory):
    from facecorr.synth import generate_scan

    rec = generate_scan(tmp_path_factory.mktemp("scan"), subject=1, expression="NE", level=0, seed=5)
    src = tmp_path_factory.mktemp("in")
    for i in range(N_SCANS):
        shutil.copy(rec["scan"], src / f"s{i}.ply")
    return src


def _stat(pid):
    """(state, ppid) of a process, None if gone."""
    try:
        rest = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return None
    return rest[0], int(rest[1])


def _children(pid):
    out = []
    for d in os.listdir("/proc"):
        if d.isdigit():
            s = _stat(d)
            if s and s[1] == pid:
                out.append(int(d))
    return out


def _alive(pids):
    return [p for p in pids if (s := _stat(p)) is not None and s[0] != "Z"]


def _default_sigint():
    """In the child: Ctrl-C's default action. A shell without job control starts background jobs
    with SIGINT ignored, and Python keeps an inherited SIG_IGN: the batch would never see the signal
    these tests send when the suite itself runs in the background."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _start(src, out):
    return subprocess.Popen([sys.executable, "-m", "facecorr.cli", "batch", str(src), str(out), "--workers", "2"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, preexec_fn=_default_sigint)


def _check_results(out, expect_all=False):
    """Every result is a complete, loadable .ply + .json pair; no temporary files anywhere."""
    import trimesh

    from facecorr.template import load_template

    if not out.exists():
        assert not expect_all
        return 0
    names = sorted(p.name for p in out.iterdir())
    assert not [n for n in names if n.startswith(".")], f"temporary files left: {names}"
    n_v = load_template().n_vertices
    done = 0
    for i in range(N_SCANS):
        ply, js = out / f"s{i}.ply", out / f"s{i}.json"
        if js.exists():
            data = json.loads(js.read_text())
            assert {"landmarks", "mhd"} <= set(data)
        if ply.exists():
            assert len(trimesh.load(ply, process=False).vertices) == n_v
        if ply.exists() and js.exists():
            done += 1
    assert not (out / "failures.json").exists()
    if expect_all:
        assert done == N_SCANS, names
    return done


def _interrupt(src, out, sig, *, after_results=None, after_s=None, with_workers=False):
    """Start a batch, send ``sig`` after ``after_results`` more results appear (or ``after_s``
    seconds, or as soon as its workers exist), return (returncode, seconds from the signal to
    the exit)."""
    before = len(list(out.glob("s*.json"))) if out.exists() else 0
    p = _start(src, out)
    t0 = time.monotonic()
    kids = set()
    while True:
        kids.update(_children(p.pid))
        if after_s is not None and time.monotonic() - t0 >= after_s:
            break
        if with_workers and len(kids) >= 2:
            break
        if after_results is not None and out.exists() and len(list(out.glob("s*.json"))) >= before + after_results:
            break
        assert p.poll() is None, f"the batch ended before the signal: {p.communicate()}"
        assert time.monotonic() - t0 < 60
        time.sleep(0.05)
    kids.update(_children(p.pid))
    p.send_signal(sig)
    ts = time.monotonic()
    _, err = p.communicate(timeout=30)
    took = time.monotonic() - ts
    # workers die with the batch, even when it is killed
    deadline = time.monotonic() + 6
    while _alive(kids) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not _alive(kids), f"orphan workers {_alive(kids)} after {sig!r}"
    if sig != signal.SIGKILL:
        lines = [l for l in err.splitlines() if l.strip() and not l.startswith("registering")]
        assert len([l for l in lines if l.startswith("facecorr:")]) == 1, err
    return p.returncode, took


def test_batch_interrupted_by_signals_then_resumed(scans, tmp_path):
    out = tmp_path / "out"
    rc, took = _interrupt(scans, out, signal.SIGINT, with_workers=True)  # very early: workers starting
    assert rc == 130 and took < 5, (rc, took)
    _check_results(out)
    rc, took = _interrupt(scans, out, signal.SIGINT, after_results=1)
    assert rc == 130 and took < 5, (rc, took)
    n1 = _check_results(out)
    assert 1 <= n1 < N_SCANS
    rc, took = _interrupt(scans, out, signal.SIGTERM, after_results=1)
    assert rc in (143, 130) and took < 5, (rc, took)
    n2 = _check_results(out)
    assert n2 > n1
    if n2 < N_SCANS - 1:  # (a slow machine may leave too little for a third interruption)
        rc, took = _interrupt(scans, out, signal.SIGKILL, after_results=1)
        assert rc == -signal.SIGKILL
    r = subprocess.run([sys.executable, "-m", "facecorr.cli", "batch", str(scans), str(out), "--workers", "2"],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    _check_results(out, expect_all=True)


def test_batch_killed_very_early_then_resumed(scans, tmp_path):
    """SIGTERM and SIGKILL early (workers starting), then a re-run does everything."""
    out = tmp_path / "out"
    rc, _ = _interrupt(scans, out, signal.SIGTERM, with_workers=True)
    assert rc in (143, 130), rc
    _check_results(out)
    rc, _ = _interrupt(scans, out, signal.SIGKILL, after_s=3.0)
    assert rc == -signal.SIGKILL
    r = subprocess.run([sys.executable, "-m", "facecorr.cli", "batch", str(scans), str(out), "--workers", "2"],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert f"{N_SCANS} registered" in r.stdout or "already done" in r.stdout
    _check_results(out, expect_all=True)
