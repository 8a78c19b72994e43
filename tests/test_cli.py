"""The command line: contracts, one-line errors with exit 2, no partial output."""

import json
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
    for cmd in ("register", "batch", "demo", "eval", "landmarks", "train", "template", "synth"):
        assert cmd in out.stdout


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

    from facecorr.fileio import atomic_path, write_json

    write_json(tmp_path / "a.json", {"x": 1})
    umask = os.umask(0)
    os.umask(umask)
    assert (tmp_path / "a.json").stat().st_mode & 0o777 == 0o666 & ~umask
    with pytest.raises(RuntimeError):
        with atomic_path(tmp_path / "b.ply") as tmp:
            tmp.write_text("partial")
            raise RuntimeError("writer failed")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.json"]
