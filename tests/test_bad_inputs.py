"""Bad and unusual input: a matrix of generated cases through the CLI (register, landmarks, batch)
and the API, each with the outcome the README promises.

Outcomes: ``user error`` = exit 2 (FacecorrError in the API), one line ``facecorr: error: ...`` on
stderr and no output file; ``same`` = the result equals the clean scan's (moved back into its
frame where the case moved it); ``flagged`` = a result whose flags name the problem.
"""

import gzip
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from facecorr.errors import FacecorrError, LandmarkError, MeshError
from facecorr.geometry.mesh import Mesh
from facecorr.io import load_mesh, save_mesh


def run_cli(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "facecorr.cli", *map(str, args)],
                          capture_output=True, text=True, cwd=cwd, timeout=300)


def assert_user_error(r, out_dir: Path, keep=()):
    """Exit 2, one line on stderr, and nothing written to ``out_dir`` but the files in ``keep``."""
    assert r.returncode == 2, (r.returncode, r.stdout, r.stderr)
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("facecorr: error: "), r.stderr
    assert ".tmp" not in lines[0] and "/." not in lines[0], lines[0]  # names the user's paths, not temp files
    left = sorted(p.name for p in out_dir.iterdir() if p.name not in keep)
    assert left == [], left


@pytest.fixture(scope="module")
def scan(tmp_path_factory):
    """A synthetic scan (mm, random pose) on disk, and its Mesh."""
    from facecorr.synth import generate_scan

    rec = generate_scan(tmp_path_factory.mktemp("scan"), subject=2, expression="HA", level=4, seed=4)
    return Path(rec["scan"]), load_mesh(rec["scan"])


@pytest.fixture(scope="module")
def clean(scan):
    from facecorr.pipeline import correspond

    return correspond(scan[1])


def _write_obj(path, v, f, header=""):
    lines = [header] if header else []
    lines += [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in v] + [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in f]
    path.write_text("\n".join(lines) + "\n")
    return path


# --- files that are not scans: the CLI refuses them, one line, exit 2, nothing written -------------

def _flat_sheet(d):
    x, y = np.meshgrid(np.linspace(0, 150, 40), np.linspace(0, 150, 40))
    v = np.c_[x.ravel(), y.ravel(), np.zeros(x.size)]
    i = np.arange(39 * 40).reshape(39, 40)[:, :39].ravel()
    f = np.r_[np.c_[i, i + 1, i + 40], np.c_[i + 1, i + 41, i + 40]]
    return _write_obj(d / "sheet.obj", v, f)


def _box(d):
    import trimesh

    m = trimesh.creation.box(extents=(150, 150, 150)).subdivide().subdivide().subdivide()
    return _write_obj(d / "cube.obj", m.vertices, m.faces)


def _sphere(d):
    import trimesh

    m = trimesh.creation.icosphere(subdivisions=5, radius=90.0)
    return _write_obj(d / "sphere.obj", m.vertices, m.faces)


def _file(name, data):
    """A case: a file ``name`` holding ``data`` (bytes or text)."""
    def make(d):
        path = d / name
        path.write_bytes(data if isinstance(data, bytes) else data.encode())
        return path
    return make


NOT_SCANS = {
    "missing file": lambda d: d / "nothing.ply",
    "empty file": _file("e.ply", b""),
    "garbage text": _file("g.ply", "this is not a mesh\n"),
    "truncated binary PLY": _file("t.ply", b"ply\nformat binary_little_endian 1.0\nelement vertex 100\nproperty float x\n"
                                  b"property float y\nproperty float z\nelement face 10\n"
                                  b"property list uchar int vertex_indices\nend_header\n" + b"\0" * 40),
    "gzip named .obj": _file("z.obj", gzip.compress(b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")),
    "PNG named .ply": _file("p.ply", b"\x89PNG\r\n\x1a\n" + b"\0" * 64),
    "unknown extension": _file("s.xyz", "0 0 0\n"),
    "NaN coordinates": _file("n.obj", "v 0 0 0\nv nan 0 0\nv 0 100 0\nf 1 2 3\n"),
    "point cloud": _file("pc.obj", "v 0 0 0\nv 100 0 0\nv 0 100 0\n"),
    "index out of range": _file("r.off", "OFF\n3 1 0\n0 0 0\n100 0 0\n0 100 0\n3 0 1 7\n"),
    "float face index": _file("fl.off", "OFF\n3 1 0\n0 0 0\n100 0 0\n0 100 0\n3 0 1.5 2\n"),
    "a flat sheet (no nose)": _flat_sheet,
    "a folder": lambda d: (d / "folder.ply").mkdir() or d / "folder.ply",  # mkdir returns None
}


CLI_CASES = [("register", c) for c in sorted(NOT_SCANS)] + \
    [("landmarks", c) for c in ("garbage text", "a flat sheet (no nose)", "point cloud")]


@pytest.mark.parametrize("command, case", CLI_CASES)
def test_the_cli_refuses_what_is_not_a_scan(tmp_path, command, case):
    src = tmp_path / "in"
    src.mkdir()
    path = NOT_SCANS[case](src)
    out = tmp_path / "out"
    out.mkdir()
    outputs = ["-o", out / "r.ply", "--json", out / "r.json"] if command == "register" else ["--json", out / "l.json"]
    assert_user_error(run_cli(command, path, *outputs), out)


@pytest.mark.parametrize("make", [_box, _sphere], ids=["cube", "sphere"])
def test_shapes_that_are_not_faces_are_refused_or_flagged(tmp_path, make):
    from facecorr.pipeline import correspond

    mesh = load_mesh(make(tmp_path))
    try:
        res = correspond(mesh)
    except FacecorrError:
        return
    failure = ("implausible_fit", "poor_face_fit", "graph_off_surface", "low_coverage", "landmark_off_surface")
    assert any(f.startswith(failure) for f in res.flags), res.flags


# --- the user's mistakes in options and outputs ----------------------------------------------------

def test_units_that_do_not_exist(tmp_path, scan):
    r = run_cli("register", scan[0], "-o", tmp_path / "r.ply", "--units", "furlong")
    assert_user_error(r, tmp_path)


def test_scan_declared_in_the_wrong_units(tmp_path, scan):
    r = run_cli("register", scan[0], "-o", tmp_path / "r.ply", "--units", "m")  # a 200 m face
    assert_user_error(r, tmp_path)


def test_micrometres_are_not_guessed(tmp_path, scan):
    m = scan[1]
    save_mesh(tmp_path / "um.ply", (m.vertices * 1000.0, m.faces))
    out = tmp_path / "out"
    out.mkdir()
    assert_user_error(run_cli("register", tmp_path / "um.ply", "-o", out / "r.ply"), out)


@pytest.mark.parametrize("what", ["existing folder", "unknown extension", "the input scan", "same as --json",
                                  "parent is a file"])
def test_bad_output_paths(tmp_path, scan, what):
    src = tmp_path / "scan.ply"
    src.write_bytes(scan[0].read_bytes())
    out = tmp_path / "out"
    out.mkdir()
    (out / "dir.ply").mkdir()
    (out / "file").write_text("x")
    args = {"existing folder": ["-o", out / "dir.ply"],
            "unknown extension": ["-o", out / "r.xyz"],
            "the input scan": ["-o", src],
            "same as --json": ["-o", out / "r.ply", "--json", out / "r.ply"],
            "parent is a file": ["-o", out / "r.ply", "--json", out / "file" / "r.json"]}[what]
    r = run_cli("register", src, *args)
    assert_user_error(r, out, keep=("dir.ply", "file"))
    assert src.read_bytes() == scan[0].read_bytes()  # the scan is never overwritten


def _landmarks_json(path, positions, units="mm"):
    path.write_text(json.dumps({"units": units, "landmarks": {k: list(map(float, v)) for k, v in positions.items()}}))
    return path


@pytest.mark.parametrize("what", ["500 mm off", "a 2-number point", "one missing", "not JSON", "unknown units"])
def test_bad_landmark_files(tmp_path, scan, clean, what):
    lms = {k: np.asarray(v) for k, v in clean.landmarks.items()}
    if what == "500 mm off":
        lms = {k: v + 500.0 for k, v in lms.items()}
    elif what == "a 2-number point":
        lms["nose_tip"] = lms["nose_tip"][:2]
    elif what == "one missing":
        del lms["subnasal"]
    lm = tmp_path / "lm.json"
    if what == "not JSON":
        lm.write_text("{landmarks: ")
    else:
        _landmarks_json(lm, lms, units="furlong" if what == "unknown units" else "mm")
    out = tmp_path / "out"
    out.mkdir()
    r = run_cli("register", scan[0], "-o", out / "r.ply", "--json", out / "r.json", "--landmarks", lm)
    assert_user_error(r, out)


def test_api_landmarks_off_the_scan_or_malformed(scan, clean):
    from facecorr.pipeline import correspond

    far = {k: np.asarray(v) + 500.0 for k, v in clean.landmarks.items()}
    with pytest.raises(LandmarkError, match="not on the scan"):
        correspond(scan[1], landmarks=far)
    with pytest.raises(LandmarkError, match="3 finite numbers"):
        correspond(scan[1], landmarks={**clean.landmarks, "nose_tip": [1.0, 2.0]})
    with pytest.raises(LandmarkError, match="dict"):
        correspond(scan[1], landmarks=[1, 2, 3])


def test_api_meshes_that_cannot_be(scan):
    m = scan[1]
    with pytest.raises(MeshError, match="integers"):
        Mesh(m.vertices, m.faces.astype(float) + 0.5)
    bad = m.vertices.copy()
    bad[3] = np.nan
    with pytest.raises(MeshError, match="NaN"):
        Mesh(bad, m.faces)
    with pytest.raises(MeshError, match="no faces"):
        Mesh(m.vertices, np.zeros((0, 3), int))


# --- valid scans stored unusually: the same answer -------------------------------------------------

def _same(res, clean, move=lambda x: x, tol=1e-3):
    d = np.linalg.norm(move(clean.vertices) - res.vertices, axis=1).max()
    assert d < tol, d


@pytest.mark.parametrize("shift", [1e3, 1e5], ids=["1 m away", "100 m away"])
def test_a_scan_far_from_the_origin(scan, clean, shift):
    from facecorr.pipeline import correspond

    m = scan[1]
    t = np.array([shift, shift, 0.0])
    res = correspond(Mesh(m.vertices + t, m.faces))
    _same(res, clean, lambda x: x + t)


def test_reversed_winding(scan, clean):
    from facecorr.pipeline import correspond

    m = scan[1]
    _same(correspond(Mesh(m.vertices, m.faces[:, [0, 2, 1]])), clean)


@pytest.mark.parametrize("units", ["cm", "m"])
def test_float32_in_other_units_from_disk(tmp_path, scan, clean, units):
    import trimesh

    from facecorr.pipeline import correspond

    m = scan[1]
    factor = {"cm": 10.0, "m": 1000.0}[units]
    path = tmp_path / f"s_{units}.ply"
    trimesh.Trimesh((m.vertices / factor).astype(np.float32), m.faces, process=False).export(path)
    loaded = load_mesh(path)
    assert loaded.units == units
    res = correspond(loaded)
    _same(res, clean, tol=0.01)  # float32 rounding of the input (~1e-5 mm) must not move the answer


def test_crlf_obj_from_disk(tmp_path, scan, clean):
    m = scan[1]
    path = tmp_path / "crlf.obj"
    _write_obj(path, m.vertices, m.faces)
    path.write_bytes(path.read_bytes().replace(b"\n", b"\r\n"))
    loaded = load_mesh(path)
    np.testing.assert_allclose(loaded.vertices, m.vertices, atol=1e-5)
    np.testing.assert_array_equal(loaded.faces, m.faces)


# --- faces that are odd but valid: a result, with the problem named --------------------------------

def test_an_upside_down_face(scan, clean):
    from facecorr.pipeline import correspond

    m = scan[1]
    c = m.vertices.mean(axis=0)
    r = np.diag([-1.0, -1.0, 1.0])  # 180 degrees about z through the centroid
    res = correspond(Mesh((m.vertices - c) @ r.T + c, m.faces))
    err = np.linalg.norm(((clean.vertices - c) @ r.T + c) - res.vertices, axis=1)
    assert np.median(err) < 1.0, np.median(err)


def test_a_mirrored_face(scan, clean):
    from facecorr.pipeline import correspond

    m = scan[1]
    mirror = np.array([-1.0, 1.0, 1.0])
    res = correspond(Mesh(m.vertices * mirror, m.faces[:, [0, 2, 1]]))
    assert res.mhd < 2.0 and not any(f.startswith("implausible_fit") for f in res.flags), res.flags
    # the subject's right eye corner of the mirror image is the mirror of the left one
    d = np.linalg.norm(res.landmarks["right_outer_eye_corner"] - clean.landmarks["left_outer_eye_corner"] * mirror)
    assert d < 6.0, d


def test_three_copies_of_a_face(scan):
    from facecorr.pipeline import correspond

    m = scan[1]
    n = len(m.vertices)
    v = np.vstack([m.vertices + [k * 400.0, 0, 0] for k in range(3)])
    f = np.vstack([m.faces + k * n for k in range(3)])
    res = correspond(Mesh(v, f))
    assert any(f.startswith("several_pieces") for f in res.flags), res.flags
    assert res.mhd < 2.0


def test_a_two_metre_spike(scan, clean):
    from facecorr.pipeline import correspond

    m = scan[1]
    v = m.vertices.copy()
    tip = np.argmax(v[:, 2])
    v[tip] = v[tip] + 2000.0 * m.vertex_normals[tip]
    res = correspond(Mesh(v, m.faces))
    err = np.linalg.norm(res.vertices - clean.vertices, axis=1)
    assert np.median(err) < 0.5, np.median(err)


def test_a_two_metre_spike_from_disk_keeps_its_units(tmp_path, scan):
    m = scan[1]
    v = m.vertices.copy()
    v[0] = v[0] + [0.0, 0.0, 2000.0]
    save_mesh(tmp_path / "spike.ply", (v, m.faces))
    assert load_mesh(tmp_path / "spike.ply").units == "mm"


def _cut(mesh, keep):
    sub, _ = mesh.submesh(keep)
    return sub


def test_a_half_face_names_the_missing_landmarks(scan, clean):
    from facecorr.pipeline import correspond

    m = scan[1]
    # keep the subject's left half: the side of the left eye corners
    centre = 0.5 * (clean.landmarks["left_inner_eye_corner"] + clean.landmarks["right_inner_eye_corner"])
    side = clean.landmarks["left_outer_eye_corner"] - clean.landmarks["right_outer_eye_corner"]
    keep = (m.vertices - centre) @ side > 5.0
    try:
        res = correspond(_cut(m, keep))
    except FacecorrError:
        return
    names = " ".join(res.flags)
    assert "right_outer_eye_corner" in names, res.flags  # the missing side is named
    doubt = ("low_coverage", "implausible_fit", "implausible_face_scale", "poor_face_fit", "graph_off_surface")
    assert any(f.startswith(doubt) for f in res.flags), (res.coverage, res.flags)


def test_a_hole_over_the_nose_is_flagged(scan, clean):
    from facecorr.pipeline import correspond

    m = scan[1]
    keep = np.linalg.norm(m.vertices - clean.landmarks["nose_tip"], axis=1) > 25.0
    try:
        res = correspond(_cut(m, keep))
    except FacecorrError:
        return
    assert any("nose_tip" in f or f.startswith(("graph_off_surface", "low_coverage", "implausible_fit"))
               for f in res.flags), res.flags


def test_coverage_of_a_clean_scan_is_reported(tmp_path, scan, clean):
    assert 0.8 < clean.coverage <= 1.0
    clean.save(tmp_path / "r.ply", tmp_path / "r.json")
    assert json.loads((tmp_path / "r.json").read_text())["coverage"] == pytest.approx(clean.coverage, abs=1e-4)


# --- batch ------------------------------------------------------------------------------------------

def test_batch_output_is_a_file(tmp_path, scan):
    src = tmp_path / "in"
    src.mkdir()
    (src / "a.ply").write_bytes(scan[0].read_bytes())
    (tmp_path / "out").write_text("x")
    r = run_cli("batch", src, tmp_path / "out")
    assert r.returncode == 2 and r.stderr.strip().startswith("facecorr: error:"), r.stderr
    assert len(r.stderr.strip().splitlines()) == 1


def test_batch_refuses_two_scans_with_one_stem(tmp_path, scan):
    src = tmp_path / "in"
    src.mkdir()
    (src / "face.ply").write_bytes(scan[0].read_bytes())
    save_mesh(src / "face.obj", (scan[1].vertices, scan[1].faces))
    out = tmp_path / "out"
    r = run_cli("batch", src, out)
    assert r.returncode == 2 and "face" in r.stderr, r.stderr
    assert not out.exists() or not any(out.rglob("*.ply"))


def test_batch_keeps_going_past_a_bad_scan_and_reports_it(tmp_path, scan):
    src = tmp_path / "in"
    src.mkdir()
    (src / "good.ply").write_bytes(scan[0].read_bytes())
    (src / "bad.ply").write_text("not a mesh\n")
    out = src / "results"  # inside the input folder: must not be read back as input
    r = run_cli("batch", src, out, "--workers", "1")
    assert r.returncode == 2, r.stderr
    assert (out / "good.ply").exists() and (out / "good.json").exists()
    failures = json.loads((out / "failures.json").read_text())
    assert [Path(f["scan"]).name for f in failures] == ["bad.ply"]
    (src / "bad.ply").unlink()
    r2 = run_cli("batch", src, out, "--workers", "1")
    assert r2.returncode == 0, r2.stderr
    assert not (out / "results").exists()  # the first run's outputs were not registered again
    assert not (out / "failures.json").exists() or json.loads((out / "failures.json").read_text()) == []


def test_a_scan_above_the_size_limit_is_refused_with_advice(tmp_path, scan, monkeypatch):
    import facecorr.io.load as load

    monkeypatch.setattr(load, "MAX_VERTICES", 1000)
    with pytest.raises(MeshError, match="decimate the scan first"):
        load_mesh(scan[0])


def test_result_json_carries_the_ibug68_points(tmp_path, clean, t):
    clean.save(tmp_path / "r.ply", tmp_path / "r.json")
    pts = json.loads((tmp_path / "r.json").read_text())["ibug68"]
    assert len(pts) == 68
    for k, (p, vid) in enumerate(zip(pts, t.ibug68)):
        if vid < 0:
            assert p is None
        else:
            np.testing.assert_allclose(p, clean.vertices[vid], atol=1e-9)
    assert sum(p is not None for p in pts) >= 51  # every point but the outer jaw line
