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
    assert {"register", "batch", "report", "demo", "eval", "landmarks", "train", "train-identity", "template", "synth"} <= listed, listed
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
    # what the blendshapes miss of the HA scan: one displacement, one mode, mean zero
    out = run_cli("train-identity", db, "--out", tmp_path / "res.npz", "--expression-residual", "--modes", "3")
    assert out.returncode == 0 and "1 modes from 1 scans" in out.stdout, out.stdout + out.stderr
    r = load_identity_basis(tmp_path / "res.npz", n_vertices=load_template().n_vertices)
    assert r.n_modes == 1 and np.all(r.mean == 0) and 0.1 < np.abs(r.modes).max() < 50
    bad = run_cli("train-identity", db, "--out", tmp_path / "none.npz", "--expression-residual", "--neutral-only")
    assert bad.returncode == 2 and "drop --neutral-only" in bad.stderr and not (tmp_path / "none.npz").exists()
    # not a database: one line, exit 2, nothing written
    bad = run_cli("train-identity", tmp_path, "--out", tmp_path / "none.npz")
    assert bad.returncode == 2 and len(bad.stderr.strip().splitlines()) == 1, bad.stderr
    assert "not a synthetic database" in bad.stderr and not (tmp_path / "none.npz").exists()


# --- outputs: checked before the work, written all or nothing; one-line errors -------------------

def _one_error_line(stderr):
    lines = [l for l in stderr.splitlines() if l.strip()]
    assert len(lines) == 1 and lines[0].startswith("facecorr: error:"), stderr
    assert "Traceback" not in stderr
    return lines[0]


def _listing(d):
    return sorted(str(p.relative_to(d)) for p in d.rglob("*"))


@pytest.mark.parametrize("args,what", [
    (["-o", "adir"], "is a folder"),
    (["-o", "r.xyz"], "unknown mesh format"),
    (["-o", "scan.ply"], "overwrite the input"),
    (["-o", "r.ply", "--json", "r.ply"], "different files"),
    (["-o", "r.ply", "--png", "r.ply"], "different files"),
    (["-o", "r.ply", "--json", "afile/r.json"], "is a file, not a folder"),
    (["-o", "afile/sub/r.ply"], "is a file, not a folder"),
    (["-o", "r.ply", "--json", "adir"], "is a folder"),
    (["-o", "r.ply", "--png", "r.txt"], "unknown picture format"),
])
def test_register_bad_outputs_refused_before_the_work(tmp_path, args, what):
    """Refused in well under the registration's time (the scan is not even read), nothing written."""
    (tmp_path / "scan.ply").write_bytes(b"not read before the outputs are checked")
    (tmp_path / "adir").mkdir()
    (tmp_path / "afile").write_text("a file")
    before = _listing(tmp_path)
    r = run_cli("register", "scan.ply", *args, cwd=tmp_path)
    assert r.returncode == 2, r.stderr
    line = _one_error_line(r.stderr)
    assert what in line, line
    assert _listing(tmp_path) == before


def _fake_correspond(mesh, landmarks=None, **kw):
    """A Result shaped like the real one, instantly (these tests are about files, not fitting)."""
    from facecorr.names import LANDMARK_NAMES
    from facecorr.pipeline.correspond import Result
    from facecorr.template import load_template

    t = load_template()
    z = {n: np.zeros(3) for n in LANDMARK_NAMES}
    return Result(vertices=np.asarray(t.vertices, float), faces=np.asarray(t.faces), landmarks=z,
                  landmarks_registered=z, confidence={n: 1.0 for n in LANDMARK_NAMES}, expression_weights={},
                  mhd=0.1, timings_s={"total": 0.0}, to_mm=mesh.to_mm, units=mesh.units)


@pytest.fixture
def fast_register(monkeypatch):
    import importlib

    # the module (facecorr.pipeline re-exports the function under the same name)
    corr = importlib.import_module("facecorr.pipeline.correspond")
    monkeypatch.setattr(corr, "correspond", _fake_correspond)


def _main(capsys, *args):
    from facecorr.cli import main

    rc = main([str(a) for a in args])
    return rc, capsys.readouterr()


def test_register_writes_all_outputs_or_none(tmp_path, one_scan, fast_register, monkeypatch, capsys):
    import facecorr.render as render

    scan = one_scan["scan"]
    out = tmp_path / "o"
    # the picture fails: neither the mesh nor the JSON stays, no temporary file
    def bad_png(*a, **k):
        raise OSError(28, "No space left on device", str(a[2]))
    monkeypatch.setattr(render, "plot_registration", bad_png)
    rc, cap = _main(capsys, "register", scan, "-o", out / "r.ply", "--json", out / "r.json", "--png", out / "r.png")
    assert rc == 2
    line = _one_error_line(cap.err)
    assert str(out / "r.png") in line and "No space" in line and "/.r." not in line, line
    assert not out.exists(), "nothing (not even the folder made for the outputs) may stay"
    # the mesh writer fails with an OSError naming its temporary file: the message names r.ply
    import facecorr.io as fio
    real_save = fio.save_mesh
    monkeypatch.setattr(fio, "save_mesh", lambda p, *a, **k: (_ for _ in ()).throw(OSError(13, "Permission denied", str(p))))
    tmp_path.joinpath("r.json").write_text("old")
    rc, cap = _main(capsys, "register", scan, "-o", tmp_path / "r.ply", "--json", tmp_path / "r.json")
    assert rc == 2
    line = _one_error_line(cap.err)
    assert str(tmp_path / "r.ply") in line and "/.r." not in line, line
    assert (tmp_path / "r.json").read_text() == "old" and not (tmp_path / "r.ply").exists()
    assert not list(tmp_path.glob(".*"))
    # a folder without write permission (simulated: the tests may run as root) is refused first
    monkeypatch.setattr(fio, "save_mesh", real_save)
    import facecorr.io.atomic as atomic
    monkeypatch.setattr(atomic.os, "access", lambda p, mode: False)
    rc, cap = _main(capsys, "register", scan, "-o", tmp_path / "ro" / "r.ply")
    assert rc == 2 and "no permission" in _one_error_line(cap.err)
    monkeypatch.undo()
    # and when everything can be written, everything is
    import importlib
    monkeypatch.setattr(importlib.import_module("facecorr.pipeline.correspond"), "correspond", _fake_correspond)
    rc, cap = _main(capsys, "register", scan, "-o", out / "r.ply", "--json", out / "r.json", "--png", out / "r.png")
    assert rc == 0, cap.err
    assert sorted(p.name for p in out.iterdir()) == ["r.json", "r.ply", "r.png"]


def test_result_save_raises_facecorr_errors_naming_the_path(tmp_path):
    from facecorr.errors import FacecorrError, OutputError
    from facecorr.io import load_mesh

    (tmp_path / "afile").write_text("x")
    mesh = load_mesh(Path_of_tiny_scan(tmp_path))
    res = _fake_correspond(mesh)
    with pytest.raises(OutputError, match="afile is a file"):
        res.save(tmp_path / "afile" / "r.ply")
    with pytest.raises(FacecorrError, match="r.json: is a folder"):
        (tmp_path / "r.json").mkdir()
        res.save(tmp_path / "r.ply", tmp_path / "r.json")
    assert not (tmp_path / "r.ply").exists()
    res.save(tmp_path / "ok.ply", tmp_path / "ok.json")
    assert json.loads((tmp_path / "ok.json").read_text())["mhd"] == pytest.approx(0.1 / mesh.to_mm)


def Path_of_tiny_scan(d):
    from facecorr.io import save_mesh

    p = d / "tiny.ply"
    v = np.array([[0, 0, 0], [100, 0, 0], [0, 120, 0], [0, 0, 80.0]])
    save_mesh(p, (v, np.array([[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]])))
    return p


def test_usage_errors_are_one_line(tmp_path):
    for args in (["register", "s.ply", "-o", "r.ply", "--units", "furlong"], ["register"], ["nosuchcommand"],
                 ["eval", "nosuchthing"], ["batch", "a", "b", "--workers", "two"]):
        r = run_cli(*args, cwd=tmp_path)
        assert r.returncode == 2, (args, r.stderr)
        _one_error_line(r.stderr)
    r = run_cli("register", "s.ply", "-o", "r.ply", "--units", "furlong", cwd=tmp_path)
    assert "furlong" in r.stderr and "--units" in r.stderr
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("lms,what", [
    ({"nose_tip": [1.0, 2.0]}, "landmark nose_tip must be 3 finite numbers"),
    ({"nose_tip": [1.0, "x", 3.0]}, "landmark nose_tip must be 3 finite numbers"),
    ({"nose_tip": None}, "landmark nose_tip must be 3 finite numbers"),
    ({"subnasal": "drop"}, "missing: subnasal"),
    ({"units": "furlong"}, "unknown units 'furlong'"),
])
def test_register_bad_landmarks_json(tmp_path, one_scan, lms, what):
    from facecorr.evaluation import metrics as evaluate

    gt = evaluate.load_ground_truth(one_scan["gt"], load_dense=False)
    data = {"units": "mm", "landmarks": {k: np.asarray(v).tolist() for k, v in gt["landmarks"].items()}}
    for k, v in lms.items():
        if k == "units":
            data["units"] = v
        elif v == "drop":
            del data["landmarks"][k]
        else:
            data["landmarks"][k] = v
    lm = tmp_path / "lm.json"
    lm.write_text(json.dumps(data))
    r = run_cli("register", one_scan["scan"], "-o", tmp_path / "r.ply", "--json", tmp_path / "r.json", "--landmarks", lm)
    assert r.returncode == 2, r.stderr
    line = _one_error_line(r.stderr)
    assert str(lm) in line and what in line, line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["lm.json"]


# --- batch: the folders ---------------------------------------------------------------------------

def test_batch_refuses_bad_folders_and_stem_clashes(tmp_path, one_scan):
    import shutil

    src = tmp_path / "in"
    src.mkdir()
    shutil.copy(one_scan["scan"], src / "face.ply")
    (tmp_path / "afile").write_text("x")
    for out, what in ((tmp_path / "afile", "not a folder"), (src, "must not be the input folder"),
                      (tmp_path / "afile" / "o", "is a file, not a folder")):
        r = run_cli("batch", src, out)
        assert r.returncode == 2, r.stderr
        assert what in _one_error_line(r.stderr)
    shutil.copy(one_scan["scan"], src / "face.obj")  # any content: refused before reading
    r = run_cli("batch", src, tmp_path / "out")
    assert r.returncode == 2
    line = _one_error_line(r.stderr)
    assert "face.ply" in line and "face.obj" in line, line
    assert not (tmp_path / "out").exists()


def test_batch_output_inside_input_and_failures_json_stay_current(tmp_path, one_scan, fast_register, capsys):
    import shutil

    src = tmp_path / "in"
    src.mkdir()
    shutil.copy(one_scan["scan"], src / "good.ply")
    (src / "broken.ply").write_bytes(b"ply\nformat ascii 1.0\nelement vertex 3\n")
    out = src / "out"
    rc, cap = _main(capsys, "batch", src, out, "--workers", "1")
    assert rc == 2 and "1 registered" in cap.out and "1 failed" in cap.out, cap
    assert [f["scan"] for f in json.loads((out / "failures.json").read_text())] == [str(src / "broken.ply")]
    # the outputs inside the input folder are not input; the broken scan is tried again
    rc, cap = _main(capsys, "batch", src, out, "--workers", "1")
    assert rc == 2 and "0 registered, 1 already done, 1 failed" in cap.out, cap.out
    assert not (out / "out").exists()
    # the broken scan is fixed: a run without failures leaves no stale failures.json
    shutil.copy(one_scan["scan"], src / "broken.ply")
    rc, cap = _main(capsys, "batch", src, out, "--workers", "1")
    assert rc == 0 and "1 registered, 1 already done, 0 failed" in cap.out, cap.out
    assert not (out / "failures.json").exists()
    assert sorted(p.name for p in out.iterdir()) == ["broken.json", "broken.ply", "good.json", "good.ply"]
    # a stale failures.json of scans that now have results is removed even when nothing is to do
    (out / "failures.json").write_text(json.dumps([{"scan": str(src / "good.ply"), "ok": False, "error": "old"}]))
    rc, cap = _main(capsys, "batch", src, out, "--workers", "1")
    assert rc == 0 and not (out / "failures.json").exists()


def test_atomic_paths_all_or_nothing(tmp_path, monkeypatch):
    """A group write failing at any step leaves none of its new files and no temporary file."""
    import os

    import facecorr.io.atomic as atomic
    from facecorr.errors import OutputError

    with atomic.atomic_paths(tmp_path / "a.ply", tmp_path / "x" / "b.json") as (ta, tb):
        ta.write_text("a")
        tb.write_text("b")
    assert (tmp_path / "a.ply").read_text() == "a" and (tmp_path / "x" / "b.json").read_text() == "b"
    real, calls = os.replace, []

    def second_rename_fails(src, dst):
        calls.append(dst)
        if len(calls) == 2:
            raise OSError(13, "Permission denied")
        real(src, dst)
    monkeypatch.setattr(atomic.os, "replace", second_rename_fails)
    with pytest.raises(OutputError, match="c.json: cannot write: Permission denied"):
        with atomic.atomic_paths(tmp_path / "c.ply", tmp_path / "c.json") as (tc, td):
            tc.write_text("c")
            td.write_text("d")
    monkeypatch.undo()
    with pytest.raises(OutputError, match=r"/y/e.json: cannot write: No space"):
        with atomic.atomic_paths(tmp_path / "e.ply", tmp_path / "y" / "e.json") as (te, tf):
            te.write_text("e")
            raise OSError(28, "No space left on device", str(tf))
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["a.ply", "b.json", "x"]
    (tmp_path / ".a.abcd1234.ply").write_text("left by a killed run")
    assert atomic.remove_stale_temps(tmp_path / "a.ply") == 1 and (tmp_path / "a.ply").exists()


def test_landmarks_json_output_checked_first(tmp_path):
    (tmp_path / "adir").mkdir()
    (tmp_path / "scan.ply").write_bytes(b"not read")
    for out, what in (("adir", "is a folder"), ("scan.ply", "overwrite the input")):
        r = run_cli("landmarks", "scan.ply", "--json", out, cwd=tmp_path)
        assert r.returncode == 2 and what in _one_error_line(r.stderr), r.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["adir", "scan.ply"]


def test_export_points_collects_every_result(tmp_path):
    from facecorr.names import LANDMARK_NAMES

    res = tmp_path / "results"
    (res / "F0001").mkdir(parents=True)
    for k, stem in enumerate(["F0001/a", "b"]):
        ibug = [[float(k), float(i), 0.5] if i >= 17 else None for i in range(68)]
        (res / f"{stem}.json").write_text(json.dumps({
            "units": "cm", "ibug68": ibug, "landmarks_registered": {n: [1.0, 2.0, 3.0 + k] for n in LANDMARK_NAMES}}))
    (res / "failures.json").write_text("[]")
    out = run_cli("export-points", res, "-o", tmp_path / "pts.csv")
    assert out.returncode == 0, out.stderr
    lines = (tmp_path / "pts.csv").read_text().splitlines()
    assert lines[0] == "scan,point,x,y,z,units" and len(lines) == 1 + 2 * (68 + 8)
    assert "F0001/a,ibug68_20,0.0,20.0,0.5,cm" in lines and "b,ibug68_3,,,,cm" in lines
    assert "b,nose_tip,1.0,2.0,4.0,cm" in lines
    js = run_cli("export-points", res, "-o", tmp_path / "pts.json")
    assert js.returncode == 0 and len(json.loads((tmp_path / "pts.json").read_text())) == 2 * 76
    bad = run_cli("export-points", tmp_path / "pts.csv", "-o", tmp_path / "x.csv")
    assert bad.returncode == 2 and len(bad.stderr.strip().splitlines()) == 1
    none = run_cli("export-points", res, "-o", tmp_path / "x.txt")
    assert none.returncode == 2 and "csv or .json" in none.stderr


def test_register_reads_a_landmark_set_off_the_result(tmp_path, one_scan):
    import trimesh

    from facecorr.template import load_template

    t = load_template()
    f0 = t.faces[10]
    (tmp_path / "set.json").write_text(json.dumps({"v100": 100, "mid": {"face": 10, "bary": [0.2, 0.3, 0.5]}}))
    out = run_cli("register", one_scan["scan"], "-o", tmp_path / "r.ply", "--json", tmp_path / "r.json",
                  "--landmark-set", tmp_path / "set.json")
    assert out.returncode == 0, out.stderr
    v = trimesh.load(tmp_path / "r.ply", process=False).vertices
    pts = json.loads((tmp_path / "r.json").read_text())["point_set"]
    np.testing.assert_allclose(pts["v100"], v[100], atol=1e-4)
    np.testing.assert_allclose(pts["mid"], 0.2 * v[f0[0]] + 0.3 * v[f0[1]] + 0.5 * v[f0[2]], atol=1e-4)
    for bad in ({"x": 10 ** 7}, {"x": {"face": 1, "bary": [0.5, 0.6, 0.1]}}, {"x": "nose"}, []):
        (tmp_path / "bad.json").write_text(json.dumps(bad))
        r = run_cli("register", one_scan["scan"], "-o", tmp_path / "b.ply", "--landmark-set", tmp_path / "bad.json")
        assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
        assert "bad.json" in r.stderr and not (tmp_path / "b.ply").exists()
