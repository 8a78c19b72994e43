"""Statistical shape models: Procrustes against a numpy reference and known transforms, PCA against
numpy's SVD, the model's sample / project / Mahalanobis, the npz and statismo files, reading a
results folder, and `facecorr model build | show | export | eval` on a small real batch."""

import json

import numpy as np
import pytest

from facecorr.errors import ShapeModelError
from facecorr.model import ShapeModel, fit_model, generalized_procrustes, principal_components, read_results
from facecorr.model.pca import n_modes_for


def random_rotation(rng):
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q *= np.sign(np.diag(r))
    if np.linalg.det(q) < 0:
        q[:, 0] *= -1
    return q


def reference_gpa(shapes, scale, iterations=200):
    """A plain numpy GPA, one shape at a time: centre, then alternate Kabsch/Umeyama fits onto the
    mean and re-averaging (mean held at unit size under similarity)."""
    x = [s - s.mean(0) for s in np.asarray(shapes, float)]
    mean = x[0] / np.linalg.norm(x[0]) if scale else x[0]
    for _ in range(iterations):
        out = []
        for s in x:
            u, sig, vt = np.linalg.svd(s.T @ mean)
            d = np.diag([1, 1, np.sign(np.linalg.det(vt.T @ u.T))])
            r = vt.T @ d @ u.T
            c = np.trace(np.diag(sig) @ d) / np.sum(s * s) if scale else 1.0
            out.append(c * s @ r.T)
        mean = np.mean(out, axis=0)
        if scale:
            mean /= np.linalg.norm(mean)
    return np.array(out)


def _same_up_to_one_similarity(a, b):
    """Residual of fitting the stacked shapes ``a`` onto ``b`` by one similarity transform."""
    from facecorr.geometry.transforms import kabsch

    pa, pb = a.reshape(-1, 3), b.reshape(-1, 3)
    r, s, t = kabsch(pa, pb, with_scale=True)
    return np.abs(s * pa @ r.T + t - pb).max()


# --- generalized Procrustes -----------------------------------------------------------------------

@pytest.mark.parametrize("scale", [False, True])
def test_gpa_matches_a_numpy_reference_on_noisy_shapes(scale):
    rng = np.random.default_rng(1)
    base = rng.normal(size=(60, 3)) * [40, 50, 20]
    shapes = []
    for i in range(12):
        s = (base + rng.normal(size=base.shape) * 2.0) @ random_rotation(rng).T
        shapes.append(s * (rng.uniform(0.7, 1.4) if scale else 1.0) + rng.normal(size=3) * 100)
    got = generalized_procrustes(shapes, scale=scale, tolerance=1e-13, max_iterations=500)
    want = reference_gpa(shapes, scale)
    assert got.converged
    assert _same_up_to_one_similarity(got.aligned, want) < 1e-6
    # the stored transforms reproduce the aligned shapes
    again = np.einsum("s,snj,sij->sni", got.scales, np.asarray(shapes), got.rotations) + got.translations[:, None]
    np.testing.assert_allclose(again, got.aligned, atol=1e-9)
    np.testing.assert_allclose(np.linalg.det(got.rotations), 1.0, atol=1e-12)


def test_gpa_recovers_known_rigid_transforms():
    rng = np.random.default_rng(2)
    base = rng.normal(size=(80, 3)) * [40, 50, 20]
    q = [random_rotation(rng) for _ in range(9)]
    d = rng.normal(size=(9, 3)) * 200
    shapes = np.array([base @ qi.T + di for qi, di in zip(q, d)])
    got = generalized_procrustes(shapes, reference=base)
    np.testing.assert_allclose(got.mean, base, atol=1e-9)
    for i in range(9):
        np.testing.assert_allclose(got.rotations[i], q[i].T, atol=1e-9)  # undoes each rotation
        np.testing.assert_allclose(got.translations[i], -d[i] @ q[i], atol=1e-7)
    np.testing.assert_allclose(got.scales, 1.0)


def test_gpa_recovers_known_similarity_transforms():
    rng = np.random.default_rng(3)
    base = rng.normal(size=(80, 3)) * [40, 50, 20]
    base -= base.mean(0)
    q = [random_rotation(rng) for _ in range(7)]
    c = rng.uniform(0.5, 2.0, size=7)
    shapes = np.array([ci * base @ qi.T + rng.normal(size=3) * 50 for qi, ci in zip(q, c)])
    got = generalized_procrustes(shapes, scale=True, reference=base)
    # the mean keeps the inputs' average size: base times the mean of the scales
    np.testing.assert_allclose(got.mean, base * c.mean(), atol=1e-8)
    np.testing.assert_allclose(got.scales * c, c.mean(), rtol=1e-10)
    for i in range(7):
        np.testing.assert_allclose(got.rotations[i], q[i].T, atol=1e-9)
    # rigid GPA on the same shapes keeps their sizes
    rigid = generalized_procrustes(shapes)
    from facecorr.model.procrustes import centroid_size

    np.testing.assert_allclose(centroid_size(rigid.aligned), c * centroid_size(base), rtol=1e-10)


# --- PCA ------------------------------------------------------------------------------------------

@pytest.mark.parametrize("n,d", [(30, 300), (50, 8)])
def test_pca_matches_numpy_svd(n, d):
    rng = np.random.default_rng(4)
    x = rng.normal(size=(n, d)) * np.geomspace(10, 0.1, d) + rng.normal(size=d) * 5
    p = principal_components(x)
    xc = x - x.mean(0)
    _, sig, vt = np.linalg.svd(xc, full_matrices=False)
    k = min(n - 1, d)
    assert len(p.variances) == k
    np.testing.assert_allclose(p.variances, sig[:k] ** 2 / (n - 1), rtol=1e-9)
    signs = np.sign(np.sum(p.components * vt[:k], axis=1))
    np.testing.assert_allclose(p.components * signs[:, None], vt[:k], atol=1e-7)
    np.testing.assert_allclose(p.components @ p.components.T, np.eye(k), atol=1e-10)
    np.testing.assert_allclose(p.scores, xc @ p.components.T, atol=1e-8)
    assert p.total_variance == pytest.approx(np.sum(xc ** 2) / (n - 1), rel=1e-10)
    assert np.all(np.diff(p.variances) <= 0)


def test_pca_mode_selection():
    v = np.array([50.0, 30.0, 15.0, 5.0])
    assert n_modes_for(v, 100.0, variance=0.5) == 1
    assert n_modes_for(v, 100.0, variance=0.8) == 2
    assert n_modes_for(v, 100.0, variance=0.81) == 3
    assert n_modes_for(v, 100.0, variance=1.0) == 4
    assert n_modes_for(v, 100.0, modes=2) == 2 and n_modes_for(v, 100.0, modes=9) == 4
    rng = np.random.default_rng(5)
    x = rng.normal(size=(20, 40)) * np.geomspace(10, 0.01, 40)
    p = principal_components(x, variance=0.9)
    kept = p.variances.sum() / p.total_variance
    assert kept >= 0.9 and (p.variances[:-1].sum() / p.total_variance) < 0.9


# --- the model on template-sized shapes -----------------------------------------------------------

def _without_rigid_part(field, points):
    """``field`` (N, 3) minus its least-squares translation + infinitesimal rotation, so that a
    Procrustes alignment leaves it (to first order) alone."""
    c = points - points.mean(0)
    gen = [np.tile(e, (len(c), 1)) for e in np.eye(3)] + [np.cross(e, c) for e in np.eye(3)]
    a = np.stack([g.ravel() for g in gen], axis=1)
    coef, *_ = np.linalg.lstsq(a, field.ravel(), rcond=None)
    return field - (a @ coef).reshape(field.shape)


@pytest.fixture(scope="module")
def population(t):
    """25 faces: the template deformed by 4 smooth random modes (no rigid part, a few mm), each in
    a random pose."""
    rng = np.random.default_rng(6)
    v = t.vertices
    c = v - v.mean(0)
    fields = [np.sin(c[:, [1]] / 25.0) * [0, 0, 4.0], np.cos(c[:, [0]] / 30.0) * [3.0, 0, 0],
              (c[:, [1]] / 60.0) ** 2 * [0, 5.0, 2.0], t.blendshapes[0]]
    fields = [_without_rigid_part(f, v) for f in fields]
    coef = rng.normal(size=(25, 4)) * [1.0, 0.8, 0.6, 0.3]
    shapes = np.array([v + np.tensordot(a, fields, axes=1) for a in coef])
    posed = np.array([s @ random_rotation(rng).T + rng.normal(size=3) * 300 for s in shapes])
    return posed, t.faces


@pytest.fixture(scope="module")
def model(population):
    shapes, faces = population
    return fit_model(shapes, faces, [f"s{i}" for i in range(len(shapes))], variance=1.0)


def test_model_components_orthonormal_and_variances_descending(model, population):
    k = model.n_modes
    c = model.components.reshape(k, -1)
    np.testing.assert_allclose(c @ c.T, np.eye(k), atol=1e-10)
    assert np.all(np.diff(model.variances) <= 0) and np.all(model.variances > 0)
    assert model.mean.shape == (population[0].shape[1], 3) and model.components.shape[1:] == model.mean.shape
    # 4 deformation fields (nearly linear after alignment): 4 modes hold almost all the variance
    assert model.explained_variance()[:4].sum() > 0.999
    # the mean sits in the template's frame (it was turned onto the template)
    from facecorr.template import load_template

    assert np.abs(model.mean - load_template().vertices).mean() < 5.0


def test_sample_project_round_trip(model):
    rng = np.random.default_rng(7)
    alpha = np.zeros(model.n_modes)
    alpha[:4] = [1.5, -0.7, 2.0, 0.3]
    face = model.sample(alpha)
    r, t = random_rotation(rng), rng.normal(size=3) * 100
    posed = face @ r.T + t
    got, recon = model.project(posed)
    np.testing.assert_allclose(got, alpha, atol=1e-6)
    np.testing.assert_allclose(recon, posed, atol=1e-6)  # back in the input's frame
    np.testing.assert_allclose(model.sample(), model.mean)
    np.testing.assert_allclose(model.sample([1.0]), model.mean + model.std[0] * model.components[0])
    # fewer modes: the reconstruction loses what the dropped ones carried
    _, recon2 = model.project(posed, n_modes=1)
    assert np.linalg.norm(recon2 - posed, axis=1).mean() > 0.1


def test_mahalanobis_of_mean_and_of_k_sigma(model):
    assert model.mahalanobis(model.mean) == pytest.approx(0.0, abs=1e-6)
    for j in range(3):
        for k in (0.5, 1.0, 3.0):
            v = model.mean + k * model.std[j] * model.components[j]
            assert model.mahalanobis(v) == pytest.approx(k, abs=1e-6)
    rng = np.random.default_rng(8)
    v = model.mean + 2.0 * model.std[1] * model.components[1]
    assert model.mahalanobis(v @ random_rotation(rng).T + 40.0) == pytest.approx(2.0, abs=1e-6)


def test_similarity_model_ignores_size(population):
    shapes, faces = population
    m = fit_model(shapes, faces, scale=True, modes=4)
    assert m.alignment == "similarity"
    v = m.sample([1.0, -2.0])
    a1, r1 = m.project(v)
    rot = random_rotation(np.random.default_rng(9))
    a2, r2 = m.project(1.7 * v @ rot.T + 5.0)
    np.testing.assert_allclose(a2, a1, atol=1e-8)  # neither pose nor size changes the coefficients
    np.testing.assert_allclose(r2, 1.7 * r1 @ rot.T + 5.0, atol=1e-6)  # the reconstruction follows the input
    # (mean + modes is not closed under scaling: a sample is not exactly at its own best scale
    # onto the mean, so its coefficients come back close, not equal)
    np.testing.assert_allclose(a1, [1.0, -2.0, 0.0, 0.0], atol=0.05)
    rigid = fit_model(shapes, faces, modes=4)
    assert rigid.mahalanobis(1.3 * rigid.mean) > 3.0  # a rigid model sees size
    assert m.mahalanobis(1.3 * m.mean) == pytest.approx(0.0, abs=1e-6)


def test_save_load_round_trip_and_broken_files(model, tmp_path):
    p = tmp_path / "m.npz"
    model.save(p)
    back = ShapeModel.load(p)
    for key in ("mean", "components", "variances", "faces", "scores"):
        np.testing.assert_array_equal(getattr(back, key), getattr(model, key))
    assert back.names == model.names and back.n_scans == model.n_scans == 25
    assert (back.alignment, back.source, back.total_variance) == (model.alignment, model.source, model.total_variance)
    with np.load(p) as z:  # the contract's keys and shapes
        assert z["mean"].shape == (model.n_vertices, 3) and z["components"].shape == (model.n_modes, model.n_vertices, 3)
        assert z["variances"].shape == (model.n_modes,) and int(z["n_scans"]) == 25 and len(z["names"]) == 25
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not an npz")
    with pytest.raises(ShapeModelError, match="not a shape model"):
        ShapeModel.load(bad)
    np.savez(tmp_path / "other.npz", a=np.zeros(3))
    with pytest.raises(ShapeModelError, match="missing"):
        ShapeModel.load(tmp_path / "other.npz")
    with pytest.raises(ShapeModelError, match="no such"):
        ShapeModel.load(tmp_path / "none.npz")
    with pytest.raises(ShapeModelError, match="vertices are"):
        model.project(np.zeros((10, 3)))


def test_fit_model_refuses_too_few_or_identical_shapes(population):
    shapes, faces = population
    with pytest.raises(ShapeModelError, match="at least 2"):
        fit_model(shapes[:1], faces)
    with pytest.raises(ShapeModelError, match="identical"):
        fit_model(np.array([shapes[0], shapes[0] + 3.0]), faces)
    with pytest.raises(ShapeModelError, match="modes"):
        fit_model(shapes, faces, modes=0)


def test_leave_one_out_on_a_low_rank_population(population):
    from facecorr.model.evaluate import group_of, leave_one_out, summarize

    shapes, faces = population
    names = [f"S{i // 5}/S{i // 5}_{i % 5}" for i in range(len(shapes))]
    rows = leave_one_out(shapes, faces, names, by="folder", modes=4, progress=False)
    s = summarize(rows)
    assert s["n_shapes"] == 25 and s["n_groups"] == 5
    # the held-out faces lie in the span of the others' 4 deformations: reconstructed to ~0,
    # while the mean shape alone misses them by millimetres
    assert s["mean_error_mm"] < 0.05 and s["mean_shape_error_mm"] > 1.0
    assert group_of("F0002/F0002_AN04_F3D", "prefix") == "F0002" == group_of("F0002/x", "folder")


# --- reading a results folder ---------------------------------------------------------------------

def _write_result(folder, stem, vertices_mm, faces, units="mm", flags=(), neutral=None):
    """A result as `facecorr batch` writes it: <stem>.ply in the scan's units + <stem>.json."""
    from facecorr.io import UNIT_TO_MM, save_mesh

    folder.mkdir(parents=True, exist_ok=True)
    save_mesh(folder / f"{stem}.ply", (vertices_mm, faces), units=units)
    (folder / f"{stem}.json").write_text(json.dumps({"units": units, "landmarks": {}, "landmarks_registered": {},
                                                    "flags": list(flags), "mhd": 0.5 / UNIT_TO_MM[units]}))
    if neutral is not None:
        save_mesh(folder / f"{stem}_neutral.ply", (neutral, faces), units=units)


def test_read_results_units_flags_and_neutral(tmp_path, population, capsys):
    shapes, faces = population
    root = tmp_path / "res"
    _write_result(root / "A", "a_mm", shapes[0], faces, neutral=shapes[3])
    _write_result(root / "A", "b_cm", shapes[1], faces, units="cm", flags=["low_confidence:nose_tip"],
                  neutral=shapes[4])
    _write_result(root / "B", "c_m", shapes[2], faces, units="m", neutral=shapes[5])
    _write_result(root / "B", "d_bad", shapes[6], faces, flags=["implausible_fit:expression at its bound"],
                  neutral=shapes[7])
    (root / "failures.json").write_text(json.dumps([{"scan": "x.ply", "ok": False, "error": "bad input"}]))
    rs = read_results(root, progress=False)
    assert rs.names == ["A/a_mm", "A/b_cm", "B/c_m"] and rs.n_failed == 1
    assert rs.skipped == [("B/d_bad", ["implausible_fit:expression at its bound"])]
    np.testing.assert_allclose(rs.shapes, shapes[:3], atol=1e-9)  # every one back in mm
    np.testing.assert_array_equal(rs.faces, faces)
    rs = read_results(root, include_flagged=True, progress=False)
    assert rs.names[-1] == "B/d_bad" and not rs.skipped
    rs = read_results(root, neutral=True, progress=False)
    np.testing.assert_allclose(rs.shapes, shapes[3:6], atol=1e-9)
    # the command line names what it left out
    from facecorr.cli import main

    assert main(["model", "build", str(root), "-o", str(tmp_path / "m.npz"), "--neutral"]) == 0
    out = capsys.readouterr().out
    assert "skipped 1 flagged result(s) (implausible_fit 1; --include-flagged keeps them): B/d_bad" in out
    assert "1 scan(s) failed registration" in out and "3 scans" in out and "expression-removed" in out
    assert ShapeModel.load(tmp_path / "m.npz").source == "neutral"


@pytest.mark.parametrize("case,message", [
    ("missing_folder", "not a folder"),
    ("empty", "no registration results"),
    ("wrong_count", "vertices, the template has"),
    ("no_neutral", "_neutral.ply"),
    ("one_result", "at least 2 results"),
    ("all_flagged", "--include-flagged"),
    ("no_mesh", "has no mesh"),
    ("bad_units", "unknown units"),
])
def test_read_results_refuses_with_one_line(tmp_path, population, case, message):
    shapes, faces = population
    root = tmp_path / "res"
    root.mkdir()
    if case == "wrong_count":
        _write_result(root, "a", shapes[0], faces)
        _write_result(root, "b", shapes[1][:100], np.array([[0, 1, 2], [2, 3, 4]]))
    elif case == "no_neutral":
        _write_result(root, "a", shapes[0], faces)
        _write_result(root, "b", shapes[1], faces)
    elif case == "one_result":
        _write_result(root, "a", shapes[0], faces)
    elif case == "all_flagged":
        _write_result(root, "a", shapes[0], faces, flags=["low_coverage:40% of the template has scan under it"])
        _write_result(root, "b", shapes[1], faces)
    elif case == "no_mesh":
        _write_result(root, "a", shapes[0], faces)
        _write_result(root, "b", shapes[1], faces)
        (root / "b.ply").unlink()
    elif case == "bad_units":
        _write_result(root, "a", shapes[0], faces)
        (root / "a.json").write_text(json.dumps({"units": "inch", "landmarks_registered": {}}))
    (root / "notes.json").write_text("[1, 2]")  # other JSON is not a result
    where = tmp_path / "none" if case == "missing_folder" else root
    with pytest.raises(ShapeModelError, match=message) as e:
        read_results(where, neutral=case == "no_neutral", progress=False)
    assert "\n" not in str(e.value)


# --- exports --------------------------------------------------------------------------------------

def test_statismo_file_has_the_published_layout(model, tmp_path):
    import h5py

    from facecorr.model.export import write_statismo

    p = tmp_path / "m.h5"
    write_statismo(model, p)
    n, k, m = model.n_vertices, model.n_modes, len(model.faces)
    with h5py.File(p, "r") as f:
        assert int(f["/version/majorVersion"][()]) == 0 and int(f["/version/minorVersion"][()]) == 9
        assert f["/version/majorVersion"].shape == () and f["/version/majorVersion"].dtype == np.int32
        rep = f["/representer"]
        assert rep.attrs["name"] == b"itkStandardMeshRepresenter" and rep.attrs["datasetType"] == b"POLYGON_MESH"
        assert "version" in rep.attrs and "pointData" in rep
        pts, cells = f["/representer/points"], f["/representer/cells"]
        assert pts.shape == (3, n) and pts.dtype == np.float32
        assert cells.shape == (3, m) and cells.dtype == np.uint32
        np.testing.assert_array_equal(cells[()].T, model.faces)
        mean, basis = f["/model/mean"][()], f["/model/pcaBasis"][()]
        var = f["/model/pcaVariance"][()]
        assert mean.shape == (3 * n,) and basis.shape == (3 * n, k) and var.shape == (k,)
        assert mean.dtype == basis.dtype == var.dtype == np.float32
        assert f["/model/noiseVariance"].shape == () and float(f["/model/noiseVariance"][()]) == 0.0
        np.testing.assert_allclose(pts[()].T, model.mean, atol=1e-3)
        # statismo 0.9: orthonormal columns; a sample is mean + basis @ (sqrt(var) * alpha)
        np.testing.assert_allclose(basis.T.astype(float) @ basis, np.eye(k), atol=1e-4)
        alpha = np.array([1.0, -2.0, 0.5] + [0.0] * (k - 3))
        sample = mean + basis @ (np.sqrt(var) * alpha)
        np.testing.assert_allclose(sample.reshape(n, 3), model.sample(alpha), atol=2e-3)
        np.testing.assert_allclose(var, model.variances, rtol=1e-6)
        info = f["/modelinfo"]
        assert info["scores"].shape == (k, model.n_scans)
        np.testing.assert_allclose(info["scores"][()].T, model.scores, atol=1e-4)
        assert isinstance(info["build-time"][()], bytes)
        b = info["modelBuilder-0"]
        assert isinstance(b["builderName"][()], bytes) and isinstance(b["buildTime"][()], bytes)
        assert [b["dataInfo"][f"URI_{i}"][()].decode() for i in range(model.n_scans)] == model.names
        assert b["parameters"]["alignment"][()] == b"rigid"


def test_statismo_without_h5py_is_one_line_and_writes_nothing(model, tmp_path, monkeypatch, capsys):
    import sys

    import h5py

    model.save(tmp_path / "m.npz")
    monkeypatch.setitem(sys.modules, "h5py", None)  # `import h5py` raises ImportError
    rc, cap = _cli(capsys, "model", "export", tmp_path / "m.npz", "--statismo", tmp_path / "m.h5",
                   "--ply-modes", tmp_path / "plys")
    assert rc == 2 and "facecorr[hdf5]" in _error_line(cap.err)
    assert not (tmp_path / "m.h5").exists() and not (tmp_path / "plys").exists()
    monkeypatch.setitem(sys.modules, "h5py", h5py)
    # an unwritable statismo path: refused before the PLY meshes are written
    (tmp_path / "dir.h5").mkdir()
    rc, cap = _cli(capsys, "model", "export", tmp_path / "m.npz", "--statismo", tmp_path / "dir.h5",
                   "--ply-modes", tmp_path / "plys")
    assert rc == 2 and "is a folder" in _error_line(cap.err) and not (tmp_path / "plys").exists()


def test_help_lists_the_model_commands(capsys):
    import re

    with pytest.raises(SystemExit):
        _cli(capsys, "--help")
    assert "model" in set(re.findall(r"^    (\S+)", capsys.readouterr().out, flags=re.M))
    with pytest.raises(SystemExit):
        _cli(capsys, "model", "--help")
    assert {"build", "show", "export", "eval"} <= set(re.findall(r"^    (\S+)", capsys.readouterr().out, flags=re.M))


def test_ply_modes(model, tmp_path):
    import trimesh

    from facecorr.model.export import write_mode_plys

    paths = write_mode_plys(model, tmp_path / "modes", n_modes=2)
    assert [p.name for p in paths] == ["mean.ply", "mode01_minus3sd.ply", "mode01_plus3sd.ply",
                                       "mode02_minus3sd.ply", "mode02_plus3sd.ply"]
    read = [np.asarray(trimesh.load(p, process=False).vertices) for p in paths]
    np.testing.assert_allclose(read[0], model.mean, atol=1e-9)
    np.testing.assert_allclose(read[4] - read[0], 3 * model.std[1] * model.components[1], atol=1e-9)
    np.testing.assert_allclose(read[1] - read[0], -3 * model.std[0] * model.components[0], atol=1e-9)


# --- the command line on a small real batch --------------------------------------------------------

@pytest.fixture(scope="module")
def batch(tmp_path_factory):
    """3 synthetic scans (one saved in cm) registered by `facecorr batch --neutral`."""
    from facecorr.cli import main
    from facecorr.io import load_mesh, save_mesh
    from facecorr.synth import generate_scan

    scans = tmp_path_factory.mktemp("scans")
    generate_scan(scans, subject=1, expression="NE", level=0, seed=3)
    generate_scan(scans, subject=1, expression="SU", level=4, seed=3)
    rec = generate_scan(tmp_path_factory.mktemp("cm"), subject=2, expression="NE", level=0, seed=3)
    (scans / "M0001").mkdir()
    save_mesh(scans / "M0001" / "M0001_NE00_F3D.ply", load_mesh(rec["scan"]), units="cm")
    out = tmp_path_factory.mktemp("results")
    assert main(["batch", str(scans), str(out), "--workers", "1", "--neutral"]) == 0
    return out


def _cli(capsys, *args):
    from facecorr.cli import main

    rc = main([str(a) for a in args])
    return rc, capsys.readouterr()


def test_cli_build_show_export_eval(batch, tmp_path, capsys):
    import h5py

    assert json.loads((batch / "M0001" / "M0001_NE00_F3D.json").read_text())["units"] == "cm"
    npz = tmp_path / "model.npz"
    rc, cap = _cli(capsys, "model", "build", batch, "-o", npz, "--modes", "2")
    assert rc == 0, cap.err
    assert "3 scans" in cap.out and "2 modes" in cap.out
    m = ShapeModel.load(npz)
    assert m.n_scans == 3 and m.n_modes == 2 and sorted(m.names) == m.names and len(m.names) == 3
    # the cm result was converted: every training shape is face-sized in mm, close to the mean
    from facecorr.model.procrustes import centroid_size
    from facecorr.template import load_template

    t = load_template()
    assert 0.8 < centroid_size(m.mean) / centroid_size(t.vertices) < 1.25
    rs = read_results(batch, progress=False)
    for shape in rs.shapes:
        _, recon = m.project(shape)
        assert np.linalg.norm(recon - shape, axis=1).mean() < 0.01  # 2 modes span 3 shapes exactly
    png = tmp_path / "modes.png"
    rc, cap = _cli(capsys, "model", "show", npz, "-o", png)
    assert rc == 0 and png.stat().st_size > 20000, cap.err
    h5, plys = tmp_path / "m.h5", tmp_path / "plys"
    rc, cap = _cli(capsys, "model", "export", npz, "--statismo", h5, "--ply-modes", plys)
    assert rc == 0, cap.err
    assert len(list(plys.glob("*.ply"))) == 5
    with h5py.File(h5) as f:
        assert f["/model/pcaBasis"].shape == (3 * m.n_vertices, 2)
    rc, cap = _cli(capsys, "model", "eval", batch, "--json", tmp_path / "loo.json")
    assert rc == 0, cap.err
    loo = json.loads((tmp_path / "loo.json").read_text())
    assert loo["summary"]["n_shapes"] == 3 and len(loo["shapes"]) == 3
    assert 0 < loo["summary"]["mean_error_mm"] < loo["summary"]["mean_shape_error_mm"] * 1.5


def test_cli_build_neutral_from_a_batch_neutral(batch, tmp_path, capsys):
    """`model build --neutral` on `batch --neutral` output: the model is made of the _neutral.ply
    files (in mm, the cm result converted), and the surprise scan's neutral shape is closer to its
    subject's neutral scan than its registration is."""
    import trimesh

    from facecorr.geometry.transforms import kabsch

    npz = tmp_path / "identity.npz"
    rc, cap = _cli(capsys, "model", "build", batch, "-o", npz, "--neutral", "--modes", "2")
    assert rc == 0 and "expression-removed shapes" in cap.out, cap
    m = ShapeModel.load(npz)
    assert m.source == "neutral" and m.n_scans == 3
    raw, neutral = read_results(batch, progress=False), read_results(batch, neutral=True, progress=False)
    assert raw.names == neutral.names == m.names
    cm = m.names.index("M0001/M0001_NE00_F3D")
    v = np.asarray(trimesh.load(batch / "M0001" / "M0001_NE00_F3D_neutral.ply", process=False).vertices)
    np.testing.assert_array_equal(neutral.shapes[cm], v * 10.0)
    for shape in neutral.shapes:  # the model spans its 3 training shapes
        _, recon = m.project(shape)
        assert np.linalg.norm(recon - shape, axis=1).mean() < 0.01

    def apart(a, b):
        r, t = kabsch(a, b)
        return float(np.linalg.norm(a @ r.T + t - b, axis=1).mean())

    ne, su = m.names.index("F0001/F0001_NE00_F3D"), m.names.index("F0001/F0001_SU04_F3D")
    before = apart(raw.shapes[su], raw.shapes[ne])
    after = apart(neutral.shapes[su], raw.shapes[ne])
    assert after < 0.6 * before, (before, after)


def _error_line(err):
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("facecorr: error:"), err
    return lines[0]


def test_cli_bad_inputs_one_line_exit_2_no_output(batch, tmp_path, capsys):
    import shutil

    out = tmp_path / "m.npz"
    empty = tmp_path / "empty"
    empty.mkdir()
    rc, cap = _cli(capsys, "model", "build", empty, "-o", out)
    assert rc == 2 and "no registration results" in _error_line(cap.err)
    lost = tmp_path / "lost"
    shutil.copytree(batch, lost)
    next(lost.rglob("*SU04_F3D_neutral.ply")).unlink()
    rc, cap = _cli(capsys, "model", "build", lost, "-o", out, "--neutral")
    line = _error_line(cap.err)
    assert rc == 2 and "SU04_F3D_neutral.ply" in line and "1 of 3" in line and "--neutral" in line, line
    # a result whose mesh is not the template
    odd = tmp_path / "odd"
    shutil.copytree(batch, odd)
    from facecorr.io import save_mesh

    save_mesh(odd / "F0001" / "F0001_NE00_F3D.ply", (np.random.default_rng(0).normal(size=(30, 3)),
                                                      np.array([[0, 1, 2]])))
    rc, cap = _cli(capsys, "model", "build", odd, "-o", out)
    assert rc == 2 and "30 vertices" in _error_line(cap.err)
    rc, cap = _cli(capsys, "model", "build", batch, "-o", tmp_path / "m.txt")
    assert rc == 2 and ".npz" in _error_line(cap.err)
    assert not out.exists() and not list(tmp_path.glob(".m.*"))
    # a usage mistake is one line too
    with pytest.raises(SystemExit) as e:
        _cli(capsys, "model", "build", batch, "-o", out, "--variance", "1.5")
    assert e.value.code == 2 and "(0, 1]" in _error_line(capsys.readouterr().err)
    not_model = tmp_path / "x.npz"
    np.savez(not_model, a=np.zeros(2))
    rc, cap = _cli(capsys, "model", "show", not_model, "-o", tmp_path / "s.png")
    assert rc == 2 and "not a facecorr shape model" in _error_line(cap.err)
    rc, cap = _cli(capsys, "model", "export", not_model)
    assert rc == 2 and "--statismo" in _error_line(cap.err)
    assert not (tmp_path / "s.png").exists() and not out.exists()
