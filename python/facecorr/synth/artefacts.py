"""Artefacts of real scans for the ``bu3dfe-ood`` preset (issue 14).

Each kind appears on a random share of the scans (:data:`SHARES`) and is listed in the scan's
ground truth (``"artefacts": [kind, ...]``, details under ``"artefact_details"``):

- ``hair``: hair over the forehead, the temples and sometimes the brows, above a wavy hairline:
  blotchy holes (no data) and the rest lifted off the skin along its normal (roughness and noisy
  spikes of 2-10 mm);
- ``beard``: stubble (0.2-0.6 mm roughness) or a full beard (a 3-10 mm thick noisy layer) on the
  chin, the lower cheeks and the upper lip, the lips left free;
- ``glasses``: a frame (two rims, a bridge, two arms) 8-14 mm in front of the eyes and the nose
  bridge: **extra geometry**, plus the holes its shadow and the lenses' reflections leave on the
  skin behind it;
- ``missing_chin``: everything below a cut between the lower lip and the menton removed (chin,
  jaw line and neck);
- ``shoulders``: a raw crop (head, neck, ears: ``crop="none"``) with a collar, shoulders and a
  chest in clothing with folds: **extra geometry**;
- ``resolution``: the scanner's sampling set for 5k-300k vertices (log-uniform);
- ``colour``: per-vertex colour or a texture (``facecorr.synth.colour``; hair and beard are dark,
  glasses black, clothing one colour).

**Ground truth stays exact.** Every scan vertex keeps its ICT triangle and barycentric
coordinates and its noise-free point on the true face (``clean``): a vertex lifted by hair or a
beard keeps the skin point under it as its truth. Added geometry (glasses, clothing) has no
correspondence: ``tri = -1``, ``bary = 0`` in the dense npz (skipped by
:func:`facecorr.evaluation.metrics.dense_error`), and the per-vertex ``artefact_label``
(:data:`LABELS`) says what each vertex is. The landmarks and iBUG-68 points are those the
scanner put on the true surface; a point in a hole left by hair or glasses is kept (the skin is
there, only unseen), a point cut away with the chin is ``null`` (like a cropped jaw line).

Everything here works in the model frame (mm, +y up, +z out of the face) before the scan's pose.
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from ..geometry.mesh import vertex_normals
from .model import ICTModel
from .scanner import Scan

__all__ = ["ARTEFACTS", "SHARES", "LABELS", "draw_plan", "apply_artefacts", "artefact_colours", "noise_field"]

#: The kinds of artefact, in the order they are drawn and applied.
ARTEFACTS = ("resolution", "shoulders", "hair", "beard", "glasses", "missing_chin", "colour")

#: The share of scans that show each kind.
SHARES = {"resolution": 0.3, "shoulders": 0.2, "hair": 0.3, "beard": 0.3, "glasses": 0.3, "missing_chin": 0.2,
          "colour": 0.3}

#: Per-vertex labels of the dense npz's ``artefact_label``.
LABELS = {"skin": 0, "hair": 1, "beard": 2, "glasses": 3, "clothing": 4}

#: Sampled surface area (mm^2) of a face crop and of a raw crop per vertex at 1 mm spacing: the
#: vertex count of a scan is about AREA / spacing^2 (measured on the bu3dfe preset).
AREA_FACE_MM2, AREA_RAW_MM2 = 36000.0, 121000.0


def draw_plan(rng: np.random.Generator) -> dict:
    """Which artefacts one scan shows and the settings they need before scanning.

    Returns
    -------
    dict kind -> settings for each chosen kind: ``resolution``: ``{"target_vertices"}``;
    ``colour``: ``{"source": "vertex" | "texture"}``; the others ``{}``.
    """
    plan = {}
    for kind in ARTEFACTS:
        on = rng.uniform() < SHARES[kind]
        extra = rng.uniform()  # one draw per kind whether chosen or not: plans do not shift each other
        if not on:
            continue
        if kind == "resolution":
            plan[kind] = {"target_vertices": int(round(np.exp(np.log(5000.0) + extra * np.log(300000.0 / 5000.0))))}
        elif kind == "colour":
            plan[kind] = {"source": "vertex" if extra < 0.5 else "texture"}
        else:
            plan[kind] = {}
    return plan


def scanner_overrides(plan: dict) -> dict:
    """ScannerConfig fields the plan changes: ``crop``/``spacing`` for ``shoulders`` (a raw crop)
    and ``resolution``."""
    raw = "shoulders" in plan
    out = {"crop": "none" if raw else "face", "spacing": 1.5 if raw else 1.0}
    if "resolution" in plan:
        area = AREA_RAW_MM2 if raw else AREA_FACE_MM2
        out["spacing"] = float(np.clip(np.sqrt(area / plan["resolution"]["target_vertices"]), 0.3, 3.0))
    return out


def noise_field(rng: np.random.Generator, X: np.ndarray, scale: float, n: int = 40) -> np.ndarray:
    """(N,) a smooth random field at the points ``X`` (N, 3) mm: a sum of ``n`` signed Gaussian bumps
    of width ``scale`` mm centred on random points of ``X``, standardised to mean 0 and std 1."""
    X = np.asarray(X, float)
    if len(X) == 0:
        return np.zeros(0)
    centres = X[rng.integers(0, len(X), n)]
    sign = rng.choice([-1.0, 1.0], n)
    f = np.zeros(len(X))
    for c, s in zip(centres, sign):
        f += s * np.exp(-np.sum((X - c) ** 2, axis=1) / (2.0 * scale * scale))
    sd = f.std()
    return (f - f.mean()) / (sd if sd > 0 else 1.0)


def _smoothstep(u):
    u = np.clip(u, 0.0, 1.0)
    return u * u * (3.0 - 2.0 * u)


class _Editable:
    """A scan being edited: arrays plus per-vertex labels."""

    def __init__(self, scan: Scan):
        self.noisy = scan.vertices.copy()
        self.faces = scan.faces.copy()
        self.tri = scan.tri.astype(np.int32).copy()
        self.bary = scan.bary.copy()
        self.clean = scan.clean.copy()
        self.label = np.zeros(len(self.noisy), np.uint8)

    def normals(self):
        return vertex_normals(self.clean, self.faces)

    def drop(self, remove: np.ndarray) -> int:
        """Remove the vertices ``remove`` (bool mask), their triangles and what is left unreferenced."""
        keep_f = ~remove[self.faces].any(1)
        F = self.faces[keep_f]
        used = np.zeros(len(self.noisy), bool)
        used[F.ravel()] = True
        remap = np.full(len(self.noisy), -1, np.int64)
        remap[used] = np.arange(int(used.sum()))
        n_before = len(self.noisy)
        self.faces = remap[F]
        for name in ("noisy", "tri", "bary", "clean", "label"):
            setattr(self, name, getattr(self, name)[used])
        return n_before - len(self.noisy)

    def append(self, V: np.ndarray, F: np.ndarray, label: str, noisy: np.ndarray | None = None) -> None:
        """Add geometry with no correspondence (``tri = -1``)."""
        n0 = len(self.noisy)
        self.noisy = np.concatenate([self.noisy, V if noisy is None else noisy])
        self.clean = np.concatenate([self.clean, V])
        self.tri = np.concatenate([self.tri, np.full(len(V), -1, np.int32)])
        self.bary = np.concatenate([self.bary, np.zeros((len(V), 3))])
        self.label = np.concatenate([self.label, np.full(len(V), LABELS[label], np.uint8)])
        self.faces = np.concatenate([self.faces, np.asarray(F, np.int64) + n0])

    def drop_small_pieces(self, min_vertices: int) -> None:
        n = len(self.noisy)
        F = self.faces
        adj = coo_matrix((np.ones(2 * len(F)), (np.concatenate([F[:, 0], F[:, 1]]), np.concatenate([F[:, 1], F[:, 2]]))),
                         shape=(n, n))
        _, lab = connected_components(adj, directed=False)
        sizes = np.bincount(lab, minlength=lab.max() + 1)
        small = (sizes[lab] < min_vertices) & (self.label == 0)
        if small.any():
            self.drop(small)


def _grid_faces(rows: int, cols: int, closed: bool = False) -> np.ndarray:
    """Triangles of a rows x cols vertex grid (row-major), optionally closed across the columns."""
    c_end = cols if closed else cols - 1
    r, c = np.meshgrid(np.arange(rows - 1), np.arange(c_end), indexing="ij")
    r, c = r.ravel(), c.ravel()
    c1 = (c + 1) % cols
    a, b, d, e = r * cols + c, r * cols + c1, (r + 1) * cols + c, (r + 1) * cols + c1
    return np.concatenate([np.stack([a, d, b], 1), np.stack([b, d, e], 1)])


def _resample(P: np.ndarray, step: float, closed: bool = False) -> np.ndarray:
    """A polyline (K, 3) resampled at about ``step`` mm."""
    Q = np.vstack([P, P[:1]]) if closed else P
    seg = np.linalg.norm(np.diff(Q, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    n = max(int(np.ceil(s[-1] / step)), 2)
    t = np.linspace(0.0, s[-1], n, endpoint=not closed)
    return np.stack([np.interp(t, s, Q[:, k]) for k in range(3)], 1)


def _band(P: np.ndarray, side: np.ndarray, width: float, step: float, closed: bool = False):
    """A ribbon of ``width`` mm along the polyline P (K, 3), spanned by the unit vectors ``side``
    (K, 3): (vertices, triangles)."""
    rows = max(int(np.ceil(width / step)) + 1, 2)
    offs = np.linspace(-0.5 * width, 0.5 * width, rows)
    V = (P[None, :, :] + offs[:, None, None] * side[None, :, :]).reshape(-1, 3)
    return V, _grid_faces(rows, len(P), closed)


# ------------------------------------------------------------------------------------------
def _hair(ed: _Editable, ib: np.ndarray, rng) -> dict:
    brow = ib[17:27]
    order = np.argsort(brow[:, 0])
    bx, by = brow[order, 0], brow[order, 1]
    outer_x = 0.5 * (abs(ib[36, 0]) + abs(ib[45, 0]))
    b = rng.uniform(-3.0, 25.0)
    c = rng.uniform(2.0, 8.0)
    lam = rng.uniform(40.0, 90.0)
    phi = rng.uniform(0.0, 2.0 * np.pi)
    x_t = outer_x + rng.uniform(0.0, 8.0)
    slope = rng.uniform(0.3, 1.0)
    floor = ib[36:48, 1].max() + 3.0  # never over the eyes themselves

    def in_hair(X):
        line = np.interp(X[:, 0], bx, by) + b + c * np.sin(2.0 * np.pi * X[:, 0] / lam + phi) \
            - slope * np.maximum(np.abs(X[:, 0]) - x_t, 0.0)
        return (X[:, 1] > np.maximum(line, floor)) & (ed.label == 0)

    region = in_hair(ed.clean)
    info = {"hairline_above_brows_mm": round(float(b), 2)}
    if not region.any():
        return {**info, "removed": 0, "lifted": 0}
    field = noise_field(rng, ed.clean, rng.uniform(6.0, 14.0))
    thr = np.quantile(field[region], rng.uniform(0.45, 0.8))
    n_removed = ed.drop(region & (field > thr))
    region = in_hair(ed.clean)
    idx = np.flatnonzero(region)
    n = ed.normals()[idx]
    lift = np.abs(rng.normal(0.0, rng.uniform(0.5, 1.5), len(idx)))
    spikes = rng.uniform(size=len(idx)) < rng.uniform(0.05, 0.2)
    lift[spikes] += rng.uniform(2.0, 10.0, int(spikes.sum()))
    ed.noisy[idx] += lift[:, None] * n
    ed.label[idx] = LABELS["hair"]
    return {**info, "removed": int(n_removed), "lifted": int(len(idx)), "spikes": int(spikes.sum())}


def _lip_mask(X, ib, margin):
    lips = ib[48:60]
    c = lips.mean(0)
    hw = 0.5 * (lips[:, 0].max() - lips[:, 0].min()) + margin
    hh = 0.5 * (lips[:, 1].max() - lips[:, 1].min()) + margin
    return ((np.abs(X[:, 0] - c[0]) / hw) ** 4 + (np.abs(X[:, 1] - c[1]) / hh) ** 4) ** 0.25


def _beard(ed: _Editable, ib: np.ndarray, rng) -> dict:
    X = ed.clean
    style = "stubble" if rng.uniform() < 0.5 else "full"
    y_top = ib[33, 1] - rng.uniform(1.0, 4.0)  # just under the nose
    side_top = ib[29, 1]                        # up the cheeks at the sides
    x_side = abs(ib[48, 0] - ib[54, 0]) * 0.5 + 8.0
    top = y_top + (side_top - y_top) * _smoothstep((np.abs(X[:, 0]) - x_side) / 20.0)
    m = _smoothstep((top - X[:, 1]) / 6.0)                          # below the upper limit
    m *= _smoothstep((X[:, 1] - (ib[8, 1] - 45.0)) / 10.0)          # down the neck a little
    m *= _smoothstep((_lip_mask(X, ib, 1.0) - 1.0) / 0.25)          # the lips are free
    m *= _smoothstep((np.abs(ib[0, 0] - ib[16, 0]) * 0.5 + 5.0 - np.abs(X[:, 0])) / 10.0)
    m *= (ed.label == 0)
    idx = np.flatnonzero(m > 0.05)
    if not len(idx):
        return {"style": style, "lifted": 0}
    n = ed.normals()[idx]
    if style == "stubble":
        sigma = rng.uniform(0.2, 0.6)
        lift = np.abs(rng.normal(0.0, sigma, len(idx))) * m[idx]
        info = {"style": style, "roughness_mm": round(float(sigma), 3)}
    else:
        thick = rng.uniform(3.0, 10.0)
        field = noise_field(rng, X[idx], rng.uniform(8.0, 15.0))
        lift = m[idx] * (thick * np.clip(1.0 + 0.25 * field, 0.3, 1.7) + np.abs(rng.normal(0.0, 1.0, len(idx))))
        info = {"style": style, "thickness_mm": round(float(thick), 2)}
    ed.noisy[idx] += lift[:, None] * n
    ed.label[idx] = LABELS["beard"]
    return {**info, "lifted": int(len(idx))}


def _glasses(ed: _Editable, ib: np.ndarray, V: np.ndarray, model: ICTModel, rng, spacing: float) -> dict:
    step = max(min(spacing, 1.5), 0.5)
    face = V[model.part_id == model.part_names.index("face")]
    width = rng.uniform(2.5, 5.0)
    a, b = rng.uniform(22.0, 27.0), rng.uniform(15.0, 19.0)
    dy = rng.uniform(-3.0, 1.0)
    out_x = rng.uniform(0.0, 3.0)
    eyes = [ib[36:42].mean(0), ib[42:48].mean(0)]
    near = np.zeros(len(face), bool)
    for c in eyes:
        near |= (np.abs(face[:, 0] - c[0]) < 1.6 * a) & (np.abs(face[:, 1] - c[1]) < b)
    z_front = float(face[near, 2].max()) + rng.uniform(8.0, 14.0)
    parts, shadow = [], np.zeros(len(ed.clean), bool)
    lens = np.zeros(len(ed.clean), bool)
    X = ed.clean
    e = 3.0
    t = np.linspace(0.0, 2.0 * np.pi, 400, endpoint=False)
    for k, c in enumerate(eyes):
        sgn = -1.0 if k == 0 else 1.0
        cx, cy = c[0] + sgn * out_x, c[1] + dy
        ct, st = np.cos(t), np.sin(t)
        px = cx + a * np.sign(ct) * np.abs(ct) ** (2.0 / e)
        py = cy + b * np.sign(st) * np.abs(st) ** (2.0 / e)
        pz = z_front - 0.12 * np.abs(px - 0.0) + 0.12 * abs(cx)  # a slight wrap
        P = _resample(np.stack([px, py, pz], 1), step, closed=True)
        # outward in-plane normal of the rim: from the centre
        side = P - np.array([cx, cy, 0.0])
        side[:, 2] = 0.0
        side /= np.maximum(np.linalg.norm(side, axis=1, keepdims=True), 1e-9)
        parts.append(_band(P, side, width, step, closed=True))
        r = ((np.abs(X[:, 0] - cx) / a) ** e + (np.abs(X[:, 1] - cy) / b) ** e) ** (1.0 / e)
        front = X[:, 2] < z_front
        shadow |= front & (np.abs(r - 1.0) * min(a, b) < 0.5 * width + 1.0)
        lens |= front & (r < 1.0)
        if k == 0:
            inner_r = (cx + a, cy)
        else:
            inner_l = (cx - a, cy)
        # the arm: from the rim's outer side straight back, just outside the head
        x0 = cx + sgn * a
        y_arm = cy + rng.uniform(0.0, 5.0)
        zs = np.arange(z_front, z_front - 90.0, -step)
        head = V[(np.abs(V[:, 1] - y_arm) < 4.0) & (sgn * V[:, 0] > 0)]
        xs = []
        last = abs(x0)
        for z in zs:
            sl = head[np.abs(head[:, 2] - z) < 4.0]
            last = max(last, float(np.abs(sl[:, 0]).max()) + 2.5) if len(sl) else last
            xs.append(sgn * last)
        A = np.stack([np.array(xs), np.full(len(zs), y_arm), zs], 1)
        parts.append(_band(A, np.tile([0.0, 1.0, 0.0], (len(A), 1)), 0.8 * width, step))
    # the bridge over the nose, a little higher than the rims' centres
    yb = 0.5 * (inner_r[1] + inner_l[1]) + rng.uniform(3.0, 8.0)
    xb = np.linspace(inner_r[0], inner_l[0], 40)
    nose = V[(np.abs(V[:, 1] - yb) < 3.0) & (np.abs(V[:, 0]) < 8.0)]
    zb = max(z_front, float(nose[:, 2].max()) + 3.0 if len(nose) else z_front) + 2.0 * np.cos(np.pi * xb / (xb[-1] - xb[0]))
    P = _resample(np.stack([xb, yb - 4.0 * np.cos(np.pi * (xb - xb.mean()) / (xb[-1] - xb[0])), zb], 1), step)
    parts.append(_band(P, np.tile([0.0, 1.0, 0.0], (len(P), 1)), 0.8 * width, step))
    shadow |= (np.abs(X[:, 1] - yb) < 0.4 * width + 4.0) & (np.abs(X[:, 0]) < abs(inner_r[0])) & (X[:, 2] < z_front + 5)
    # reflections: holes in the lenses' area
    field = noise_field(rng, X, rng.uniform(3.0, 6.0))
    refl = lens & (field > np.quantile(field[lens], rng.uniform(0.75, 0.95))) if lens.any() else lens
    n_removed = ed.drop((shadow | refl) & (ed.label == 0))
    n_added = 0
    for Vg, Fg in parts:
        ed.append(Vg, Fg, "glasses", noisy=Vg + rng.normal(0.0, 0.15, Vg.shape))
        n_added += len(Vg)
    return {"frame_z_in_front_of_eyes_mm": round(float(z_front - face[near, 2].max()), 2), "rim_mm": [round(a, 2), round(b, 2)],
            "removed": int(n_removed), "added": n_added}


def _missing_chin(ed: _Editable, ib: np.ndarray, rng) -> tuple[dict, float, float]:
    lo, hi = ib[8, 1] + 6.0, ib[57, 1] - 3.0
    y_cut = rng.uniform(lo, hi) if hi > lo else 0.5 * (lo + hi)
    tilt = rng.uniform(-0.1, 0.1)
    cut = (ed.clean[:, 1] < y_cut + tilt * ed.clean[:, 0]) & (ed.label != LABELS["clothing"])
    n = ed.drop(cut)
    return {"cut_y_mm": round(float(y_cut), 2), "removed": int(n)}, float(y_cut), float(tilt)


def _shoulders(ed: _Editable, V: np.ndarray, model: ICTModel, rng, spacing: float) -> dict:
    step = max(spacing, 1.0)
    y_low = float(ed.clean[:, 1].min()) + 5.0
    head = V[model.part_id == model.part_names.index("head_neck")]
    ring = head[np.abs(head[:, 1] - (y_low + 10.0)) < 4.0]
    if len(ring) < 10:
        ring = head[np.argsort(head[:, 1])[:200]]
    cx, cz = float(ring[:, 0].mean()), float(ring[:, 2].mean())
    rx = float(np.abs(ring[:, 0] - cx).max()) + 4.0
    rz = float(np.abs(ring[:, 2] - cz).max()) + 4.0
    A, B = rng.uniform(165.0, 200.0), rng.uniform(100.0, 130.0)
    # profile: (radius scale from the collar to the shoulders, y) along u in [0, 1]
    knots_u = np.array([0.0, 0.12, 0.2, 0.45, 1.0])
    knots_s = np.array([0.0, 0.0, 0.1, 1.0, 1.0])
    knots_y = np.array([y_low + 18.0, y_low - 2.0, y_low - 6.0, y_low - 40.0, y_low - 160.0])
    length = 20.0 + 5.0 + np.hypot(A - rx, 34.0) + 120.0
    n_u = max(int(length / step), 20)
    u = np.linspace(0.0, 1.0, n_u)
    s = np.interp(u, knots_u, knots_s)
    s = s * s * (3.0 - 2.0 * s)
    y = np.interp(u, knots_u, knots_y)
    rxu, rzu = rx + (A - rx) * s, rz + (B - rz) * s
    n_t = max(int(np.pi * 1.2 * A / step), 40)
    th = np.linspace(-np.radians(105.0), np.radians(105.0), n_t)
    X = cx + rxu[:, None] * np.sin(th)[None, :]
    Z = cz + rzu[:, None] * np.cos(th)[None, :]
    Y = np.repeat(y[:, None], n_t, 1)
    P = np.stack([X, Y, Z], -1).reshape(-1, 3)
    radial = np.stack([np.sin(th)[None, :] * np.ones((n_u, 1)), np.zeros((n_u, n_t)),
                       np.cos(th)[None, :] * np.ones((n_u, 1))], -1).reshape(-1, 3)
    folds = 2.5 * noise_field(rng, P, rng.uniform(15.0, 30.0), n=30)
    P = P + np.clip(folds, -6.0, 6.0)[:, None] * radial
    F = _grid_faces(n_u, n_t)
    ed.append(P, F, "clothing", noisy=P + rng.normal(0.0, 0.2, P.shape))
    return {"added": int(len(P)), "shoulder_half_width_mm": round(float(A), 1)}


def apply_artefacts(scan: Scan, V: np.ndarray, model: ICTModel, plan: dict, rng: np.random.Generator, spacing: float):
    """Apply the plan's geometric artefacts to a scan made with the identity pose.

    Parameters
    ----------
    scan : Scan of the head ``V`` in the model frame (pose = identity), from
        :func:`facecorr.synth.scanner.scan_head` with :func:`scanner_overrides`.
    V : (N, 3) mm, the true head (ICT vertex order).
    model : ICTModel. plan : from :func:`draw_plan`. rng : the scan's generator.
    spacing : float, the scanner's spacing (mm), for the density of added geometry.

    Returns
    -------
    (scan, labels (S,) uint8, details {kind: dict}) -- a new Scan (still model frame) with
    ``ibug68`` points cut away with the chin set to NaN.
    """
    ib = V[model.landmarks68]
    ed = _Editable(scan)
    details = {}
    ibug = scan.ibug68.copy()
    if "resolution" in plan:
        details["resolution"] = {"target_vertices": plan["resolution"]["target_vertices"], "spacing_mm": round(spacing, 4)}
    if "shoulders" in plan:  # first: it sits under the neck the raw scan ends with
        details["shoulders"] = _shoulders(ed, V, model, rng, spacing)
    if "hair" in plan:
        details["hair"] = _hair(ed, ib, rng)
    if "beard" in plan:
        details["beard"] = _beard(ed, ib, rng)
    if "missing_chin" in plan:
        details["missing_chin"], y_cut, tilt = _missing_chin(ed, ib, rng)
        gone = np.isfinite(ibug).all(1) & (ibug[:, 1] < y_cut + tilt * ibug[:, 0] + 0.5)
        ibug[gone] = np.nan
    ed.drop_small_pieces(60)
    if "glasses" in plan:
        details["glasses"] = _glasses(ed, ib, V, model, rng, spacing)
        ed.drop_small_pieces(60)
    if "colour" in plan:
        details["colour"] = dict(plan["colour"])
    out = Scan(vertices=ed.noisy, faces=ed.faces.astype(np.int64), tri=ed.tri, bary=ed.bary, clean=ed.clean,
               pose=scan.pose, landmarks=scan.landmarks, ibug68=ibug, info=dict(scan.info))
    if "resolution" in details:
        details["resolution"]["vertices"] = int(len(out.vertices))
    return out, ed.label, details


def artefact_colours(rng_seed: int) -> dict:
    """RGB in [0, 1] of each artefact label: hair and beard dark brown, glasses near black,
    clothing one colour drawn from ``rng_seed``."""
    rng = np.random.default_rng(rng_seed)
    return {LABELS["hair"]: np.array([0.22, 0.15, 0.10]), LABELS["beard"]: np.array([0.25, 0.18, 0.12]),
            LABELS["glasses"]: np.array([0.05, 0.05, 0.06]), LABELS["clothing"]: rng.uniform(0.1, 0.9, 3)}
