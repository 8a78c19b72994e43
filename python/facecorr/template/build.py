"""The template builder: cut the packaged ``data/template.npz`` from the vendored ICT model.

:func:`build_template` is deterministic; ``python -m facecorr.template.build`` writes its result
to the packaged file (:func:`save_template`). What is cut and why (crop rings, nostril tubes,
regions, blendshape recipes and their cosines) is in the :mod:`facecorr.template` package
docstring. All lengths are millimetres in the ICT model frame (+y up, +z out of the face).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from .. import _core
from ..geometry.mesh import Mesh
from ..geometry.transforms import view_rotation
from ..names import LANDMARK_IBUG68, LANDMARK_NAMES
from .model import (
    _FORMAT_VERSION, BOUNDARY_LOOP_NAMES, CHIN, GRAPH_EDGES, ICT_MODEL_PATH, MOUTH, REGION_NAMES,
    TEMPLATE_PATH, UPPER,
)

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

# The crop: vertex rings peeled off the narrow face's outer boundary (package docstring).
PEEL_RINGS = 8

# Region geometry (mm), see the package docstring.
MOUTH_MARGIN_X = 10.0
MOUTH_MARGIN_Y = 7.0
CHIN_JAW_FRACTION = 0.35
CHIN_MIN_NORMAL_Z = 0.5  # cos 60 deg: the chin region is what a frontal scanner sees
REGION_SMOOTHING_PASSES = 3


def _edges(faces: np.ndarray, n: int) -> np.ndarray:
    """(E, 2) int64 unique undirected edges (i < j, lexicographic) of ``faces`` (M, 3) over ``n``
    vertices: the compiled kernel behind :attr:`facecorr.geometry.mesh.Mesh.edges`."""
    return _core.mesh_edges(np.ascontiguousarray(faces, dtype=np.int64), n)


def _boundary_edges(faces: np.ndarray) -> tuple[np.ndarray, int]:
    """(B, 2) int64 edges used by exactly one triangle of ``faces`` (M, 3), lexicographic, and the
    largest number of triangles sharing one edge (2 on an edge-manifold mesh).

    :class:`~facecorr.geometry.mesh.Mesh` has boundary *vertices* but no per-edge use count, so
    this one stays here.
    """
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    e = np.sort(e, axis=1)
    edges, counts = np.unique(e, axis=0, return_counts=True)
    return edges[counts == 1], int(counts.max())


def _vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(N, 3) unit area-weighted vertex normals (0 for vertices in no triangle), as
    :attr:`facecorr.geometry.mesh.Mesh.vertex_normals` (the compiled kernel)."""
    return Mesh(vertices, faces).vertex_normals


def _adjacency(n: int, edges: np.ndarray) -> sp.csr_matrix:
    """(n, n) symmetric CSR vertex adjacency (1 per edge) of unique edges (E, 2)."""
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
    """Ordered boundary loops of the cut, named by what they surround.

    Parameters: faces (M, 3), vertices (N, 3) mm, ibug68 (68,) template vertex ids.
    Returns: dict BOUNDARY_LOOP_NAMES name -> (n,) int64 vertex ids, in loop order.
    """
    bedges, max_use = _boundary_edges(faces)
    if max_use > 2:
        raise RuntimeError("template cut is not edge-manifold")
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


def _regions(vertices: np.ndarray, faces: np.ndarray, adj: sp.csr_matrix, ibug68: np.ndarray,
             jaw_displacement: np.ndarray) -> np.ndarray:
    """(N,) int8 region label (index into REGION_NAMES) of each vertex (package docstring).

    Parameters: vertices (N, 3) mm, faces (M, 3), adj (N, N) vertex adjacency, ibug68 (68,)
    template vertex ids, jaw_displacement (N, 3) mm (the jawOpen field).
    """
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

    bedges, _ = _boundary_edges(faces)
    _, loop_label = connected_components(_adjacency(n, bedges), directed=False)
    bverts = np.unique(bedges)
    labels, sizes = np.unique(loop_label[bverts], return_counts=True)
    outer = bverts[loop_label[bverts] == labels[np.argmax(sizes)]]
    return dijkstra(_adjacency(n, _edges(faces, n)), indices=outer, unweighted=True, min_only=True)


def visible_points(vertices, faces, points, rotation, tol=0.5) -> np.ndarray:
    """(P,) bool: whether each point (on or near the surface) is unoccluded in the view.

    A point is hidden when a triangle covering its projection lies more than ``tol`` mm nearer
    the viewer (a depth test, not a normal test: in a side view symmetric points project onto
    each other). ``rotation`` (3, 3) takes model to view coordinates, the viewer on +z (as in
    :func:`facecorr.render.draw_mesh`); the projection is orthographic.

    Parameters: vertices (N, 3) mm, faces (M, 3), points (P, 3) mm, rotation (3, 3), tol mm.

    This exact per-point test is kept rather than a depth buffer from
    :func:`facecorr.geometry.raster.rasterize`: sampling the buffer at each point's pixel
    disagrees on a few silhouette points per view at every pixel size tried (0.25, 0.1,
    0.05 mm) and changes which nostril vertices the build drops, i.e. ``template.npz``.
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

    Parameters: vertices (N, 3) mm, faces (M, 3) (the narrow face after the ring peel), ibug68
    (68,) ICT vertex ids of the iBUG-68 points.
    """
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
    comp = _components_within(_adjacency(len(vertices), _edges(faces, len(vertices))), hidden)
    sizes = np.bincount(comp[comp >= 0])
    return np.isin(comp, np.flatnonzero(sizes >= 20))


def _clean_cut(keep_face: np.ndarray, tris: np.ndarray, n: int) -> np.ndarray:
    """Tidy a face selection into one edge-manifold piece with simple boundary loops.

    Parameters: keep_face (F,) bool over ``tris`` (F, 3), n = number of vertices.
    Returns: (F,) bool, the tidied selection.

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
        comp = _components_within(_adjacency(n, _edges(tris[keep], n)), used)
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

    Parameters
    ----------
    model_path : the vendored ICT model npz (``neutral`` (V, 3) mm, ``triangles`` (F, 3),
        ``narrow_face`` (V,) bool, ``landmarks68`` (68,), ``expression`` (53, V, 3) mm,
        ``expression_names`` (53,)).

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

    adj = _adjacency(len(vertices), _edges(faces, len(vertices)))
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


def main(argv=None) -> int:
    """``python -m facecorr.template.build [--out PATH]``: rebuild the packaged template."""
    p = argparse.ArgumentParser(
        prog="python -m facecorr.template.build",
        description=f"rebuild {TEMPLATE_PATH.name} from the ICT model (deterministic)")
    p.add_argument("-o", "--out", default=str(TEMPLATE_PATH), help="output path (default: the packaged file)")
    args = p.parse_args(argv)
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
