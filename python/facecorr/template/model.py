"""The template's data model: :class:`Template`, the npz it is stored in and its loader.

See the :mod:`facecorr.template` package docstring for the frame (mm, +y up, +z out of the
face, subject's right at -x) and for how the content is built (:mod:`facecorr.template.build`).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from ..names import LANDMARK_NAMES

DATA_DIR = Path(__file__).resolve().parent.parent / "data"
ICT_MODEL_PATH = DATA_DIR / "ict" / "ict_face_model.npz"
TEMPLATE_PATH = DATA_DIR / "template.npz"

#: Per-vertex region labels, in this order (``Template.regions`` holds indices into it).
REGION_NAMES = ("upper", "chin", "mouth")
UPPER, CHIN, MOUTH = 0, 1, 2

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
        """The template (or P(alpha), ``alpha`` (K,)) as a :class:`facecorr.geometry.mesh.Mesh` (mm)."""
        from ..geometry.mesh import Mesh

        v = self.vertices if alpha is None else self.expression(alpha)
        return Mesh(v, self.faces, source="template")


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


def _inside_polygon(points: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """(P,) bool: even-odd test of 2D ``points`` (P, 2) against a closed ``polygon`` (L, 2)."""
    x, y = points[:, 0][:, None], points[:, 1][:, None]
    a, b = polygon, np.roll(polygon, -1, axis=0)
    crosses = (a[:, 1] > y) != (b[:, 1] > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        x_at = a[:, 0] + (y - a[:, 1]) * (b[:, 0] - a[:, 0]) / (b[:, 1] - a[:, 1])
    return (crosses & (x < x_at)).sum(axis=1) % 2 == 1


@lru_cache(maxsize=4)
def eye_caps(template: Template, stride: int = 3) -> dict:
    """The front of each eyeball as the template's eye hole shows it, template frame (mm).

    The ICT model's own eyeballs (``eyeball_right``/``eyeball_left`` of the packaged ICT model,
    the frame the template is cut in): the vertices of the eyeball's front half that lie inside
    the eye's boundary loop seen from the front (+z) and at least 1 mm from it, every
    ``stride``-th. Used by the eye search (:mod:`facecorr.registration.eyes`) as the recessed dome
    the lids close around.

    Returns
    -------
    dict "right_eye" / "left_eye" -> (C, 3) float64; empty if the template is not cut from the
    packaged ICT model's neutral face (its vertices differ from it by more than 1e-3 mm).
    """
    v = np.asarray(template.vertices, float)
    iv = np.asarray(template.ict_vertex)
    with np.load(ICT_MODEL_PATH) as d:
        neutral, part_id, parts = d["neutral"], d["part_id"], [str(s) for s in d["part_names"]]
    if len(iv) != len(v) or iv.max(initial=-1) >= len(neutral) or np.abs(neutral[iv] - v).max() > 1e-3:
        return {}
    out = {}
    for name in ("right_eye", "left_eye"):
        loop = np.asarray(template.boundary_loops.get(name, ()), dtype=np.int64)
        part = "eyeball_" + name.split("_")[0]
        if len(loop) < 3 or part not in parts:
            continue
        ball = neutral[part_id == parts.index(part)].astype(np.float64)
        front = ball[ball[:, 2] > np.median(ball[:, 2])]
        ring = v[loop]
        gap = np.sqrt(((front[:, None, :2] - ring[None, :, :2]) ** 2).sum(-1)).min(axis=1)
        keep = _inside_polygon(front[:, :2], ring[:, :2]) & (gap >= 1.0)
        out[name] = np.ascontiguousarray(front[keep][::stride])
    return out
