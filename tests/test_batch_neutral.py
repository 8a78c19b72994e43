"""`facecorr batch --neutral`: <stem>_neutral.ply beside each result, resumable, written with its result.

The registration is replaced by an instant fake (these tests are about the files): every call
returns the template moved by one more millimetre, and its "neutral shape" is that minus 1 mm in
x, so a file tells which call wrote it and whether the neutral shape belongs to the mesh beside it.
"""

import itertools
import json
import shutil

import numpy as np
import pytest
import trimesh

CALLS = itertools.count(1)


def _fake_correspond(mesh, landmarks=None, **kw):
    from facecorr.names import LANDMARK_NAMES
    from facecorr.pipeline.correspond import Result
    from facecorr.template import load_template

    t = load_template()
    v = np.asarray(t.vertices, float) + next(CALLS)
    z = {n: np.zeros(3) for n in LANDMARK_NAMES}
    return Result(vertices=v, faces=np.asarray(t.faces), landmarks=z, landmarks_registered=z,
                  confidence={n: 1.0 for n in LANDMARK_NAMES}, expression_weights={}, mhd=0.1,
                  timings_s={"total": 0.0}, to_mm=mesh.to_mm, units=mesh.units,
                  neutral_vertices=v - np.array([1.0, 0.0, 0.0]), neutral_removed={})


@pytest.fixture
def fast_register(monkeypatch):
    import importlib

    monkeypatch.setattr(importlib.import_module("facecorr.pipeline.correspond"), "correspond", _fake_correspond)


@pytest.fixture(scope="module")
def scan(tmp_path_factory):
    from facecorr.synth import generate_scan

    return generate_scan(tmp_path_factory.mktemp("scan"), subject=1, expression="NE", level=0, seed=5,
                         spacing=2.0)["scan"]


def _main(capsys, *args):
    from facecorr.cli import main

    rc = main([str(a) for a in args])
    return rc, capsys.readouterr()


def _vertices(path):
    return np.asarray(trimesh.load(path, process=False).vertices)


def _written_by(out, stem):
    """The fake call that wrote <stem>.ply, and that of <stem>_neutral.ply (None if absent)."""
    from facecorr.template import load_template

    t = np.asarray(load_template().vertices, float)
    mesh = _vertices(out / f"{stem}.ply") - t
    call = int(round(mesh[0, 0]))
    assert np.allclose(mesh, call)
    neutral = out / f"{stem}_neutral.ply"
    if not neutral.exists():
        return call, None
    n = _vertices(neutral) - t + np.array([1.0, 0.0, 0.0])
    return call, int(round(n[0, 0]))


def test_batch_neutral_adds_the_missing_files_and_keeps_each_group_whole(tmp_path, scan, fast_register, capsys):
    src, out = tmp_path / "in", tmp_path / "out"
    (src / "sub").mkdir(parents=True)
    shutil.copy(scan, src / "a.ply")
    shutil.copy(scan, src / "sub" / "b.ply")
    rc, cap = _main(capsys, "batch", src, out, "--workers", "1")
    assert rc == 0 and "2 registered, 0 already done" in cap.out, cap
    assert not list(out.rglob("*_neutral.ply"))
    # a rerun with --neutral over results without it: each scan is done again, all its files
    # written together (the neutral shape belongs to the mesh beside it)
    rc, cap = _main(capsys, "batch", src, out, "--workers", "1", "--neutral")
    assert rc == 0 and "2 registered, 0 already done" in cap.out, cap
    assert sorted(str(p.relative_to(out)) for p in out.rglob("*")) == [
        "a.json", "a.ply", "a_neutral.ply", "sub", "sub/b.json", "sub/b.ply", "sub/b_neutral.ply"]
    for stem in ("a", "sub/b"):
        call, neutral_call = _written_by(out, stem)
        assert neutral_call == call and call > 2
        assert json.loads((out / f"{stem}.json").read_text())["neutral_expression_removed"] == {}
    a_ply_mtime = (out / "a.ply").stat().st_mtime_ns
    # complete: nothing to do
    rc, cap = _main(capsys, "batch", src, out, "--workers", "1", "--neutral")
    assert rc == 0 and "0 registered, 2 already done" in cap.out, cap
    assert (out / "a.ply").stat().st_mtime_ns == a_ply_mtime
    # a result that lost its JSON is redone by a run without --neutral: its old neutral shape is
    # rewritten with it (it must not describe an older registration); the other scan is untouched
    (out / "a.json").unlink()
    before_b = _written_by(out, "sub/b")
    rc, cap = _main(capsys, "batch", src, out, "--workers", "1")
    assert rc == 0 and "1 registered, 1 already done" in cap.out, cap
    call, neutral_call = _written_by(out, "a")
    assert neutral_call == call and call > max(before_b)
    assert _written_by(out, "sub/b") == before_b
    # --overwrite without --neutral keeps every group whole too
    rc, cap = _main(capsys, "batch", src, out, "--workers", "1", "--overwrite")
    assert rc == 0 and "2 registered" in cap.out
    assert all(n == c for c, n in (_written_by(out, s) for s in ("a", "sub/b")))
    # a lost neutral shape alone makes its scan a job again
    (out / "sub" / "b_neutral.ply").unlink()
    rc, cap = _main(capsys, "batch", src, out, "--workers", "1", "--neutral")
    assert rc == 0 and "1 registered, 1 already done" in cap.out, cap
    assert _written_by(out, "sub/b")[0] == _written_by(out, "sub/b")[1]
    assert not list(out.rglob(".*")), "temporary files left"


def test_batch_neutral_writes_all_of_a_scans_files_or_none(tmp_path, scan, fast_register, capsys):
    src, out = tmp_path / "in", tmp_path / "out"
    src.mkdir()
    shutil.copy(scan, src / "a.ply")
    shutil.copy(scan, src / "c.ply")
    (out / "c_neutral.ply").mkdir(parents=True)  # the neutral shape cannot be written there
    rc, cap = _main(capsys, "batch", src, out, "--workers", "1", "--neutral")
    assert rc == 2 and "1 registered, 0 already done, 1 failed" in cap.out, cap
    assert "c_neutral.ply: is a folder" in cap.err, cap.err
    assert sorted(p.name for p in out.iterdir()) == ["a.json", "a.ply", "a_neutral.ply", "c_neutral.ply",
                                                     "failures.json"]
    failures = json.loads((out / "failures.json").read_text())
    assert [f["scan"] for f in failures] == [str(src / "c.ply")]


def test_batch_neutral_refuses_a_scan_named_like_a_neutral_shape(tmp_path, scan, capsys):
    src, out = tmp_path / "in", tmp_path / "out"
    src.mkdir()
    shutil.copy(scan, src / "face.ply")
    shutil.copy(scan, src / "face_neutral.ply")
    rc, cap = _main(capsys, "batch", src, out, "--workers", "1", "--neutral")
    lines = [ln for ln in cap.err.splitlines() if ln.strip()]
    assert rc == 2 and len(lines) == 1 and lines[0].startswith("facecorr: error:"), cap.err
    assert "face.ply's expression-removed shape would be written to" in lines[0] and "rename" in lines[0]
    assert not out.exists()
