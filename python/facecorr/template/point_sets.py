"""Point sets defined on the template, read off every registered scan.

A lab's own landmark set (83-point BU-3DFE style, ...) is a JSON object ``{name: definition}``
where a definition is a template vertex id (an int) or a point inside a template triangle,
``{"face": triangle id, "bary": [b0, b1, b2]}`` (barycentric weights, summing to 1). Because every
registered scan has the template's vertex order, the same definition gives the same anatomical
point on each of them.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import FacecorrError


@dataclass(frozen=True)
class PointSet:
    """names (P,); corners (P, 3) template vertex ids; weights (P, 3) barycentric weights."""

    names: tuple
    corners: np.ndarray
    weights: np.ndarray

    def on(self, vertices) -> dict:
        """name -> (3,) position of each point on ``vertices`` (N, 3) (template vertex order)."""
        v = np.asarray(vertices, dtype=np.float64)
        pts = np.einsum("pk,pkd->pd", self.weights, v[self.corners])
        return dict(zip(self.names, pts))


def read_point_set(path, template) -> PointSet:
    """Read and check a point-set JSON (module docstring) against ``template``; FacecorrError with
    one line naming the file and the point on any problem."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError) as e:
        raise FacecorrError(f"{path}: not a point-set JSON ({type(e).__name__}: {e})") from None
    if not isinstance(data, dict) or not data:
        raise FacecorrError(f"{path}: a point set is a non-empty JSON object {{name: definition}}")
    faces = np.asarray(template.faces)
    names, corners, weights = [], [], []
    for name, d in data.items():
        if isinstance(d, int) and not isinstance(d, bool):
            if not 0 <= d < template.n_vertices:
                raise FacecorrError(f"{path}: {name}: vertex id {d} outside [0, {template.n_vertices - 1}]")
            c, w = [d, d, d], [1.0, 0.0, 0.0]
        elif isinstance(d, dict) and isinstance(d.get("face"), int) and isinstance(d.get("bary"), list):
            f, b = d["face"], d["bary"]
            if not 0 <= f < len(faces):
                raise FacecorrError(f"{path}: {name}: face id {f} outside [0, {len(faces) - 1}]")
            try:
                w = [float(x) for x in b]
            except (TypeError, ValueError):
                w = []
            if len(w) != 3 or not np.isfinite(w).all() or min(w) < -1e-9 or abs(sum(w) - 1.0) > 1e-6:
                raise FacecorrError(f"{path}: {name}: bary must be 3 weights >= 0 summing to 1, got {b!r}")
            c = faces[f].tolist()
        else:
            raise FacecorrError(f"{path}: {name}: a definition is a vertex id or "
                                f"{{\"face\": id, \"bary\": [b0, b1, b2]}}, got {d!r}")
        names.append(str(name))
        corners.append(c)
        weights.append(w)
    return PointSet(tuple(names), np.asarray(corners, dtype=np.int64), np.asarray(weights, dtype=np.float64))
