"""The command line: contracts, one-line errors with exit 2, no partial output."""

import json
import re
import subprocess
import sys

import numpy as np
import pytest


def run_cli(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "facecorr.cli", *map(str, args)],
                          capture_output=True, text=True, cwd=cwd, timeout=300)


def test_help_lists_every_command():
    out = run_cli("--help")
    assert out.returncode == 0
    # the sub-command names as argparse lists them, one per line, whole words
    listed = set(re.findall(r"^    (\S+)", out.stdout, flags=re.M))
    assert {"register", "batch", "demo", "eval", "landmarks", "train", "train-identity", "template", "synth"} <= listed, listed
    sub = run_cli("eval", "--help")
    assert {"registration", "landmarks"} <= set(re.findall(r"^    (\S+)", sub.stdout, flags=re.M)), sub.stdout


def test_template_json_contract():
    out = run_cli("template", "--json")
    assert out.returncode == 0, out.stderr
    data = json.loads(out.stdout)
    assert data["n_vertices"] > 1000
    assert len(data["ibug68"]) == 68
    assert set(data["landmarks"]) == {
        "right_outer_eye_corner", "right_inner_eye_corner", "left_inner_eye_corner",
        "left_outer_eye_corner", "right_subalare", "left_subalare", "nose_tip", "subnasal"}
    assert "regions" in data


@pytest.mark.parametrize("content,what", [
    (None, "missing file"),
    (b"", "empty file"),
    (b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\n", "truncated PLY"),
    (b"this is not a mesh at all\n", "garbage"),
])
def test_register_bad_input_is_one_line_exit_2_and_no_output(tmp_path, content, what):
    scan = tmp_path / "scan.ply"
    if content is not None:
        scan.write_bytes(content)
    out_ply = tmp_path / "out.ply"
    out_json = tmp_path / "out.json"
    r = run_cli("register", scan, "-o", out_ply, "--json", out_json)
    assert r.returncode == 2, (what, r.stderr)
    lines = [l for l in r.stderr.splitlines() if l.strip()]
    assert len(lines) == 1 and lines[0].startswith("facecorr: error:"), (what, r.stderr)
    assert "Traceback" not in r.stderr
    assert not out_ply.exists() and not out_json.exists()
    assert not list(tmp_path.glob(".out*")), "temporary files left behind"


def test_register_nan_mesh(tmp_path):
    import trimesh

    v = np.random.default_rng(0).normal(size=(30, 3)) * 50
    v[3] = np.nan
    f = np.array([[0, 1, 2], [3, 4, 5], [6, 7, 8]])
    scan = tmp_path / "nan.obj"
    scan.write_text("".join(f"v {a} {b} {c}\n" for a, b, c in v) + "".join(f"f {a+1} {b+1} {c+1}\n" for a, b, c in f))
    r = run_cli("register", scan, "-o", tmp_path / "o.ply")
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert not (tmp_path / "o.ply").exists()


def test_atomic_write_leaves_usual_permissions_and_nothing_on_failure(tmp_path):
    import os

    from facecorr.io.atomic import atomic_path, write_json

    write_json(tmp_path / "a.json", {"x": 1})
    umask = os.umask(0)
    os.umask(umask)
    assert (tmp_path / "a.json").stat().st_mode & 0o777 == 0o666 & ~umask
    with pytest.raises(RuntimeError):
        with atomic_path(tmp_path / "b.ply") as tmp:
            tmp.write_text("partial")
            raise RuntimeError("writer failed")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.json"]


@pytest.fixture(scope="module")
def one_scan(tmp_path_factory):
    from facecorr.synth import generate_scan

    return generate_scan(tmp_path_factory.mktemp("scan"), subject=1, expression="NE", level=0, seed=5)


def test_batch_survives_a_bad_scan_and_resumes(tmp_path, one_scan):
    """A broken file is reported (exit 2) while the good scan is registered; a rerun redoes nothing."""
    import shutil

    src = tmp_path / "in"
    src.mkdir()
    shutil.copy(one_scan["scan"], src / "good.ply")
    (src / "broken.ply").write_bytes(b"ply\nformat ascii 1.0\nelement vertex 3\n")
    out = tmp_path / "out"
    r = run_cli("batch", src, out, "--workers", "1")
    assert r.returncode == 2, r.stderr
    assert "1 registered" in r.stdout and "1 failed" in r.stdout
    assert (out / "good.ply").exists() and (out / "good.json").exists()
    assert not (out / "broken.ply").exists()
    failures = json.loads((out / "failures.json").read_text())
    assert [f["scan"].endswith("broken.ply") for f in failures] == [True]
    data = json.loads((out / "good.json").read_text())
    assert set(data) >= {"landmarks", "expression_weights", "mhd", "timings_s"}
    import trimesh

    from facecorr.template import load_template

    reg = trimesh.load(out / "good.ply", process=False)
    assert len(reg.vertices) == load_template().n_vertices
    before = (out / "good.ply").stat().st_mtime_ns
    r2 = run_cli("batch", src, out, "--workers", "1")
    assert "1 already done" in r2.stdout and (out / "good.ply").stat().st_mtime_ns == before


def test_register_with_given_landmarks_in_other_units(tmp_path, one_scan):
    """--landmarks in cm on a scan saved in cm: the result comes back in the scan's frame and units."""
    from facecorr.evaluation import metrics as evaluate
    from facecorr.io import load_mesh, save_mesh

    gt = evaluate.load_ground_truth(one_scan["gt"], load_dense=False)
    mesh = load_mesh(one_scan["scan"])
    scan_cm = tmp_path / "scan_cm.ply"
    save_mesh(scan_cm, (mesh.vertices / 10.0, mesh.faces))
    lm = tmp_path / "lm.json"
    lm.write_text(json.dumps({"units": "cm", "landmarks": {k: (v / 10.0).tolist() for k, v in gt["landmarks"].items()}}))
    r = run_cli("register", scan_cm, "-o", tmp_path / "reg.ply", "--json", tmp_path / "reg.json", "--landmarks", lm)
    assert r.returncode == 0, r.stderr
    res = json.loads((tmp_path / "reg.json").read_text())
    assert res["units"] == "cm"
    err = [np.linalg.norm(np.array(res["landmarks_registered"][k]) * 10 - gt["landmarks"][k]) for k in gt["landmarks"]]
    assert np.median(err) < 3.0, err  # mm: the registered template's landmarks land on the true ones


def test_demo_writes_its_outputs(tmp_path):
    r = run_cli("demo", "--out", tmp_path / "demo")
    assert r.returncode == 0, r.stderr
    for name in ("registered.ply", "result.json", "registration.png", "registered_gt_landmarks.ply",
                 "result_gt_landmarks.json", "registration_gt_landmarks.png"):
        assert (tmp_path / "demo" / name).stat().st_size > 0, name
    assert "fully automatic:" in r.stdout and "with the true landmarks:" in r.stdout


def test_process_map_keeps_order_in_spawned_workers():
    import math

    from facecorr.threads import process_map

    jobs = [0.5 * k for k in range(7)]
    assert process_map(math.sqrt, jobs, workers=2, progress=False) == [math.sqrt(j) for j in jobs]
    assert process_map(math.sqrt, jobs, workers=1, progress=False) == [math.sqrt(j) for j in jobs]


def test_train_identity_writes_a_loadable_basis(tmp_path):
    from facecorr.registration.identity import load_identity_basis
    from facecorr.synth import generate
    from facecorr.template import load_template

    db = tmp_path / "db"
    generate(db, preset="tiny", seed=5, workers=2, expressions=["NE", "HA"], levels=[4], progress=False)
    out = run_cli("train-identity", db, "--out", tmp_path / "basis.npz", "--modes", "3")
    assert out.returncode == 0, out.stderr
    assert "1 modes from 2 scans" in out.stdout  # one training subject (F0001) x NE, HA: rank 1
    b = load_identity_basis(tmp_path / "basis.npz", n_vertices=load_template().n_vertices)
    assert b.n_modes == 1 and b.n_samples == 2 and np.isfinite(b.modes).all()
    # not a database: one line, exit 2, nothing written
    bad = run_cli("train-identity", tmp_path, "--out", tmp_path / "none.npz")
    assert bad.returncode == 2 and len(bad.stderr.strip().splitlines()) == 1, bad.stderr
    assert "not a synthetic database" in bad.stderr and not (tmp_path / "none.npz").exists()
