"""The blendshape template P(alpha) = A0 + sum_k alpha_k A_k that the registration fits.

Everything is cut from the vendored ICT face model (``data/ict/ict_face_model.npz``, MIT) by the
deterministic :func:`build_template`; ``python -m facecorr.template --build`` writes the result to
``data/template.npz`` (committed, float32) and :func:`load_template` reads it (cached).

Frame and units
    The ICT model's own frame, unchanged: millimetres, +y up, +z out of the face, the subject's
    right at -x (iBUG-68 point 36, the right outer eye corner, is at x = -44.6 mm). Keeping the
    model frame means a scan generated from the model and the template share coordinates up to
    the scan's rigid pose.

Rest pose A0 (5325 vertices, 10287 triangles)
    The ICT generic neutral over the model's ``narrow_face`` area (forehead to chin, cheek to
    cheek; no ears, neck, mouth socket, teeth, tongue or eyeballs) minus its PEEL_RINGS = 8
    outermost vertex rings and minus the nostril tubes -- the extent of a BU-3DFE cropped face.

    - The crop: the narrow face's edge loops are concentric (138 vertices each), so peeling
      whole rings keeps a smooth outer boundary (largest turn between consecutive boundary
      edges: 6 degrees). Why peel: on 14 synthetic BU-3DFE-like scans (``facecorr.synth``, tiny
      preset, seed 1, level 4, a perfect registration) the share of scans with data within 2 mm
      of a vertex averages 0.03-0.56 on rings 0-7 (forehead top, temples, under the chin:
      outside the scans' crop), 0.65 on ring 8 and >= 0.8 from ring 10 on; a template reaching
      far beyond the scans only inflates MHD and leaves vertices without data. The eyebrow
      points (iBUG 17-26, ring 12) stay 4 rings inside; the upper jaw line (iBUG 0-4, 12-16) is
      cut (``ibug68`` = -1 there).
    - The nostril tubes (2 x 138 vertices) go deep into the nose where no scanner looks: a
      vertex near the nose is dropped when no horizontal-ish view (yaw -60..60, pitch 0 / 15 deg
      from below) sees it unoccluded and at a non-grazing angle (:func:`_nostril_interiors`).
      Their cut edges are two small boundary loops inside the nostrils, out of sight.

    Faces are the ICT triangles with all three corners kept, in ICT order and with ICT corner
    order, so a point given by (ICT triangle, barycentric coords) is the same point on the
    template (:attr:`Template.ict_face_to_template_face`): dense ground truth stays exact. The
    cut is one connected, edge-manifold piece with six boundary loops (BOUNDARY_LOOP_NAMES): the
    outer crop line, the two eye openings, the mouth slit (open between the lips, as in the
    model) and the two nostrils. No decimation: 5325 vertices is already inside the 5-10k
    budget.

Blendshapes A_k (K = 14 displacement fields, mm, weights meant in [0, 1])
    Chosen from the 53 ICT (ARKit-named) expression shapes, mostly jaw, lips and mouth corners
    plus brows, as the paper asks (expression fitting: "no two blendshapes add the same kind of
    displacement"). Redundancy is measured by the cosine similarity of the flattened
    displacement fields over the template (``blendshape_cosine`` in the npz); the rule is that no
    two kept fields have cosine >= MAX_BLENDSHAPE_COSINE = 0.65 (the same motion twice) or
    <= MIN_BLENDSHAPE_COSINE = -0.95 (a motion and its exact undoing, which could only cancel).
    Numbers from the build (benches/template_coverage.py measures what the set reproduces):

    Candidates dropped or merged (cosine to the kept shape, over the template):

    - mouthLowerDown_L+R: 0.85 with jawOpen (the lower lip goes down with the jaw) -> dropped.
    - mouthClose -0.86 and mouthPress_L+R -0.84 with jawOpen, 0.85 and 0.84 with mouthShrugLower
      (they close the lips, mostly what the chin raiser does) -> dropped.
    - mouthShrugLower (chin raiser, FACS AU17, in sadness, anger, disgust) is kept although its
      cosine with jawOpen is -0.92: it is the only way to move the chin and lower lip *up*
      (weights are >= 0), and without it 73% of its displacement over mouth + chin is left
      unexplained by the other 13 shapes (bounded least squares). The pair's Gram matrix has
      eigenvalues 1.92 and 0.08: jointly fittable, not degenerate.
    - mouthFunnel: 0.88 with mouthPucker (the same lip protrusion) -> merged, A = (pucker +
      funnel) / 2, cosine 0.97 / 0.97 to the two.
    - mouthDimple_L/_R: 0.79 with mouthSmile, same side -> dropped.
    - noseSneer_L+R 0.89 and mouthShrugUpper 0.75 with mouthUpperUp -> dropped.
    - browInnerUp/browOuterUp of one side: 0.654 -> kept only as left+right sums (0.63).

    Kept, with each one's largest and smallest cosine to the other kept fields
    (``python -m facecorr.template --build`` stores the matrix as ``blendshape_cosine``):

    ==============  ==========================  ==========================
    blendshape      max cosine (with)           min cosine (with)
    ==============  ==========================  ==========================
    jawOpen         +0.21 (mouthFrown_L/_R)     -0.92 (mouthShrugLower)
    mouthSmile_L    +0.57 (mouthStretch_L)      -0.39 (mouthPucker)
    mouthSmile_R    +0.57 (mouthStretch_R)      -0.39 (mouthPucker)
    mouthFrown_L    +0.58 (mouthStretch_L)      -0.41 (mouthUpperUp)
    mouthFrown_R    +0.58 (mouthStretch_R)      -0.41 (mouthUpperUp)
    mouthStretch_L  +0.58 (mouthFrown_L)        -0.57 (mouthPucker)
    mouthStretch_R  +0.58 (mouthFrown_R)        -0.57 (mouthPucker)
    mouthPucker     +0.25 (mouthShrugLower)     -0.57 (mouthStretch_L/_R)
    mouthUpperUp    +0.40 (mouthSmile_L/_R)     -0.41 (mouthFrown_L/_R)
    mouthShrugLower +0.25 (mouthPucker)         -0.92 (jawOpen)
    browInnerUp     +0.63 (browOuterUp)         -0.32 (browDown_L/_R)
    browOuterUp     +0.63 (browInnerUp)         -0.51 (browDown_L/_R)
    browDown_L      +0.02 (browDown_R)          -0.51 (browOuterUp)
    browDown_R      +0.02 (browDown_L)          -0.51 (browOuterUp)
    ==============  ==========================  ==========================

    Recipes: mouthPucker = (ICT mouthPucker + mouthFunnel) / 2; mouthUpperUp, browInnerUp and
    browOuterUp = the ICT _L + _R shapes; the others are the ICT shape of that name. Symmetric
    actions are summed to keep K small; the lip-corner actions and browDown stay split because
    real expressions are often asymmetric there and their left/right cosines are below 0.1.
    Negative cosines are opposite motions (brows down vs up, lips stretched vs puckered, jaw
    down vs chin up), which the weights in [0, 1] keep apart.

Regions (paper Fig. 7: upper face, chin, mouth), per vertex, ``REGION_NAMES`` order
    mouth
        the lips and mouth corners: the vertices whose (x, y) lie in the ellipse around the lip
        contour (iBUG 48-59) with semi-axes half the mouth width + 10 mm and half the lip height
        + 7 mm (its top stays below the subnasal point).
    chin
        the jaw below the lower lip: vertices below the lowest lip point (iBUG 57), outside the
        mouth, that jawOpen moves by at least 35% of its largest displacement (the chin and the
        front of the mandible, not the cheeks near the jaw hinge), and whose rest-pose normal is
        within 60 deg of +z. The last condition leaves out the under-chin surface, which a
        frontal scanner does not see: the paper's expression fit waits until 80% of the chin
        vertices have a valid nearest neighbour on the scan, which an unseen half of the region
        would never allow.
    upper
        the rest (forehead, eyes, nose, cheeks, and the under-chin surface).
    Each region is one edge-connected piece (small islands are given to the neighbouring region).

Landmarks
    ``ibug68``: the ICT ``landmarks68`` vertices mapped to template ids (-1 where outside: the
    upper jaw line 0-4 and 12-16; every evaluation point 17-59 is inside). The 8 landmarks of the method are iBUG 36, 39, 42, 45, 31,
    35, 30, 33 (``facecorr.names.LANDMARK_IBUG68``).

Landmark graph Pa (the paper's Fig. 2 structure; its picture is not in the text we have)
    The 8 landmark positions on A0 with GRAPH_EDGES (indices in LANDMARK_NAMES order): the eye
    corners in a chain (outer-inner-inner-outer), each inner eye corner to the nose tip and to
    its subalare, each outer eye corner to its subalare, and the nose points to each other (both
    subalare to the tip and to the subnasal, tip to subnasal): 14 edges, a planar triangulated
    graph that fixes left/right and up/down once the nose points are labelled.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from ..names import LANDMARK_IBUG68, LANDMARK_NAMES

DATA_DIR = Path(__file__).resolve().parent.parent / "data"
ICT_MODEL_PATH = DATA_DIR / "ict" / "ict_face_model.npz"
TEMPLATE_PATH = DATA_DIR / "template.npz"

#: Per-vertex region labels, in this order (``Template.regions`` holds indices into it).
REGION_NAMES = ("upper", "chin", "mouth")
UPPER, CHIN, MOUTH = 0, 1, 2

#: Blendshapes: name -> {ICT expression name: weight}; A_k = sum weight * ICT displacement.
BLENDSHAPE_RECIPES: tuple[tuple[str, dict[str, float]], ...] = (
    ("jawOpen", {"jawOpen": 1.0}),
    ("mouthSmile_L", {"mouthSmile_L": 1.0}),
    ("mouthSmile_R", {"mouthSmile_R": 1.0}),
    ("mouthFrown_L", {"mouthFrown_L": 1.0}),
    ("mouthFrown_R", {"mouthFrown_R": 1.0}),
    ("mouthStretch_L", {"mouthStretch_L": 1.0}),
    ("mouthStretch_R", {"mouthStretch_R": 1.0}),
    ("mouthPucker", {"mouthPucker": 0.5, "mouthFunnel": 0.5}),
    ("mouthUpperUp", {"mouthUpperUp_L": 1.0, "mouthUpperUp_R": 1.0}),
    ("mouthShrugLower", {"mouthShrugLower": 1.0}),
    ("browInnerUp", {"browInnerUp_L": 1.0, "browInnerUp_R": 1.0}),
    ("browOuterUp", {"browOuterUp_L": 1.0, "browOuterUp_R": 1.0}),
    ("browDown_L", {"browDown_L": 1.0}),
    ("browDown_R", {"browDown_R": 1.0}),
)

#: No two kept blendshapes may have a displacement cosine similarity at or above this ...
MAX_BLENDSHAPE_COSINE = 0.65
#: ... or at or below this (nearly exactly opposite fields would only cancel each other).
MIN_BLENDSHAPE_COSINE = -0.95

#: Landmark-graph edges, pairs of indices into LANDMARK_NAMES (0 right outer eye corner,
#: 1 right inner, 2 left inner, 3 left outer, 4 right subalare, 5 left subalare, 6 nose tip,
#: 7 subnasal).
GRAPH_EDGES = (
    (0, 1), (1, 2), (2, 3),          # eye corners, right to left
    (1, 6), (2, 6),                  # inner eye corners - nose tip
    (1, 4), (2, 5),                  # inner eye corners - subalare, same side
    (0, 4), (3, 5),                  # outer eye corners - subalare, same side
    (4, 6), (5, 6), (4, 7), (5, 7),  # subalare - tip, subalare - subnasal
    (6, 7),                          # tip - subnasal
)

#: The template's boundary loops (``Template.boundary_loops`` keys).
BOUNDARY_LOOP_NAMES = ("outer", "right_eye", "left_eye", "mouth", "right_nostril", "left_nostril")

# The crop: vertex rings peeled off the narrow face's outer boundary (module docstring).
PEEL_RINGS = 8

# Region geometry (mm), see the module docstring.
MOUTH_MARGIN_X = 10.0
MOUTH_MARGIN_Y = 7.0
CHIN_JAW_FRACTION = 0.35
CHIN_MIN_NORMAL_Z = 0.5  # cos 60 deg: the chin region is what a frontal scanner sees
REGION_SMOOTHING_PASSES = 3

_FORMAT_VERSION = 1


@dataclass(frozen=True, eq=False)
class Template:
    """The blendshape template (arrays are read-only; see the module docstring for how it is built).

    Attributes
    ----------
    vertices : (N, 3) float64, mm -- the rest pose A0 in the template frame.
    faces : (M, 3) int64 -- triangles (ICT corner order).
    blendshapes : (K, N, 3) float64, mm -- displacement fields A_k.
    blendshape_names : tuple of K str.
    blendshape_cosine : (K, K) float64 -- cosine similarity of the flattened A_k.
    regions : (N,) int8 -- index into REGION_NAMES.
    boundary : (B,) int64 -- vertex ids on any boundary loop, sorted.
    boundary_loops : dict name -> (n,) int64 -- each loop in order, BOUNDARY_LOOP_NAMES: "outer",
        "right_eye", "left_eye", "mouth", "right_nostril", "left_nostril".
    landmark_ids : (8,) int64 -- vertex ids of the LANDMARK_NAMES landmarks, in that order.
    landmarks : dict name -> vertex id.
    ibug68 : (68,) int64 -- vertex id of each iBUG-68 point, -1 where outside the template.
    graph_points : (8, 3) float64, mm -- the landmark-graph template Pa (A0 at landmark_ids).
    graph_edges : (E, 2) int64 -- pairs of indices into landmark_ids.
    ict_vertex : (N,) int64 -- index of each vertex in the vendored ICT model.
    ict_face_to_template_face : (M_ict,) int64 -- template face of each ICT triangle, -1 if none.
    """

    vertices: np.ndarray
    faces: np.ndarray
    blendshapes: np.ndarray
    blendshape_names: tuple
    blendshape_cosine: np.ndarray
    regions: np.ndarray
    boundary: np.ndarray
    boundary_loops: dict
    landmark_ids: np.ndarray
    ibug68: np.ndarray
    graph_points: np.ndarray
    graph_edges: np.ndarray
    ict_vertex: np.ndarray
    ict_face_to_template_face: np.ndarray

    @property
    def n_vertices(self) -> int:
        return len(self.vertices)

    @property
    def n_blendshapes(self) -> int:
        return len(self.blendshapes)

    @property
    def region_names(self) -> tuple:
        """REGION_NAMES: ``regions`` holds indices into it."""
        return REGION_NAMES

    @property
    def landmarks(self) -> dict:
        """Landmark name -> template vertex id."""
        return {n: int(i) for n, i in zip(LANDMARK_NAMES, self.landmark_ids)}

    def region_ids(self, name: str) -> np.ndarray:
        """(n,) vertex ids of region ``name`` (one of REGION_NAMES)."""
        if name not in REGION_NAMES:
            raise ValueError(f"unknown region {name!r}; expected one of {REGION_NAMES}")
        return np.flatnonzero(self.regions == REGION_NAMES.index(name))

    def expression(self, alpha) -> np.ndarray:
        """P(alpha) = A0 + sum_k alpha_k A_k.

        Parameters
        ----------
        alpha : (K,) array of blending weights (the method keeps them in [0, 1]).

        Returns
        -------
        (N, 3) float64 vertex positions, mm.
        """
        a = np.asarray(alpha, dtype=np.float64)
        if a.shape != (self.n_blendshapes,):
            raise ValueError(f"alpha must have shape ({self.n_blendshapes},), got {a.shape}")
        if not np.isfinite(a).all():
            raise ValueError("alpha has NaN or infinite values")
        return self.vertices + np.tensordot(a, self.blendshapes, axes=1)

    def mesh(self, alpha=None):
        """The template (or P(alpha)) as a :class:`facecorr.mesh.Mesh`."""
        from ..geometry.mesh import Mesh

        v = self.vertices if alpha is None else self.expression(alpha)
        return Mesh(v, self.faces, source="template")


# ----------------------------------------------------------------------------------------------
# building


def _edges(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unique undirected edges (E, 2) of a triangle list and how many faces use each (E,)."""
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    e = np.sort(e, axis=1)
    return np.unique(e, axis=0, return_counts=True)


def _adjacency(n: int, edges: np.ndarray) -> sp.csr_matrix:
    a = sp.coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n, n))
    return (a + a.T).tocsr()


def _components_within(adj: sp.csr_matrix, mask: np.ndarray) -> np.ndarray:
    """Component label of each vertex of ``mask`` in the subgraph induced by it (-1 outside).

    Labels are ordered by decreasing component size (0 = largest), ties by smallest vertex id.
    """
    ids = np.flatnonzero(mask)
    sub = adj[ids][:, ids]
    _, lab = connected_components(sub, directed=False)
    sizes = np.bincount(lab)
    first = np.full(len(sizes), len(ids))
    np.minimum.at(first, lab, np.arange(len(ids)))
    order = np.lexsort((first, -sizes))
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    out = np.full(len(mask), -1, dtype=np.int64)
    out[ids] = rank[lab]
    return out


def _boundary_loops(faces: np.ndarray, vertices: np.ndarray, ibug68: np.ndarray) -> dict:
    """Ordered boundary loops, named by what they surround."""
    edges, counts = _edges(faces)
    if counts.max() > 2:
        raise RuntimeError("template cut is not edge-manifold")
    bedges = edges[counts == 1]
    nbr: dict[int, list[int]] = {}
    for a, b in bedges.tolist():
        nbr.setdefault(a, []).append(b)
        nbr.setdefault(b, []).append(a)
    if any(len(v) != 2 for v in nbr.values()):
        raise RuntimeError("template boundary has a vertex on more than one loop")
    loops = []
    seen: set[int] = set()
    for start in sorted(nbr):
        if start in seen:
            continue
        loop, prev, cur = [start], -1, start
        seen.add(start)
        while True:
            a, b = nbr[cur]
            nxt = a if a != prev else b
            if nxt == start:
                break
            loop.append(nxt)
            seen.add(nxt)
            prev, cur = cur, nxt
        loops.append(np.array(loop, dtype=np.int64))
    if len(loops) != len(BOUNDARY_LOOP_NAMES):
        raise RuntimeError(f"expected {len(BOUNDARY_LOOP_NAMES)} boundary loops {BOUNDARY_LOOP_NAMES}, "
                           f"found {len(loops)}")
    # Name each loop by the nearest landmark group to its centroid; the outer one is the longest.
    lengths = [np.linalg.norm(np.diff(vertices[np.r_[l, l[:1]]], axis=0), axis=1).sum() for l in loops]
    outer = int(np.argmax(lengths))
    anchors = {
        "right_eye": vertices[ibug68[36:42]].mean(0),
        "left_eye": vertices[ibug68[42:48]].mean(0),
        "mouth": vertices[ibug68[60:68]].mean(0),
        "right_nostril": vertices[ibug68[[31, 33]]].mean(0),
        "left_nostril": vertices[ibug68[[33, 35]]].mean(0),
    }
    named = {"outer": loops[outer]}
    for name, p in anchors.items():
        d = [np.inf if i == outer or any(l is x for x in named.values()) else
             np.linalg.norm(vertices[l].mean(0) - p) for i, l in enumerate(loops)]
        named[name] = loops[int(np.argmin(d))]
    return named


def _vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    a, b, c = (vertices[faces[:, k]] for k in range(3))
    fn = np.cross(b - a, c - a)
    n = np.zeros_like(vertices)
    for k in range(3):
        np.add.at(n, faces[:, k], fn)
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)


def _regions(vertices: np.ndarray, faces: np.ndarray, adj: sp.csr_matrix, ibug68: np.ndarray,
             jaw_displacement: np.ndarray) -> np.ndarray:
    x, y = vertices[:, 0], vertices[:, 1]
    lip = vertices[ibug68[48:60]]
    right_corner, left_corner = vertices[ibug68[48]], vertices[ibug68[54]]
    top, bottom = vertices[ibug68[51]], vertices[ibug68[57]]
    cx = 0.5 * (right_corner[0] + left_corner[0])
    cy = 0.5 * (top[1] + bottom[1])
    a = 0.5 * (left_corner[0] - right_corner[0]) + MOUTH_MARGIN_X
    b = 0.5 * (top[1] - bottom[1]) + MOUTH_MARGIN_Y
    if cy + b >= vertices[ibug68[33], 1]:
        raise RuntimeError("mouth region would reach above the subnasal point")
    del lip
    mouth = ((x - cx) / a) ** 2 + ((y - cy) / b) ** 2 <= 1.0
    jaw_mag = np.linalg.norm(jaw_displacement, axis=1)
    facing = _vertex_normals(vertices, faces)[:, 2] >= CHIN_MIN_NORMAL_Z
    chin = (jaw_mag >= CHIN_JAW_FRACTION * jaw_mag.max()) & facing & ~mouth & (y < bottom[1])
    labels = np.full(len(vertices), UPPER, dtype=np.int8)
    labels[chin] = CHIN
    labels[mouth] = MOUTH
    # Majority smoothing over 1-rings: the thin radial triangles around the lips otherwise give
    # the vertex-wise ellipse test a saw-tooth edge (ties keep the vertex's own label).
    ring = adj + sp.identity(len(vertices), format="csr")
    for _ in range(REGION_SMOOTHING_PASSES):
        onehot = np.eye(len(REGION_NAMES))[labels]
        votes = ring @ onehot + 0.5 * onehot
        labels = votes.argmax(axis=1).astype(np.int8)
    # Make every region one connected piece: islands go to the region most of their
    # neighbours belong to (repeat until stable; it converges in a couple of passes).
    for _ in range(10):
        changed = False
        for r in range(len(REGION_NAMES)):
            comp = _components_within(adj, labels == r)
            for c in range(1, comp.max() + 1):
                island = np.flatnonzero(comp == c)
                nb = adj[island].indices
                nb_labels = labels[nb][labels[nb] != r]
                labels[island] = np.bincount(nb_labels, minlength=3).argmax()
                changed = True
        if not changed:
            break
    return labels


def _rings_from_outer_boundary(faces: np.ndarray, n: int) -> np.ndarray:
    """(n,) edge hops from each vertex to the longest boundary loop of ``faces`` (inf if apart)."""
    from scipy.sparse.csgraph import dijkstra

    edges, counts = _edges(faces)
    bedges = edges[counts == 1]
    _, loop_label = connected_components(_adjacency(n, bedges), directed=False)
    bverts = np.unique(bedges)
    labels, sizes = np.unique(loop_label[bverts], return_counts=True)
    outer = bverts[loop_label[bverts] == labels[np.argmax(sizes)]]
    return dijkstra(_adjacency(n, edges), indices=outer, unweighted=True, min_only=True)


def visible_points(vertices, faces, points, rotation, tol=0.5) -> np.ndarray:
    """(P,) bool: whether each point (on or near the surface) is unoccluded in the view.

    A point is hidden when a triangle covering its projection lies more than ``tol`` mm nearer
    the viewer (a depth test, not a normal test: in a side view symmetric points project onto
    each other). ``rotation`` (3, 3) takes model to view coordinates, the viewer on +z (as in
    :func:`facecorr.render.draw_mesh`); the projection is orthographic.
    """
    v = np.asarray(vertices, float) @ np.asarray(rotation).T
    p = np.asarray(points, float) @ np.asarray(rotation).T
    tri = v[np.asarray(faces)]
    lo, hi = tri[:, :, :2].min(axis=1), tri[:, :, :2].max(axis=1)
    out = np.ones(len(p), bool)
    for i, q in enumerate(p):
        cand = np.flatnonzero((lo[:, 0] <= q[0]) & (q[0] <= hi[:, 0]) & (lo[:, 1] <= q[1]) & (q[1] <= hi[:, 1]))
        if len(cand) == 0:
            continue
        a, b, c = tri[cand, 0], tri[cand, 1], tri[cand, 2]
        e1, e2, w = (b - a)[:, :2], (c - a)[:, :2], q[:2] - a[:, :2]
        det = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
        ok = np.abs(det) > 1e-12
        det = np.where(ok, det, 1.0)
        s_ = (w[:, 0] * e2[:, 1] - w[:, 1] * e2[:, 0]) / det
        t_ = (e1[:, 0] * w[:, 1] - e1[:, 1] * w[:, 0]) / det
        cover = ok & (s_ >= 0) & (t_ >= 0) & (s_ + t_ <= 1)
        depth = a[cover, 2] + s_[cover] * (b - a)[cover, 2] + t_[cover] * (c - a)[cover, 2]
        out[i] = not (depth > q[2] + tol).any()
    return out


def _nostril_interiors(vertices: np.ndarray, faces: np.ndarray, ibug68: np.ndarray) -> np.ndarray:
    """(N,) bool: the nostril tubes, which no face scanner sees.

    A vertex near the nose is *seen* from a view when it is unoccluded and not at grazing
    incidence (cos > 0.17, as a structured-light scanner); views are horizontal-ish (yaw -60..60
    in 30 deg steps, pitch 0 and 15 deg from below), like a stereo-pod scanner's cameras. The
    unseen vertices form one piece inside each nostril; pieces of >= 20 vertices are returned.
    """
    from ..geometry.transforms import view_rotation

    x, y = vertices[:, 0], vertices[:, 1]
    alae = vertices[ibug68[[31, 35]]]
    used = np.zeros(len(vertices), bool)
    used[faces.ravel()] = True
    box = used & ((x > alae[0, 0] - 12) & (x < alae[1, 0] + 12) & (y > vertices[ibug68[33], 1] - 10)
                  & (y < vertices[ibug68[30], 1] + 15))
    ids = np.flatnonzero(box)
    near = box[faces].any(axis=1)  # the occluders of the nostrils are nose triangles
    normals = _vertex_normals(vertices, faces)
    seen = np.zeros(len(ids), bool)
    for yaw in (-60, -30, 0, 30, 60):
        for pitch in (0, -15):
            r = view_rotation(yaw, pitch)
            facing = (normals[ids] @ r.T)[:, 2] > 0.17
            seen |= facing & visible_points(vertices, faces[near], vertices[ids], r)
    hidden = np.zeros(len(vertices), bool)
    hidden[ids[~seen]] = True
    comp = _components_within(_adjacency(len(vertices), _edges(faces)[0]), hidden)
    sizes = np.bincount(comp[comp >= 0])
    return np.isin(comp, np.flatnonzero(sizes >= 20))


def _clean_cut(keep_face: np.ndarray, tris: np.ndarray, n: int) -> np.ndarray:
    """Tidy a face selection into one edge-manifold piece with simple boundary loops.

    Repeats until stable: drop triangles with two or three boundary edges (spikes a cut through
    the mesh leaves), drop the triangles around vertices where two boundary loops touch, keep
    the largest edge-connected piece.
    """
    keep = keep_face.copy()
    for _ in range(100):
        before = keep.sum()
        idx = np.flatnonzero(keep)
        f = tris[idx]
        e = np.sort(np.stack([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]], axis=1), axis=2)
        uniq, inv, counts = np.unique(e.reshape(-1, 2), axis=0, return_inverse=True, return_counts=True)
        on_boundary = counts[inv.reshape(-1, 3)] == 1
        keep[idx[on_boundary.sum(axis=1) >= 2]] = False
        bedges = uniq[counts == 1]
        bdeg = np.bincount(bedges.ravel(), minlength=n)
        pinch = bdeg > 2
        keep[idx[pinch[f].any(axis=1)]] = False
        used = np.zeros(n, bool)
        used[tris[keep].ravel()] = True
        comp = _components_within(_adjacency(n, _edges(tris[keep])[0]), used)
        keep &= (comp[tris] == 0).all(axis=1)
        if keep.sum() == before:
            return keep
    raise RuntimeError("template cut did not converge to a clean boundary")


def blendshape_cosine(blendshapes: np.ndarray) -> np.ndarray:
    """(K, K) cosine similarity of the flattened displacement fields (K, N, 3)."""
    d = blendshapes.reshape(len(blendshapes), -1).astype(np.float64)
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    return d @ d.T


def build_template(model_path: str | Path = ICT_MODEL_PATH) -> dict[str, np.ndarray]:
    """Cut the template from the ICT model (deterministic).

    Returns
    -------
    dict of arrays, the content of ``template.npz`` (see :class:`Template` for the meaning).
    """
    m = np.load(model_path)
    neutral = m["neutral"].astype(np.float64)
    tris = m["triangles"].astype(np.int64)
    inside = m["narrow_face"].astype(bool)
    names = [str(s) for s in m["expression_names"]]

    inside &= _rings_from_outer_boundary(tris[inside[tris].all(axis=1)], len(neutral)) >= PEEL_RINGS
    inside &= ~_nostril_interiors(neutral, tris[inside[tris].all(axis=1)], m["landmarks68"].astype(np.int64))
    keep_face = _clean_cut(inside[tris].all(axis=1), tris, len(neutral))

    ict_vertex = np.unique(tris[keep_face].ravel())
    to_template = np.full(len(neutral), -1, dtype=np.int64)
    to_template[ict_vertex] = np.arange(len(ict_vertex))
    faces = to_template[tris[keep_face]]
    face_map = np.full(len(tris), -1, dtype=np.int64)
    face_map[np.flatnonzero(keep_face)] = np.arange(len(faces))
    vertices = neutral[ict_vertex]

    ibug68 = to_template[m["landmarks68"].astype(np.int64)]
    landmark_ids = ibug68[list(LANDMARK_IBUG68)]
    if (landmark_ids < 0).any():
        raise RuntimeError("a method landmark lies outside the template")

    expr = m["expression"]
    blend = []
    for _, recipe in BLENDSHAPE_RECIPES:
        field = np.zeros_like(vertices)
        for src, w in recipe.items():
            field += w * expr[names.index(src)][ict_vertex].astype(np.float64)
        blend.append(field)
    blend = np.stack(blend)
    cos = blendshape_cosine(blend)
    off = cos[~np.eye(len(cos), dtype=bool)]
    if off.max() >= MAX_BLENDSHAPE_COSINE or off.min() <= MIN_BLENDSHAPE_COSINE:
        raise RuntimeError(f"redundant blendshapes: cosines {off.min():.3f}..{off.max():.3f}")

    adj = _adjacency(len(vertices), _edges(faces)[0])
    regions = _regions(vertices, faces, adj, ibug68, blend[[n for n, _ in BLENDSHAPE_RECIPES].index("jawOpen")])
    loops = _boundary_loops(faces, vertices, ibug68)

    out = {
        "format_version": np.int32(_FORMAT_VERSION),
        "vertices": vertices.astype(np.float32),
        "faces": faces.astype(np.int32),
        "blendshapes": blend.astype(np.float32),
        "blendshape_names": np.array([n for n, _ in BLENDSHAPE_RECIPES]),
        "blendshape_cosine": cos.astype(np.float32),
        "regions": regions.astype(np.int8),
        "region_names": np.array(REGION_NAMES),
        "ibug68": ibug68.astype(np.int32),
        "landmark_ids": landmark_ids.astype(np.int32),
        "landmark_names": np.array(LANDMARK_NAMES),
        "graph_edges": np.array(GRAPH_EDGES, dtype=np.int32),
        "ict_vertex": ict_vertex.astype(np.int32),
        "ict_face_to_template_face": face_map.astype(np.int32),
    }
    for name, loop in loops.items():
        out[f"boundary_{name}"] = loop.astype(np.int32)
    return out


def save_template(path: str | Path = TEMPLATE_PATH, model_path: str | Path = ICT_MODEL_PATH) -> dict:
    """Build the template and write it to ``path`` (compressed npz). Returns the arrays."""
    from ..io.atomic import atomic_path

    arrays = build_template(model_path)
    with atomic_path(path) as tmp:
        np.savez_compressed(tmp, **arrays)
    return arrays


def _readonly(a: np.ndarray) -> np.ndarray:
    a = np.ascontiguousarray(a)
    a.flags.writeable = False
    return a


def template_from_arrays(d) -> Template:
    """A :class:`Template` from the arrays of :func:`build_template` (or an opened npz)."""
    if int(d["format_version"]) != _FORMAT_VERSION:
        raise RuntimeError(f"template.npz has format {int(d['format_version'])}, expected {_FORMAT_VERSION}")
    vertices = d["vertices"].astype(np.float64)
    landmark_ids = d["landmark_ids"].astype(np.int64)
    loops = {n: _readonly(d[f"boundary_{n}"].astype(np.int64)) for n in BOUNDARY_LOOP_NAMES}
    boundary = np.sort(np.concatenate(list(loops.values())))
    return Template(
        vertices=_readonly(vertices),
        faces=_readonly(d["faces"].astype(np.int64)),
        blendshapes=_readonly(d["blendshapes"].astype(np.float64)),
        blendshape_names=tuple(str(s) for s in d["blendshape_names"]),
        blendshape_cosine=_readonly(d["blendshape_cosine"].astype(np.float64)),
        regions=_readonly(d["regions"].astype(np.int8)),
        boundary=_readonly(boundary),
        boundary_loops=loops,
        landmark_ids=_readonly(landmark_ids),
        ibug68=_readonly(d["ibug68"].astype(np.int64)),
        graph_points=_readonly(vertices[landmark_ids]),
        graph_edges=_readonly(d["graph_edges"].astype(np.int64)),
        ict_vertex=_readonly(d["ict_vertex"].astype(np.int64)),
        ict_face_to_template_face=_readonly(d["ict_face_to_template_face"].astype(np.int64)),
    )


@lru_cache(maxsize=1)
def load_template() -> Template:
    """The packaged template (``data/template.npz``), loaded once and cached."""
    with np.load(TEMPLATE_PATH) as d:
        return template_from_arrays(d)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m facecorr.template", description=__doc__.splitlines()[0])
    p.add_argument("--build", action="store_true", help=f"rebuild {TEMPLATE_PATH.name} from the ICT model")
    p.add_argument("-o", "--out", default=str(TEMPLATE_PATH), help="output path (default: the packaged file)")
    args = p.parse_args(argv)
    if not args.build:
        p.print_help()
        return 0
    arrays = save_template(args.out)
    cos = arrays["blendshape_cosine"]
    off = cos[~np.eye(len(cos), dtype=bool)]
    counts = np.bincount(arrays["regions"], minlength=3)
    print(f"wrote {args.out}: {len(arrays['vertices'])} vertices, {len(arrays['faces'])} faces, "
          f"{len(arrays['blendshapes'])} blendshapes (cosine {off.min():.2f}..{off.max():.2f}), "
          + ", ".join(f"{n} {c}" for n, c in zip(REGION_NAMES, counts)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
