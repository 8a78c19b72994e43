"""`facecorr model build --scheduler`: the model built on Dask workers (processes on loopback) is
the local build's, to round-off; one progress bar; one-line errors, no output.

The results are 25 stand-ins written as `facecorr batch` writes them (the template with smooth
random deformations, in random poses, some in cm), with their `_neutral.ply` files; chunks of 4
shapes (7 chunks, the last one short) so that every step crosses chunks.
"""

import json

import numpy as np
import pytest

import distributed

N_SHAPES = 25


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    from facecorr.io import save_mesh
    from facecorr.template import load_template
    from scipy.spatial.transform import Rotation

    t = load_template()
    v0, faces = np.asarray(t.vertices, float), np.asarray(t.faces)
    rng = np.random.default_rng(11)
    root = tmp_path_factory.mktemp("results")
    scale = np.ptp(v0, axis=0)
    for i in range(N_SHAPES):
        def shape():
            w = rng.normal(size=(4, 3)) * 1.5
            field = sum(np.sin(v0 @ rng.normal(size=3) / scale.mean() * 3 + rng.uniform(0, 6))[:, None] * w[j]
                        for j in range(4))
            r = Rotation.from_rotvec(rng.normal(size=3) * 0.3).as_matrix()
            return (v0 * rng.uniform(0.9, 1.1) + field) @ r.T + rng.normal(size=3) * 20
        units = "cm" if i % 3 == 0 else "mm"  # (save_mesh converts the mm to them)
        folder = root / f"S{i // 5:02d}"
        folder.mkdir(exist_ok=True)
        stem = folder / f"S{i // 5:02d}_{i:02d}"
        save_mesh(stem.with_suffix(".ply"), (shape(), faces), units=units)
        save_mesh(stem.parent / (stem.name + "_neutral.ply"), (shape(), faces), units=units)
        flags = ["low_coverage:50%"] if i == 7 else ["low_confidence:nose_tip"]
        stem.with_suffix(".json").write_text(json.dumps({"units": units, "landmarks_registered": {}, "flags": flags}))
    return root


@pytest.fixture(scope="module")
def cluster():
    """A scheduler (in this process) and 2 worker processes (one thread each) on loopback. Its
    scheduler serves HTTP on port 8787 (Dask's default), so that the `--scheduler local` command
    below meets a taken port, as next to any other cluster."""
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None,
                                  silence_logs=40) as c, distributed.Client(c) as client:
        yield c, client


def _assert_same_model(a, b, tol=1e-9):
    assert a.names == b.names and a.n_scans == b.n_scans and a.n_modes == b.n_modes
    assert (a.alignment, a.source) == (b.alignment, b.source)
    np.testing.assert_array_equal(a.faces, b.faces)
    np.testing.assert_allclose(a.mean, b.mean, rtol=0, atol=tol * np.abs(a.mean).max())
    np.testing.assert_allclose(a.components, b.components, rtol=0, atol=tol * np.abs(a.components).max())
    np.testing.assert_allclose(a.variances, b.variances, rtol=tol, atol=0)
    np.testing.assert_allclose(a.scores, b.scores, rtol=0, atol=tol * np.abs(a.scores).max())
    assert a.total_variance == pytest.approx(b.total_variance, rel=tol)


@pytest.mark.parametrize("neutral,options", [(False, {}), (False, {"scale": True, "modes": 5}),
                                             (True, {"variance": 1.0, "include_flagged": True})])
def test_cluster_build_is_the_local_build(results, cluster, neutral, options):
    from facecorr.model import build_model
    from facecorr.model.distributed import build_model_on_cluster

    _, client = cluster
    local = build_model(results, neutral=neutral, progress=False, **options)
    remote, skipped, n_failed = build_model_on_cluster(results, client, neutral=neutral, chunk_size=4,
                                                       progress=False, **options)
    assert local.n_scans == (N_SHAPES if options.get("include_flagged") else N_SHAPES - 1)
    assert skipped == ([] if options.get("include_flagged") else [("S01/S01_07", ["low_coverage:50%"])])
    assert n_failed == 0 and local.n_modes >= 5
    _assert_same_model(local, remote)
    # the default chunking (one chunk here: fewer shapes than a chunk's minimum) gives it too
    whole, _, _ = build_model_on_cluster(results, client, neutral=neutral, progress=False, **options)
    _assert_same_model(local, whole)


def _main(capsys, *args):
    from facecorr.cli import main

    rc = main([str(a) for a in args])
    return rc, capsys.readouterr()


def test_cli_build_on_a_cluster_one_bar_same_file(results, cluster, tmp_path, capsys):
    from facecorr.model import ShapeModel

    local, _ = cluster
    rc, cap = _main(capsys, "model", "build", results, "-o", tmp_path / "local.npz", "--neutral")
    assert rc == 0, cap.err
    rc, cap = _main(capsys, "model", "build", results, "-o", tmp_path / "dask.npz", "--neutral",
                    "--scheduler", local.scheduler_address)
    assert rc == 0, cap.err
    assert "24 scans" in cap.out and "skipped 1 flagged result(s) (low_coverage 1" in cap.out, cap.out
    bars = {line.split(":")[0].strip() for line in cap.err.replace("\r", "\n").splitlines() if "task" in line}
    assert bars == {"building on the cluster"}, cap.err
    assert "reading" not in cap.err  # the workers read: no second bar
    _assert_same_model(ShapeModel.load(tmp_path / "local.npz"), ShapeModel.load(tmp_path / "dask.npz"))


def _error_line(err):
    lines = [line for line in err.replace("\r", "\n").splitlines() if line.strip() and "task" not in line]
    assert len(lines) == 1 and lines[0].startswith("facecorr: error:"), err
    return lines[0]


def test_cluster_build_errors_are_one_line_and_write_nothing(results, cluster, tmp_path, capsys, monkeypatch):
    import shutil

    import facecorr.pipeline.cluster as cl

    local, _ = cluster
    out = tmp_path / "m.npz"
    address = local.scheduler_address
    # a result mesh a worker cannot read: the worker's error, named by the file
    broken = tmp_path / "broken"
    shutil.copytree(results, broken)
    bad = broken / "S03" / "S03_17.ply"
    bad.write_bytes(b"ply\nformat ascii 1.0\nelement vertex 3\n")
    rc, cap = _main(capsys, "model", "build", broken, "-o", out, "--scheduler", address)
    line = _error_line(cap.err)
    assert rc == 2 and str(bad) in line and "cannot read the result mesh" in line, line
    # a mesh of another template, in the last chunk
    from facecorr.io import save_mesh

    shutil.copy(results / "S03" / "S03_17.ply", bad)
    save_mesh(broken / "S04" / "S04_24.ply", (np.zeros((4, 3)) + np.arange(4)[:, None], np.array([[0, 1, 2]])))
    rc, cap = _main(capsys, "model", "build", broken, "-o", out, "--scheduler", address)
    assert rc == 2 and "S04_24.ply: 4 vertices" in _error_line(cap.err)
    # missing neutral shapes: refused before any cluster is reached (this address has none)
    shutil.copy(results / "S04" / "S04_24.ply", broken / "S04" / "S04_24.ply")
    next(broken.rglob("*_neutral.ply")).unlink()
    rc, cap = _main(capsys, "model", "build", broken, "-o", out, "--neutral", "--scheduler", "tcp://127.0.0.1:9")
    assert rc == 2 and "--neutral needs the expression-removed shape" in _error_line(cap.err)
    # no scheduler there
    monkeypatch.setattr(cl, "CONNECT_TIMEOUT_S", 1)
    rc, cap = _main(capsys, "model", "build", results, "-o", out, "--scheduler", "tcp://127.0.0.1:9")
    assert rc == 2 and "cannot connect to the Dask scheduler" in _error_line(cap.err)
    assert not out.exists() and not list(tmp_path.glob(".m.*"))


def test_workers_that_cannot_read_the_results_are_named(cluster, tmp_path):
    from facecorr.errors import FacecorrError
    from facecorr.pipeline.cluster import check_workers

    _, client = cluster
    with pytest.raises(FacecorrError, match=r"cannot read .*missing.ply: the workers need the results folder at "
                                            r"the same path \(a shared filesystem\)$"):
        check_workers(client, str(tmp_path / "missing.ply"), what="the results folder", fix="")


def test_a_bad_result_on_a_local_cluster_is_one_line_on_stderr(results, tmp_path):
    """`--scheduler local` as a command: the workers' own logs do not add to the one line."""
    import os
    import shutil
    import subprocess
    import sys

    broken = tmp_path / "broken"
    shutil.copytree(results, broken)
    bad = broken / "S02" / "S02_12.ply"
    bad.write_bytes(b"not a mesh")
    r = subprocess.run([sys.executable, "-m", "facecorr.cli", "model", "build", str(broken), "-o",
                        str(tmp_path / "m.npz"), "--scheduler", "local", "--workers", "1"],
                       capture_output=True, text=True, timeout=180, env={**os.environ, "FACECORR_THREADS": "1"})
    assert r.returncode == 2 and r.stdout == "", r
    assert _error_line(r.stderr).startswith(f"facecorr: error: {bad}: cannot read the result mesh"), r.stderr
    assert not (tmp_path / "m.npz").exists()
