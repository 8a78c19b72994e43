"""The expression-removed shape (issue 15 item 3): facecorr.registration.neutral."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from facecorr.geometry.transforms import kabsch
from facecorr.registration.neutral import NeutralOptions, neutral_shape, packaged_neutral_basis
from facecorr.template import load_template


def _face(template, basis, alpha, beta):
    return (np.asarray(template.vertices) + basis.mean + np.tensordot(beta, basis.modes, 1)
            + np.tensordot(alpha, np.asarray(template.blendshapes), 1))


def _rms_after_kabsch(a, b):
    r, t = kabsch(a, b)
    return float(np.sqrt(np.mean(np.sum((a @ r.T + t - b) ** 2, axis=1))))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_model_face_gets_its_expression_removed_in_any_pose(seed):
    """A face of the model itself (identity β, expression α, a random similarity pose): the
    neutral shape is that identity with α = 0, in the input's pose, and α comes back."""
    tpl, basis = load_template(), packaged_neutral_basis()
    rng = np.random.default_rng(seed)
    alpha = np.zeros(tpl.n_blendshapes)
    names = list(tpl.blendshape_names)
    for n, a in (("jawOpen", 0.5), ("mouthSmile_L", 0.6), ("mouthSmile_R", 0.6), ("browInnerUp", 0.4)):
        alpha[names.index(n)] = a
    beta = rng.normal(0, 1, basis.n_modes)
    r = Rotation.random(random_state=seed).as_matrix()
    s, t = rng.uniform(0.9, 1.1), rng.normal(0, 100, 3)
    pose = lambda x: s * x @ r.T + t  # noqa: E731
    expressive, neutral_true = pose(_face(tpl, basis, alpha, beta)), pose(_face(tpl, basis, 0 * alpha, beta))
    neutral, removed = neutral_shape(expressive, tpl, basis, NeutralOptions(identity_prior=1e-6))
    np.testing.assert_allclose(removed, alpha, atol=1e-3)
    assert np.abs(neutral - neutral_true).max() < 0.05
    # the raw face is millimetres from its neutral shape: the test measures something
    assert _rms_after_kabsch(expressive, neutral_true) > 2.0


def test_residual_detail_stays_and_a_neutral_face_is_left_alone():
    tpl, basis = load_template(), packaged_neutral_basis()
    rng = np.random.default_rng(5)
    face = _face(tpl, basis, np.zeros(tpl.n_blendshapes), rng.normal(0, 1, basis.n_modes))
    detail = rng.normal(0, 0.3, face.shape)  # what no mode explains
    neutral, removed = neutral_shape(face + detail, tpl, basis, NeutralOptions(identity_prior=1e-6))
    assert removed.max() < 0.02
    moved = np.linalg.norm(neutral - (face + detail), axis=1)
    assert moved.max() < 0.2, moved.max()  # the 0.3 mm noise projects a little onto the blendshapes
    # the default identity prior (μ = 1e3 mm², chosen so the modes cannot take up expression)
    # shrinks a 1 σ identity: the blendshapes then take up a little of it
    neutral, removed = neutral_shape(face + detail, tpl, basis, NeutralOptions(residual_modes=0))
    moved = np.linalg.norm(neutral - (face + detail), axis=1)
    assert removed.max() < 0.2 and np.median(moved) < 0.25 and moved.max() < 2.0, (removed.max(), moved.max())
    # the residual expression modes (ν = 300 mm², weaker than μ) take up more of it: the price of
    # removing what the blendshapes miss (on 10 held-out training subjects' neutral registrations,
    # 0.72 -> 0.85 mm; BENCHMARKS.md)
    neutral, removed = neutral_shape(face + detail, tpl, basis)
    moved = np.linalg.norm(neutral - (face + detail), axis=1)
    assert removed.max() < 0.2 and np.median(moved) < 0.8 and moved.max() < 2.5, (np.median(moved), moved.max())


def test_what_the_blendshapes_miss_is_removed_by_the_residual_modes():
    """A model face whose expression is blendshapes plus residual expression modes (a disgust's
    nose wrinkle, say): the residual modes take it away; the blendshapes alone leave most of it."""
    from facecorr.registration.neutral import packaged_residual_basis

    tpl, basis, res = load_template(), packaged_neutral_basis(), packaged_residual_basis()
    assert res.n_modes == 10 and np.allclose(res.mean, 0)
    rng = np.random.default_rng(3)
    alpha = np.zeros(tpl.n_blendshapes)
    alpha[list(tpl.blendshape_names).index("jawOpen")] = 0.3
    beta = rng.normal(0, 0.3, basis.n_modes)
    gamma = np.array([2.0, -1.5, 1.0] + [0.0] * (res.n_modes - 3))
    neutral_true = _face(tpl, basis, 0 * alpha, beta)
    expressive = _face(tpl, basis, alpha, beta) + np.tensordot(gamma, res.modes, 1)
    opts = NeutralOptions(identity_prior=1e-6, residual_prior=1e-6)
    neutral, removed = neutral_shape(expressive, tpl, basis, opts)
    assert _rms_after_kabsch(neutral, neutral_true) < 0.05
    without, _ = neutral_shape(expressive, tpl, basis, NeutralOptions(identity_prior=1e-6, residual_modes=0))
    before = _rms_after_kabsch(expressive, neutral_true)
    assert before > 2.0 and _rms_after_kabsch(without, neutral_true) > 0.3 * before


def test_wrong_shape_is_refused():
    with pytest.raises(ValueError, match="template"):
        neutral_shape(np.zeros((10, 3)), load_template())


def test_register_neutral_writes_the_shape_with_the_mesh(tmp_path):
    """`facecorr register SCAN -o OUT --neutral N`: N has the template's vertex order, differs
    from OUT by the removed expression only, and a bad N path is refused before the work."""
    import json
    import sys
    from pathlib import Path

    import trimesh

    sys.path.insert(0, str(Path(__file__).parent))
    from synthetic_face import make_scan

    from facecorr.cli import main
    from facecorr.io import save_mesh

    mesh, _, _, _ = make_scan(0)
    scan = tmp_path / "s.ply"
    save_mesh(scan, mesh)
    assert main(["register", str(scan), "-o", str(tmp_path / "x.ply"), "--neutral", str(tmp_path / "x.abc")]) == 2
    assert not (tmp_path / "x.ply").exists()
    rc = main(["register", str(scan), "-o", str(tmp_path / "r.ply"), "--json", str(tmp_path / "r.json"),
               "--neutral", str(tmp_path / "n.ply")])
    assert rc == 0
    reg = np.asarray(trimesh.load(tmp_path / "r.ply", process=False).vertices)
    neu = np.asarray(trimesh.load(tmp_path / "n.ply", process=False).vertices)
    assert reg.shape == neu.shape == (load_template().n_vertices, 3)
    assert json.loads((tmp_path / "r.json").read_text())["neutral_expression_removed"] is not None
    assert np.isfinite(neu).all() and np.median(np.linalg.norm(neu - reg, axis=1)) < 5.0
