"""Simulated structured-light / stereo face scanner with exact dense ground truth.

How a scan is made from a deformed ICT head (model frame, mm):

1. **Sampling grid** — a cylindrical range image around the head's vertical axis (x = 0,
   z = ``axis_z``): columns are angles, rows are heights, spacing ``spacing`` mm (at radius
   ``ref_radius`` for the angular step), with a random sub-pixel phase per scan. Every ICT
   triangle (face, head, eyeballs, mouth socket, gums, tongue, teeth) is rasterized into it with
   depth = -radius (:func:`facecorr.raster.rasterize`), so each pixel is the outermost surface
   point along a horizontal ray towards the axis. The pixel's 3-D point is the barycentric
   combination of the hit ICT triangle: it lies exactly on the model surface and its (triangle,
   barycentric) pair is the dense ground truth.
2. **Visibility** — 2-3 perspective cameras (a stereo-pod scanner: front-left, front-right and
   one slightly below, ~700 mm away) render depth maps of the head (with a small random head
   pose relative to the scanner). A grid point is kept when at least one camera sees it: not
   occluded (depth test) and not at grazing incidence (cos > ``min_cos``). This leaves the
   natural holes: nostrils, under the chin and nose, behind the ears, occluded mouth interior.
3. **Cropping** — ``crop="face"``: inside an ellipsoid (semi-axes r, 1.15 r, r; r random in
   ``crop_radius``) centred ~30 mm behind the nose tip, and in front of a plane just before the ears, like
   BU-3DFE's cropped face models; ``crop="none"``: everything the cameras see (raw scan).
4. **Triangulation** — the grid's cells become two triangles each (split along the shorter
   diagonal); a triangle is kept when its three corners are kept and no edge is longer than
   ``max_edge_factor * spacing`` (depth discontinuities: lips/teeth, eyelids/eyeball). Small
   pieces are dropped. The connectivity has nothing to do with the ICT mesh.
5. **Sensor noise** — Gaussian along the viewing ray of the best camera (sigma drawn per scan
   from ``noise_sigma``), plus rare spikes (``spike_fraction``, ``spike_amplitude`` mm).
6. **Landmarks** — each iBUG-68 point is moved to the nearest point of the noise-free scan
   surface, as an annotator clicks the visible eye corner when the model's corner vertex lies in
   a fold (squint); a point more than ``landmark_snap_mm`` away is not on the scan (cropped jaw
   line, inner lips hidden by closed lips); ``landmark8_snap_mm`` for the 8 landmarks, which are
   always annotated. The crop sphere always contains the brows and eyes.
7. **Pose** — a random rigid transform (yaw/pitch/roll uniform within the configured ranges,
   or a uniform random rotation) and translation maps the model frame to the scan frame.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from ..names import LANDMARK_IBUG68
from ..geometry.raster import rasterize
from ..geometry.mesh import vertex_normals
from ..geometry.spatial import closest_point_on_triangles  # noqa: F401 - also imported from here
from .model import ICTModel


#: Vertical elongation of the face crop ellipsoid.
CROP_ELONGATION = 1.15


@dataclass(frozen=True)
class ScannerConfig:
    """Parameters of the simulated scanner (mm, degrees). Ranges are (low, high) uniform."""

    spacing: float = 1.0
    ref_radius: float = 100.0
    axis_z: float = 10.0
    crop: str = "face"
    crop_radius: tuple = (85.0, 95.0)
    crop_margin: float = 8.0  # mm of skin kept beyond the outermost eyebrow / eye point
    min_cos: float = 0.17
    landmark_snap_mm: float = 3.0  # max distance of a model landmark to the scan surface to be 'on the scan'
    landmark8_snap_mm: float = 6.0  # the same for the 8 landmarks of the method
    max_edge_factor: float = 3.5
    min_piece: int = 150
    noise_sigma: tuple = (0.1, 0.3)
    spike_fraction: tuple = (0.0, 4e-4)
    spike_amplitude: tuple = (1.5, 6.0)
    yaw: float = 45.0
    pitch: float = 30.0
    roll: float = 30.0
    uniform_rotation: bool = False
    translation: float = 50.0
    head_jitter: tuple = (10.0, 8.0, 5.0)
    camera_distance: float = 700.0
    camera_pixels: int = 720
    camera_fov_mm: float = 420.0
    cameras: tuple = ((-35.0, 5.0), (35.0, 5.0), (0.0, -22.0))  # (azimuth, elevation) degrees


@dataclass
class Scan:
    """One simulated scan and its ground truth (scan frame unless noted).

    vertices (S, 3) noisy mm; faces (F, 3); tri (S,) ICT triangle ids; bary (S, 3);
    clean (S, 3) noise-free positions; pose (3, 4) model -> scan; landmarks (8, 3);
    ibug68 (68, 3) with NaN where the point is not on the scan; info dict of scan parameters.
    """

    vertices: np.ndarray
    faces: np.ndarray
    tri: np.ndarray
    bary: np.ndarray
    clean: np.ndarray
    pose: np.ndarray
    landmarks: np.ndarray
    ibug68: np.ndarray
    info: dict = field(default_factory=dict)


def rot_x(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def rot_y(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def rot_z(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def random_rotation(rng, yaw, pitch, roll, uniform=False):
    """(3, 3) rotation: ``Ry(yaw) Rx(pitch) Rz(roll)`` with angles uniform in +-range (degrees),
    or a uniformly distributed rotation (unit quaternion from a 4-D Gaussian) when ``uniform``."""
    if uniform:
        q = rng.normal(size=4)
        w, x, y, z = q / np.linalg.norm(q)
        return np.array([
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ])
    a = np.radians([rng.uniform(-yaw, yaw), rng.uniform(-pitch, pitch), rng.uniform(-roll, roll)])
    return rot_y(a[0]) @ rot_x(a[1]) @ rot_z(a[2])


def closest_point_on_mesh(points: np.ndarray, V: np.ndarray, F: np.ndarray, search_radius: float):
    """Closest point of the mesh (V, F) to each of ``points`` (K, 3) (mm), looking only at
    triangles with a vertex within ``search_radius`` of the point.

    Returns (distances (K,), closest points (K, 3)); inf and NaN where no triangle is that near."""
    from scipy.spatial import cKDTree

    dist = np.full(len(points), np.inf)
    closest = np.full((len(points), 3), np.nan)
    if len(F) == 0:
        return dist, closest
    order = np.argsort(F.ravel(), kind="stable")
    starts = np.searchsorted(F.ravel()[order], np.arange(len(V) + 1))
    for k, ids in enumerate(cKDTree(V).query_ball_point(points, search_radius)):
        if not ids:
            continue
        faces = np.unique(np.concatenate([order[starts[i]:starts[i + 1]] // 3 for i in ids]))
        if len(faces):
            d, q = closest_point_on_triangles(np.repeat(points[k][None], len(faces), 0), V[F[faces]])
            j = int(np.argmin(d))
            dist[k], closest[k] = d[j], q[j]
    return dist, closest


def _cylinder_coords(p, axis_z):
    theta = np.arctan2(p[..., 0], p[..., 2] - axis_z)
    radius = np.hypot(p[..., 0], p[..., 2] - axis_z)
    return theta, radius


def _camera(azim_deg, elev_deg, target, distance):
    """Camera centre and rows of the world->camera rotation (x right, y down, z forward)."""
    az, el = np.radians(azim_deg), np.radians(elev_deg)
    centre = target + distance * np.array([np.sin(az) * np.cos(el), np.sin(el), np.cos(az) * np.cos(el)])
    fwd = (target - centre) / np.linalg.norm(target - centre)
    right = np.cross(fwd, [0.0, 1.0, 0.0])
    right /= np.linalg.norm(right)
    down = np.cross(fwd, right)
    return centre, np.stack([right, down, fwd])


def scan_head(model: ICTModel, V: np.ndarray, cfg: ScannerConfig, rng: np.random.Generator) -> Scan:
    """Simulate one scan of the deformed ICT head ``V`` ((N, 3) mm, model frame)."""
    T = model.triangles
    lm = model.landmarks68
    nose_tip = V[lm[30]]
    normals = vertex_normals(V, T)

    # --- 1. cylindrical sampling grid ------------------------------------------------------
    d_theta = cfg.spacing / cfg.ref_radius
    theta, radius = _cylinder_coords(V, cfg.axis_z)
    if cfg.crop == "face":
        th_lo, th_hi = -1.9, 1.9
        y_hi, y_lo = nose_tip[1] + 115.0, nose_tip[1] - 125.0
    else:
        th_lo, th_hi = -2.7, 2.7
        y_hi, y_lo = V[:, 1].max() + 1.0, V[:, 1].min() - 1.0
    th0 = th_lo + rng.uniform(0.0, d_theta)
    y0 = y_hi - rng.uniform(0.0, cfg.spacing)
    W = int(np.ceil((th_hi - th0) / d_theta)) + 1
    H = int(np.ceil((y0 - y_lo) / cfg.spacing)) + 1
    uv = np.stack([(theta - th0) / d_theta, (y0 - V[:, 1]) / cfg.spacing], axis=1)
    t_th = theta[T]
    keep_tri = np.nonzero((t_th.max(1) - t_th.min(1)) < np.pi)[0]  # not across the seam at the back
    tri_img, bary_img, _ = rasterize(uv, -radius, T[keep_tri], W, H)
    hit = tri_img >= 0
    tri_id = np.where(hit, keep_tri[np.maximum(tri_img, 0)], -1)

    rows, cols = np.nonzero(hit)
    gtri = tri_id[rows, cols]
    gbary = bary_img[rows, cols]
    corners = T[gtri]
    P = np.einsum("sk,skd->sd", gbary, V[corners])
    Nrm = np.einsum("sk,skd->sd", gbary, normals[corners])
    Nrm /= np.maximum(np.linalg.norm(Nrm, axis=1, keepdims=True), 1e-12)

    # --- 2. visibility from the scanner's cameras -----------------------------------------
    target = np.array([0.0, nose_tip[1] - 15.0, nose_tip[2] - 50.0])
    jit = np.radians([rng.uniform(-a, a) for a in cfg.head_jitter])
    Rj = rot_y(jit[0]) @ rot_x(jit[1]) @ rot_z(jit[2])  # head pose relative to the scanner
    Vs = (V - target) @ Rj.T + target
    Ps = (P - target) @ Rj.T + target
    Ns = Nrm @ Rj.T
    f = cfg.camera_pixels * cfg.camera_distance / cfg.camera_fov_mm
    cpx = (cfg.camera_pixels - 1) / 2.0
    px_mm = cfg.camera_fov_mm / cfg.camera_pixels
    best_cos = np.full(len(P), -np.inf)
    view_dir = np.zeros_like(P)  # in the scanner frame
    for azim, elev in cfg.cameras:
        C, Rc = _camera(azim, elev, target, cfg.camera_distance)
        q = (Vs - C) @ Rc.T
        cuv = np.stack([f * q[:, 0] / q[:, 2] + cpx, f * q[:, 1] / q[:, 2] + cpx], axis=1)
        _, _, zbuf = rasterize(cuv, q[:, 2], T, cfg.camera_pixels, cfg.camera_pixels)
        qp = (Ps - C) @ Rc.T
        pu = np.rint(f * qp[:, 0] / qp[:, 2] + cpx).astype(np.int64)
        pv = np.rint(f * qp[:, 1] / qp[:, 2] + cpx).astype(np.int64)
        inside = (pu >= 0) & (pu < cfg.camera_pixels) & (pv >= 0) & (pv < cfg.camera_pixels)
        ray = Ps - C
        ray /= np.linalg.norm(ray, axis=1, keepdims=True)
        cos = -np.einsum("sd,sd->s", Ns, ray)
        zb = np.full(len(P), -np.inf)
        zb[inside] = zbuf[pv[inside], pu[inside]]
        tan = np.sqrt(np.maximum(1.0 - cos**2, 0.0)) / np.maximum(cos, cfg.min_cos)
        tol = 0.3 + 0.75 * px_mm * tan
        seen = inside & (qp[:, 2] <= zb + tol) & (cos > cfg.min_cos)
        better = seen & (cos > best_cos)
        best_cos[better] = cos[better]
        view_dir[better] = ray[better]
    visible = best_cos > -np.inf

    # --- 3. cropping -----------------------------------------------------------------------
    keep = visible.copy()
    info = {}
    if cfg.crop == "face":
        r_crop = rng.uniform(*cfg.crop_radius)
        # an ellipsoid (1.15x taller than wide) centred ~30 mm behind the nose tip: keeps the
        # whole brows and the chin of an open mouth, drops the ears and most of the forehead
        centre = nose_tip + np.array([rng.uniform(-3, 3), rng.uniform(-4.0, 4.0), -rng.uniform(25.0, 35.0)])
        # BU-3DFE's cropped faces always contain the eyebrows and the eyes with some skin around
        # them: grow the ellipsoid if a brow or eye point would be near its edge.
        brow_eye = np.linalg.norm((V[lm[17:48]] - centre) / np.array([1.0, CROP_ELONGATION, 1.0]), axis=1)
        r_crop = max(r_crop, float(brow_eye.max()) + cfg.crop_margin)
        ear_z = 0.5 * (V[lm[0], 2] + V[lm[16], 2]) - rng.uniform(0.0, 10.0)
        dist = np.linalg.norm((P - centre) / np.array([1.0, CROP_ELONGATION, 1.0]), axis=1)
        keep &= (dist < r_crop) & (P[:, 2] > ear_z)
        info.update(crop_radius_mm=float(r_crop), crop_plane_z_mm=float(ear_z))

    # --- 4. triangulate the grid ------------------------------------------------------------
    vid = np.full((H, W), -1, dtype=np.int64)
    vid[rows[keep], cols[keep]] = np.arange(int(keep.sum()))
    Pk = P[keep]
    a, b = vid[:-1, :-1], vid[:-1, 1:]
    c, d = vid[1:, :-1], vid[1:, 1:]
    cell = (a >= 0) | (b >= 0)  # quick reject of empty cells
    a, b, c, d = a[cell], b[cell], c[cell], d[cell]

    def dist(i, j):
        ok = (i >= 0) & (j >= 0)
        out = np.full(len(i), np.inf)
        out[ok] = np.linalg.norm(Pk[i[ok]] - Pk[j[ok]], axis=1)
        return out

    ad, bc = dist(a, d), dist(b, c)
    split_ad = ad <= bc
    t1 = np.where(split_ad[:, None], np.stack([a, c, d], 1), np.stack([a, c, b], 1))
    t2 = np.where(split_ad[:, None], np.stack([a, d, b], 1), np.stack([b, c, d], 1))
    F = np.concatenate([t1, t2])
    F = F[(F >= 0).all(1)]
    e = np.stack([dist(F[:, 0], F[:, 1]), dist(F[:, 1], F[:, 2]), dist(F[:, 2], F[:, 0])], 1)
    F = F[e.max(1) <= cfg.max_edge_factor * cfg.spacing]
    # drop small pieces and unreferenced vertices
    n = len(Pk)
    adj = coo_matrix((np.ones(2 * len(F)), (np.concatenate([F[:, 0], F[:, 1]]), np.concatenate([F[:, 1], F[:, 2]]))), shape=(n, n))
    _, label = connected_components(adj, directed=False)
    used = np.zeros(n, bool)
    used[F.ravel()] = True
    sizes = np.bincount(label[used], minlength=label.max() + 1)
    good_label = sizes >= cfg.min_piece
    if cfg.crop == "face":
        good_label[:] = False
        big = np.argsort(-sizes, kind="stable")
        good_label[big[0]] = True
        # keep teeth / tongue / eyeball islands a face scan would show
        good_label |= sizes >= max(cfg.min_piece, 0.002 * sizes[big[0]])
    vkeep = used & good_label[label]
    remap = np.full(n, -1, dtype=np.int64)
    remap[vkeep] = np.arange(int(vkeep.sum()))
    F = remap[F]
    F = F[(F >= 0).all(1)]

    src = np.nonzero(keep)[0][vkeep]  # index into the grid points
    P_out, tri_out, bary_out = P[src], gtri[src], gbary[src]

    # --- 5. sensor noise along the viewing ray (model frame) ---------------------------------
    vdir = view_dir[src] @ Rj  # scanner -> model frame
    sigma = rng.uniform(*cfg.noise_sigma)
    noisy = P_out + (sigma * rng.normal(size=len(P_out)))[:, None] * vdir
    n_spikes = int(round(rng.uniform(*cfg.spike_fraction) * len(P_out)))
    if n_spikes:
        idx = rng.choice(len(P_out), n_spikes, replace=False)
        amp = rng.uniform(*cfg.spike_amplitude, n_spikes) * rng.choice([-1.0, 1.0], n_spikes)
        noisy[idx] += amp[:, None] * vdir[idx]

    # --- ground truth on the scan: the iBUG-68 points as an annotator would click them --------
    # Each model landmark is moved to the nearest point of the noise-free scan surface (a point
    # in a fold -- an eye corner of a squinting face -- to the visible corner next to it). It is
    # on the scan when that point is within ``landmark_snap_mm``; farther means cropped, unseen
    # or hidden behind another surface (e.g. an inner lip point of a closed mouth).
    ib = V[lm]
    # The 8 landmarks of the method are always annotated (a deep fold -- the subnasale under a
    # wrinkled nose in disgust -- moves them farther: up to ``landmark8_snap_mm``).
    limit = np.full(68, cfg.landmark_snap_mm)
    limit[list(LANDMARK_IBUG68)] = max(cfg.landmark_snap_mm, cfg.landmark8_snap_mm)
    snap_dist, ib_snapped = closest_point_on_mesh(ib, P_out, F, limit.max() + 2.0 * cfg.spacing)
    on_scan = snap_dist <= limit
    info["landmark_snap_mm"] = snap_dist[list(LANDMARK_IBUG68)].round(4).tolist()

    # --- 6. rigid pose ---------------------------------------------------------------------
    R = random_rotation(rng, cfg.yaw, cfg.pitch, cfg.roll, cfg.uniform_rotation)
    t = rng.uniform(-cfg.translation, cfg.translation, 3)
    pose = np.concatenate([R, t[:, None]], axis=1)

    def posed(x):
        return x @ R.T + t

    ib_gt = np.where(on_scan[:, None], ib_snapped, ib)
    ib_scan = posed(ib_gt)
    ib_scan[~on_scan] = np.nan
    info.update(noise_sigma_mm=float(sigma), n_spikes=n_spikes, spacing_mm=cfg.spacing,
                head_jitter_deg=np.degrees(jit).round(3).tolist())
    return Scan(
        vertices=posed(noisy), faces=F, tri=tri_out.astype(np.int32), bary=bary_out,
        clean=posed(P_out), pose=pose, landmarks=posed(ib_gt[list(LANDMARK_IBUG68)]),
        ibug68=ib_scan, info=info,
    )
