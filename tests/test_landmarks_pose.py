"""Rigid pose by trimmed ICP from a rotation sweep about the nose-tip normal."""

import numpy as np
import pytest
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from facecorr.geometry.transforms import axis_angle, rotation_between
from facecorr.landmarks.pose import fit_pose, normal_sweep_starts, trimmed_icp


def _grid_normals(p, n):
    """Unit vertex normals of an n x n height-field grid (from its triangulation)."""
    from facecorr.geometry.mesh import Mesh

    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel(), idx[1:, :-1].ravel()
    faces = np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])])
    return Mesh(p, faces).vertex_normals


def _bumpy_face(n=60):
    """A height field with a nose-like bump and asymmetric features (no rotational symmetry)."""
    x, y = np.meshgrid(np.linspace(-60, 60, n), np.linspace(-70, 70, n))
    z = 25 * np.exp(-(x**2 + y**2) / 300) + 12 * np.exp(-((x + 25) ** 2 + (y - 30) ** 2) / 80) \
        + 6 * np.exp(-((x - 22) ** 2 + (y - 30) ** 2) / 150) + 5 * np.exp(-(x**2 + (y + 40) ** 2) / 120) - 0.004 * (x**2 + 0.5 * y**2)
    return np.column_stack([x.ravel(), y.ravel(), z.ravel()])


@pytest.mark.parametrize("seed", range(4))
def test_rotation_helpers(seed):
    rng = np.random.default_rng(seed)
    a, b = rng.normal(size=3), rng.normal(size=3)
    r = rotation_between(a, b)
    np.testing.assert_allclose(r @ (a / np.linalg.norm(a)), b / np.linalg.norm(b), atol=1e-12)
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(rotation_between(a, -a) @ a, -a, atol=1e-12)
    k = axis_angle(a, 0.7)
    np.testing.assert_allclose(k, Rotation.from_rotvec(0.7 * a / np.linalg.norm(a)).as_matrix(), atol=1e-12)


@pytest.mark.parametrize("seed", range(5))
def test_sweep_and_icp_recover_any_rotation(seed):
    tpl = _bumpy_face()
    rng = np.random.default_rng(seed)
    rot = Rotation.random(random_state=seed).as_matrix()
    shift = rng.normal(size=3) * 100
    clean = _bumpy_face(90)
    normals = _grid_normals(clean, 90) @ rot.T
    scan = clean @ rot.T + shift + rng.normal(size=(8100, 3)) * 0.2
    tree = cKDTree(scan)
    tip = np.array([0.0, 0.0, 25.0])
    # normals: the template's is +z; the scan's, as a detector would measure it, with 5 deg error
    n_scan = axis_angle(np.cross(rot[:, 2], [1, 0, 0]), np.radians(5)) @ rot[:, 2]
    starts = normal_sweep_starts(tip, np.array([0, 0, 1.0]), tip @ rot.T + shift, n_scan, 12)
    pts = tpl[::7]
    r, t, rms, _ = fit_pose(pts, tree, starts, normals=normals)
    assert rms < 1.0
    np.testing.assert_allclose(r, rot, atol=0.02)
    np.testing.assert_allclose(t, shift, atol=2.0)
    # point-to-point from the same starts converges far more slowly (why we use point-to-plane)
    r2, _, _, _ = fit_pose(pts, tree, starts)
    assert np.abs(r2 - rot).max() > np.abs(r - rot).max()


def test_trimmed_icp_ignores_missing_part():
    tpl = _bumpy_face()
    scan = tpl[tpl[:, 0] < 30]  # a third of the face missing
    tree = cKDTree(scan)
    normals = _grid_normals(tpl, 60)[tpl[:, 0] < 30]
    r0 = axis_angle(np.array([0, 0, 1.0]), np.radians(8))
    r, t, rms, d = trimmed_icp(tpl[::5], tree, r0, np.array([3.0, -2, 1]), iters=60, keep=0.6, normals=normals)
    np.testing.assert_allclose(r, np.eye(3), atol=5e-3)
    assert rms < 0.5


def _posed_scene(seed: int, n_angles: int):
    """The bumpy face turned by a random rotation and moved: (rotation, cKDTree of the scan, scan
    normals, ``n_angles`` sweep starts about the nose tip, template points (every 7th))."""
    rot = Rotation.random(random_state=seed).as_matrix()
    clean = _bumpy_face(90)
    normals = _grid_normals(clean, 90) @ rot.T
    scan = clean @ rot.T + np.array([5.0, -20.0, 40.0])
    tip = np.array([0.0, 0.0, 25.0])
    starts = normal_sweep_starts(tip, np.array([0, 0, 1.0]), tip @ rot.T + [5.0, -20.0, 40.0], rot[:, 2], n_angles)
    return rot, cKDTree(scan), normals, starts, _bumpy_face()[::7]


@pytest.mark.parametrize("use_normals", [True, False])
def test_batch_icp_equals_looped_trimmed_icp(use_normals):
    from facecorr.landmarks.pose import batch_icp, fit_poses

    rot, tree, normals, starts, pts = _posed_scene(3, 8)
    nrm = normals if use_normals else None
    rms, rs, ts = batch_icp(pts, tree, starts, iters=5, normals=nrm)
    for k, (r0, t0) in enumerate(starts):
        r, t, rms_k, _ = trimmed_icp(pts, tree, r0, t0, iters=5, tol=-np.inf, normals=nrm)
        np.testing.assert_allclose(rs[k], r, atol=1e-6)
        np.testing.assert_allclose(ts[k], t, atol=1e-5)
        assert rms[k] == pytest.approx(rms_k, rel=1e-6)
    # and the best refined pose is the true one
    (r, t, rms_best), *_ = fit_poses(pts, tree, starts, n_best=2, normals=normals)
    np.testing.assert_allclose(r, rot, atol=0.02)


def test_hinted_queries_give_the_same_poses_as_plain_queries():
    """pose.py searches each point within its last match (KDTree.query_hinted): the poses are
    exactly those of plain nearest-point queries (the same tree without hints)."""
    from facecorr.geometry.spatial import KDTree
    from facecorr.landmarks.pose import batch_icp, fit_poses

    rot = Rotation.random(random_state=5).as_matrix()
    clean = _bumpy_face(90)
    normals = _grid_normals(clean, 90) @ rot.T
    scan = clean @ rot.T + np.array([5.0, -20.0, 40.0])
    tip = np.array([0.0, 0.0, 25.0])
    starts = normal_sweep_starts(tip, np.array([0, 0, 1.0]), tip @ rot.T + [5.0, -20.0, 40.0], rot[:, 2], 12)
    pts = _bumpy_face()[::5]
    tree = KDTree(scan)

    class Plain:  # the same tree, taking no hints
        data, query = tree.data, tree.query

    a = batch_icp(pts, tree, starts, iters=6, normals=normals)
    b = batch_icp(pts, Plain(), starts, iters=6, normals=normals)
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x, y)
    pa = fit_poses(pts, tree, starts, n_best=2, normals=normals)
    pb = fit_poses(pts, Plain(), starts, n_best=2, normals=normals)
    for x, y in zip(pa, pb):
        for u, v in zip(x, y):
            np.testing.assert_array_equal(u, v)


def test_batch_icp_scales_move_each_start_at_its_own_size():
    """``scales``: start k moves the points as s_k R x + t; the same as the rigid batch of the
    points scaled by s_k (each size run on its own), to rounding."""
    from facecorr.landmarks.pose import batch_icp

    _, tree, normals, starts, pts = _posed_scene(7, 4)
    sizes = np.array([0.9, 1.0, 1.1, 1.2])
    rms, rs, ts = batch_icp(pts, tree, starts, iters=4, normals=normals, scales=sizes)
    for k, s in enumerate(sizes):
        rms1, rs1, ts1 = batch_icp(s * pts, tree, [starts[k]], iters=4, normals=normals)
        np.testing.assert_allclose(rs[k], rs1[0], atol=1e-9)
        np.testing.assert_allclose(ts[k], ts1[0], atol=1e-7)
        assert rms[k] == pytest.approx(rms1[0], rel=1e-9)


def test_coarse_scan_ranks_the_starts_and_the_scan_refines_them():
    """``fit_poses(coarse_scan=...)``: the coarse stage on a subsampled scan (its own tree and
    normals), the refinement on the whole scan: the same true pose as without it, and given the
    whole scan as the coarse one, exactly the default result."""
    from facecorr.geometry.spatial import KDTree, voxel_subsample
    from facecorr.landmarks.pose import fit_poses

    rot, ctree, normals, starts, pts = _posed_scene(11, 12)
    tree = KDTree(ctree.data)
    sub = voxel_subsample(tree.data, np.arange(len(tree.data)), 4.0)
    assert len(sub) < 0.5 * len(tree.data)
    (r, t, rms), *_ = fit_poses(pts, tree, starts, n_best=2, normals=normals, coarse_scan=(KDTree(tree.data[sub]),
                                                                                          normals[sub]))
    np.testing.assert_allclose(r, rot, atol=0.02)
    default = fit_poses(pts, tree, starts, n_best=2, normals=normals)
    assert rms == pytest.approx(default[0][2], abs=1e-3)
    same = fit_poses(pts, tree, starts, n_best=2, normals=normals, coarse_scan=(tree, normals))
    for x, y in zip(same, default):
        for u, v in zip(x, y):
            np.testing.assert_array_equal(u, v)
    # no refinement (fine_iters=0): the coarse poses with their whole-scan residual
    (r0, _, rms0), *_ = fit_poses(pts, tree, starts, n_best=2, normals=normals, fine_iters=0)
    assert rms0 >= rms - 1e-9


def test_pose_points_keep_the_upper_face_near_the_nose_tip():
    """``pose_points``: radius 0 is every ICP point; a radius keeps exactly those within it of
    Pa's nose tip; a radius holding fewer than 10 points falls back to all of them."""
    from facecorr.landmarks.model import load_model
    from facecorr.landmarks.start import pose_points
    from facecorr.names import NOSE_TIP

    model = load_model(None)
    allp = model.icp_points
    assert pose_points(model, 0.0) is allp
    d = np.linalg.norm(allp - model.graph_points[NOSE_TIP], axis=1)
    near = pose_points(model, 55.0)
    assert len(near) == int((d < 55.0).sum()) and 10 <= len(near) < len(allp)
    assert np.linalg.norm(near - model.graph_points[NOSE_TIP], axis=1).max() < 55.0
    assert pose_points(model, 0.5) is allp


def test_wider_search_takes_its_own_pose_points_radius():
    """By default the first search fits the points near the nose and the wider one all of them
    (another reading of an unusual face); ``retry_pose_points_radius=None`` keeps the first's."""
    from facecorr.landmarks.predict import PredictOptions

    assert PredictOptions().pose_points_radius > 0 and PredictOptions().wider().pose_points_radius == 0.0
    assert PredictOptions(pose_points_radius=40.0, retry_pose_points_radius=None).wider().pose_points_radius == 40.0


def _scene_mesh(seed: int):
    """The bumpy face turned by a random rotation and moved, as a Mesh (for ``Mesh.surface``)."""
    from facecorr.geometry.mesh import Mesh

    n = 90
    rot = Rotation.random(random_state=seed).as_matrix()
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel(), idx[1:, :-1].ravel()
    faces = np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])])
    return rot, Mesh(_bumpy_face(n) @ rot.T + np.array([5.0, -20.0, 40.0]), faces)


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("keep", [0.8, 1.0])
def test_surface_icp_agrees_with_the_numpy_trimmed_icp(seed, keep):
    """The Rust ICP (rust/src/icp.rs) against its numpy reference, from sweep starts (near and far
    from the answer), on the same scan points and normals: the same poses to 1e-6 (rotation) /
    1e-5 mm, the same RMS and distances. Tolerances: the two differ by rounding only (Cholesky vs
    lstsq for the 6x6 step, selection vs sort of the trimmed set), which the few starts whose
    trimmed set changes near a tie could amplify, so most (not all) starts must agree exactly
    and every start's RMS within 1 %."""
    from facecorr.landmarks.pose import surface_icp

    rot, mesh = _scene_mesh(seed)
    tip = np.array([0.0, 0.0, 25.0])
    starts = normal_sweep_starts(tip, np.array([0, 0, 1.0]), tip @ rot.T + [5.0, -20.0, 40.0], rot[:, 2], 6)
    pts = _bumpy_face()[::7]
    fast = surface_icp(pts, mesh.surface, starts, iters=30, keep=keep)
    close = 0
    for (r0, t0), (r, t, rms, d) in zip(starts, fast):
        rr, tr, rmsr, dr = trimmed_icp(pts, mesh.kdtree, r0, t0, iters=30, keep=keep, normals=mesh.vertex_normals)
        assert rms == pytest.approx(rmsr, rel=1e-2, abs=1e-6)
        if np.abs(r - rr).max() < 1e-6 and np.abs(t - tr).max() < 1e-5:
            close += 1
            np.testing.assert_allclose(d, dr, atol=1e-5)
            assert rms == pytest.approx(rmsr, rel=1e-8, abs=1e-9)
    assert close >= len(starts) - 1, close
    # the best start finds the true rotation
    best = min(fast, key=lambda f: f[2])
    np.testing.assert_allclose(best[0], rot, atol=0.02)


def test_surface_icp_edge_cases():
    from facecorr import _core
    from facecorr.landmarks.pose import surface_icp

    rot, mesh = _scene_mesh(0)
    pts = _bumpy_face()[::11]
    assert surface_icp(pts, mesh.surface, []) == []
    # 0 iterations: the start's own residual, as the numpy ICP reports it
    (r, t, rms, d), = surface_icp(pts, mesh.surface, [(rot, np.array([5.0, -20.0, 40.0]))], iters=0)
    rr, tr, rmsr, dr = trimmed_icp(pts, mesh.kdtree, rot, np.array([5.0, -20.0, 40.0]), iters=0,
                                   normals=mesh.vertex_normals)
    np.testing.assert_array_equal(r, rr)
    assert rms == pytest.approx(rmsr, rel=1e-12)
    np.testing.assert_allclose(d, dr, rtol=1e-12)
    # fewer than 6 points: all are kept, as in numpy
    (_, _, rms3, d3), = surface_icp(pts[:3], mesh.surface, [(rot, np.array([5.0, -20.0, 40.0]))], iters=0)
    assert len(d3) == 3 and rms3 == pytest.approx(np.sqrt(np.mean(d3 ** 2)), rel=1e-12)
    with pytest.raises(ValueError, match="rotations must have shape"):
        _core.trimmed_icp(mesh.surface, pts, np.zeros((2, 3, 3)), np.zeros((1, 3)), 5, 0.8, 1e-5)
    with pytest.raises(ValueError, match="keep"):
        surface_icp(pts, mesh.surface, [(rot, np.zeros(3))], keep=0.0)
    with pytest.raises(ValueError, match="NaN"):
        surface_icp(np.full((4, 3), np.nan), mesh.surface, [(rot, np.zeros(3))])


def test_surface_batch_icp_agrees_with_batch_icp():
    """The coarse stage in Rust (``_surface_batch_icp``, fixed iterations, starts at their own
    sizes) against the numpy ``batch_icp`` on the same scan: the same ranking of the starts and
    poses to 1e-5 (rounding only; see the test above)."""
    from facecorr.landmarks.pose import _surface_batch_icp, batch_icp

    rot, mesh = _scene_mesh(2)
    tip = np.array([0.0, 0.0, 25.0])
    starts = normal_sweep_starts(tip, np.array([0, 0, 1.0]), tip @ rot.T + [5.0, -20.0, 40.0], rot[:, 2], 8)
    starts = starts + starts
    scales = np.array([1.0] * 8 + [1.1] * 8)
    pts = _bumpy_face()[::7]
    a = batch_icp(pts, mesh.kdtree, starts, iters=8, normals=mesh.vertex_normals, scales=scales)
    b = _surface_batch_icp(pts, mesh.surface, starts, 8, 0.8, scales)
    np.testing.assert_allclose(b[0], a[0], rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(b[1], a[1], atol=1e-6)
    np.testing.assert_allclose(b[2], a[2], atol=1e-5)
    assert np.argmin(a[0]) == np.argmin(b[0])


def test_pose_scores_in_two_rounds_continue_only_the_contenders():
    """``start._pose_scores`` with ``first_iters``: every pose is scored after that many
    iterations, and the poses within ``margin`` of the best (after the caller's ``offsets``) go
    on to ``iters``, resumed. Its reference: the one-round scores for those that go on (bitwise:
    a resumed ICP is one run), the first round's own scores for the others; a margin of 0
    continues the best pose alone, offsets change which; ``finish()`` gives the one-round scores
    of every pose."""
    from facecorr.landmarks.pose import surface_icp
    from facecorr.landmarks.start import _pose_scores

    rot, mesh = _scene_mesh(1)
    tip = np.array([0.0, 0.0, 25.0])
    starts = normal_sweep_starts(tip, np.array([0, 0, 1.0]), tip @ rot.T + [5.0, -20.0, 40.0], rot[:, 2], 8)
    pts = _bumpy_face()[::9]
    poses = [(r, t, s) for (r, t), s in zip(starts, [1.0, 0.9] * 4)]

    def reference(n_iter):
        return [surface_icp(s * pts, mesh.surface, [(r, t)], iters=n_iter)[0][2] for r, t, s in poses]

    full, first = np.array(reference(10)), np.array(reference(3))
    assert first.max() - first.min() > 1.0  # the sweep has contenders and hopeless poses
    one, finish = _pose_scores(pts, mesh, poses, "trimmed", 10)
    np.testing.assert_array_equal(one, full)
    np.testing.assert_array_equal(finish(), full)
    np.testing.assert_array_equal(_pose_scores(pts, mesh, poses, "trimmed", 10, first_iters=3)[0], full)
    np.testing.assert_array_equal(_pose_scores(pts, mesh, poses, "truncated", 10, first_iters=3)[0],
                                  _pose_scores(pts, mesh, poses, "truncated", 10)[0])
    for margin, offsets in ((0.5, None), (0.0, None), (0.0, -10.0 * (np.arange(8) == 5))):
        ranked = first + (0 if offsets is None else offsets)
        go_on = ranked <= ranked.min() + margin
        got, finish = _pose_scores(pts, mesh, poses, "trimmed", 10, offsets=offsets, first_iters=3, margin=margin)
        np.testing.assert_array_equal(np.where(go_on, full, first), got)
        assert go_on.sum() < len(poses)
        np.testing.assert_array_equal(finish(), full)
        np.testing.assert_array_equal(finish(), full)  # kept, not recomputed into something else
    assert go_on[5] and go_on.sum() == 1  # the offset made pose 5 the best of the first round


def test_lazy_poses_compute_once_and_move():
    """``start.LazyPoses``: computed on first read only, once for every moved copy, and a moved
    copy's translations are the originals plus the offsets."""
    from facecorr.landmarks.start import LazyPoses

    calls = []

    def compute():
        calls.append(1)
        return [(np.eye(3), np.array([1.0, 2.0, 3.0]), 0.5, 1.0), (np.eye(3), np.zeros(3), 0.7, 0.8)]

    lazy = LazyPoses(compute)
    moved = lazy.moved([10.0, 0.0, 0.0]).moved([0.0, 5.0, 0.0])
    assert not calls
    assert len(moved) == 2 and len(calls) == 1
    np.testing.assert_array_equal(moved[0][1], [11.0, 7.0, 3.0])
    np.testing.assert_array_equal([p[1] for p in lazy], [[1.0, 2.0, 3.0], [0.0, 0.0, 0.0]])
    assert [p[2:] for p in moved] == [(0.5, 1.0), (0.7, 0.8)] and len(calls) == 1
    assert list(LazyPoses(list)) == []
    assert len([None] + lazy) == 3 and len(lazy + [None]) == 3  # concatenates like the list it stands for
