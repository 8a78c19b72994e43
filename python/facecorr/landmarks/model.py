"""The trained landmark model: one versioned ``.npz`` file (a few kB), validated on load.

Contents (L = 8 landmarks in ``facecorr.names.LANDMARK_NAMES`` order, S = number of FP radii,
E = landmark-graph edges, D = 3 PCA dimensions):

============================  ============  =====================================================
key                           shape         meaning
============================  ============  =====================================================
format_version                ()            :data:`FORMAT_VERSION`
landmark_names                (L,) str      the order of every per-landmark array
radii                         (S,)          FP geodesic-disk radii, mm
pca_mean, pca_components      (S,), (D, S)  FPPCA projection
medoids, sigma                (L, D), (L,)  class medoids and RMS spread in PCA space
ellipse_centers, ellipse_A    (L, D), (L, D, D) MVEE decision rules of the M-clusters
node_mean, node_cov           (L, S), (L, S, S) Gaussian node potentials (FP vectors)
edges                         (E, 2)        landmark-graph edges (i, j), indices into L
edge_mean, edge_cov           (E, 3), (E, 3, 3) Gaussian edge potentials: canonical x_j - x_i, mm,
                                            in the template frame (see train.py)
graph_points                  (L, 3)        landmark-graph template Pa, mm, template frame
search_radius                 (L,)          BP candidate region radius around each aligned Pa
                                            point, mm
nose_pair_mean, nose_pair_std (4, 4), (4, 4) Euclidean distances between the nose points
                                            (right subalare, left subalare, tip, subnasal), mm,
                                            left/right pooled (the sides are unknown when used)
icp_points                    (P, 3)        template upper-face points for the rigid pose ICP, mm
icp_tip_normal                (3,)          template surface normal at the nose tip
offset_mean, offset_cov       (L, 3), (L, 3, 3) Gaussian position prior: landmark minus Pa point
                                            after the ICP pose, template frame, mm
params                        () str        JSON: the scalar settings (nose search radius, MDS
                                            sample count, ...) and training provenance
============================  ============  =====================================================
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import numpy as np

from ..errors import ModelError
from ..names import LANDMARK_NAMES
from .paper.classify import Classifier

FORMAT_VERSION = 1

#: Where the packaged default model lives (inside the installed package).
DEFAULT_MODEL = "landmarks_model.npz"

#: Scalar settings with their defaults; stored in the model's ``params`` JSON.
DEFAULT_PARAMS = {
    "nose_search_radius_mm": 25.0,   # paper's r: the geodesic circle around the nose-tip start
    "subnasal_search_radius_mm": 30.0,  # the circle around the subnasal for classes 5/6
    "mds_samples": 50,               # farthest-point samples of the canonical form
    "mds_region_mm": 90.0,           # geodesic radius (around the subnasal) the samples come from
    "max_candidates": 60,            # per landmark and BP pass
    "node_ridge": 1e-4,              # added to the FP covariance diagonal (relative)
}


@dataclass
class LandmarkModel:
    """A trained model (see the module docstring for the fields)."""

    radii: np.ndarray
    classifier: Classifier
    node_mean: np.ndarray
    node_cov: np.ndarray
    edges: np.ndarray
    edge_mean: np.ndarray
    edge_cov: np.ndarray
    graph_points: np.ndarray
    search_radius: np.ndarray
    nose_pair_mean: np.ndarray
    nose_pair_std: np.ndarray
    icp_points: np.ndarray
    icp_tip_normal: np.ndarray
    offset_mean: np.ndarray
    offset_cov: np.ndarray
    params: dict = field(default_factory=dict)
    source: str | None = None

    def param(self, name: str):
        return self.params.get(name, DEFAULT_PARAMS.get(name))

    def save(self, path) -> None:
        """Write the model atomically (a complete file or none)."""
        from ..io.atomic import atomic_path

        c = self.classifier
        arrays = dict(
            format_version=np.int64(FORMAT_VERSION),
            landmark_names=np.array(LANDMARK_NAMES),
            radii=self.radii, pca_mean=c.mean, pca_components=c.components, medoids=c.medoids,
            sigma=c.sigma, ellipse_centers=c.ellipse_centers, ellipse_A=c.ellipse_A,
            node_mean=self.node_mean, node_cov=self.node_cov, edges=self.edges.astype(np.int64),
            edge_mean=self.edge_mean, edge_cov=self.edge_cov, graph_points=self.graph_points,
            search_radius=self.search_radius, nose_pair_mean=self.nose_pair_mean,
            nose_pair_std=self.nose_pair_std, icp_points=self.icp_points, icp_tip_normal=self.icp_tip_normal,
            offset_mean=self.offset_mean, offset_cov=self.offset_cov, params=np.array(json.dumps(self.params, sort_keys=True)),
        )
        validate_arrays(arrays, str(path))
        with atomic_path(path) as tmp:
            np.savez_compressed(tmp, **arrays)


_SHAPES = {
    "radii": ("S",), "pca_mean": ("S",), "pca_components": ("D", "S"), "medoids": ("L", "D"),
    "sigma": ("L",), "ellipse_centers": ("L", "D"), "ellipse_A": ("L", "D", "D"),
    "node_mean": ("L", "S"), "node_cov": ("L", "S", "S"), "edges": ("E", 2), "edge_mean": ("E", 3),
    "edge_cov": ("E", 3, 3), "graph_points": ("L", 3), "search_radius": ("L",),
    "nose_pair_mean": (4, 4), "nose_pair_std": (4, 4), "icp_points": ("P", 3), "icp_tip_normal": (3,),
    "offset_mean": ("L", 3), "offset_cov": ("L", 3, 3),
}


def validate_arrays(arrays: dict, name: str) -> None:
    """Raise ModelError (one line) unless the arrays form a consistent model."""
    for key in ("format_version", "landmark_names", "params", *_SHAPES):
        if key not in arrays:
            raise ModelError(f"{name}: not a facecorr landmark model (missing '{key}')")
    version = int(np.asarray(arrays["format_version"]))
    if version != FORMAT_VERSION:
        raise ModelError(f"{name}: model format version {version}, this facecorr reads version {FORMAT_VERSION}; retrain it")
    names = tuple(str(s) for s in np.asarray(arrays["landmark_names"]).tolist())
    if names != LANDMARK_NAMES:
        raise ModelError(f"{name}: the model's landmark names differ from facecorr's ({names})")
    dims = {"L": len(LANDMARK_NAMES)}
    for key, spec in _SHAPES.items():
        a = np.asarray(arrays[key])
        if a.ndim != len(spec):
            raise ModelError(f"{name}: '{key}' has {a.ndim} dimensions, expected {len(spec)}")
        for size, want in zip(a.shape, spec):
            if isinstance(want, int):
                if size != want:
                    raise ModelError(f"{name}: '{key}' has shape {a.shape}, expected {spec}")
            elif dims.setdefault(want, size) != size:
                raise ModelError(f"{name}: '{key}' has shape {a.shape}, inconsistent with {want}={dims[want]}")
        if not np.issubdtype(a.dtype, np.number) or not np.isfinite(a).all():
            raise ModelError(f"{name}: '{key}' has non-numeric, NaN or infinite values")
    edges = np.asarray(arrays["edges"])
    if edges.min() < 0 or edges.max() >= dims["L"] or (edges[:, 0] == edges[:, 1]).any():
        raise ModelError(f"{name}: 'edges' must pair distinct landmark indices in [0, {dims['L']})")
    if (np.asarray(arrays["radii"]) <= 0).any() or (np.asarray(arrays["search_radius"]) <= 0).any():
        raise ModelError(f"{name}: radii and search radii must be positive (mm)")
    off = ~np.eye(4, dtype=bool)
    if (np.asarray(arrays["nose_pair_std"])[off] <= 0).any():
        raise ModelError(f"{name}: 'nose_pair_std' must be positive off the diagonal (mm)")
    if len(np.asarray(arrays["icp_points"])) < 10:
        raise ModelError(f"{name}: 'icp_points' needs at least 10 points")
    for key in ("node_cov", "edge_cov", "ellipse_A", "offset_cov"):
        for k, m in enumerate(np.asarray(arrays[key])):
            if not np.allclose(m, m.T, rtol=1e-6, atol=1e-12) or np.linalg.eigvalsh(0.5 * (m + m.T)).min() <= 0:
                raise ModelError(f"{name}: '{key}'[{k}] is not symmetric positive definite")
    try:
        params = json.loads(str(np.asarray(arrays["params"])))
        if not isinstance(params, dict):
            raise ValueError
    except ValueError:
        raise ModelError(f"{name}: 'params' is not a JSON object") from None


def load_model(path=None) -> LandmarkModel:
    """Load and validate a model file; ``None`` = the packaged default.

    Raises
    ------
    ModelError : missing, unreadable, of another version or inconsistent (one-line message).
    """
    if path is None:
        ref = resources.files("facecorr") / "data" / DEFAULT_MODEL
        if not ref.is_file():
            raise ModelError("no packaged default landmark model; train one with `facecorr train DB --out MODEL.npz`")
        path = Path(str(ref))
    name = str(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except FileNotFoundError:
        raise ModelError(f"{name}: no such model file") from None
    except (OSError, ValueError, EOFError) as e:
        raise ModelError(f"{name}: not a readable .npz model ({type(e).__name__})") from None
    validate_arrays(arrays, name)
    clf = Classifier(mean=arrays["pca_mean"].astype(float), components=arrays["pca_components"].astype(float),
                     medoids=arrays["medoids"].astype(float), sigma=arrays["sigma"].astype(float),
                     ellipse_centers=arrays["ellipse_centers"].astype(float), ellipse_A=arrays["ellipse_A"].astype(float))
    return LandmarkModel(
        radii=arrays["radii"].astype(float), classifier=clf, node_mean=arrays["node_mean"].astype(float),
        node_cov=arrays["node_cov"].astype(float), edges=arrays["edges"].astype(np.int64),
        edge_mean=arrays["edge_mean"].astype(float), edge_cov=arrays["edge_cov"].astype(float),
        graph_points=arrays["graph_points"].astype(float), search_radius=arrays["search_radius"].astype(float),
        nose_pair_mean=arrays["nose_pair_mean"].astype(float), nose_pair_std=arrays["nose_pair_std"].astype(float),
        icp_points=arrays["icp_points"].astype(float), icp_tip_normal=arrays["icp_tip_normal"].astype(float),
        offset_mean=arrays["offset_mean"].astype(float), offset_cov=arrays["offset_cov"].astype(float),
        params=json.loads(str(arrays["params"])), source=name)
