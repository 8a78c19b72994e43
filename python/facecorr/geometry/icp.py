"""Trimmed point-to-plane ICP of a point set onto a mesh surface, many starts at once (Rust,
``rust/src/icp.rs``): the pose search's fits (:mod:`facecorr.landmarks.pose`) and the registration's
mouth search (:mod:`facecorr.registration.mouth`)."""

from __future__ import annotations

import numpy as np

from .. import _core


def surface_icp(points: np.ndarray, surface, starts, iters: int = 20, keep: float = 0.8, tol: float = 1e-5,
                prev=None, return_prev: bool = False) -> list:
    """:func:`facecorr.landmarks.pose.trimmed_icp` (point-to-plane) of ``points`` (P, 3) onto a mesh's ``surface``
    (:attr:`facecorr.geometry.mesh.Mesh.surface`: its vertices and unit vertex normals) from every
    start (R, t) at once: the Rust kernel of ``rust/src/icp.rs``, the starts in parallel.

    The same method as ``landmarks.pose.trimmed_icp`` with ``normals``, its reference; they agree to
    rounding (the trimmed set is selected, not sorted, and the 6x6 step solved by Cholesky, not
    lstsq; ``tests/test_pose.py``). Why: a 2000-point numpy ICP iteration spends as long in
    Python overhead as in its nearest-neighbour query. Returns [(R (3, 3), t (3,), trimmed RMS mm,
    distances (P,) mm), ...], one per start; with ``return_prev`` each also ends with its ``prev``
    (the trimmed RMS before the last step, mm): passed back as ``prev`` (one per start) with the
    returned poses as starts, a run goes on bitwise as if it had not stopped after ``iters``.
    """
    if len(starts) == 0:
        return []
    rs = np.array([np.asarray(r, dtype=np.float64) for r, _ in starts]).reshape(-1, 3, 3)
    ts = np.array([np.asarray(t, dtype=np.float64) for _, t in starts]).reshape(-1, 3)
    pv = None if prev is None else np.ascontiguousarray(prev, dtype=np.float64)
    r_out, t_out, rms, d, _, prev_out = _core.trimmed_icp(surface, np.ascontiguousarray(points, dtype=np.float64), rs,
                                                          ts, int(iters), float(keep), float(tol), pv)
    if return_prev:
        return [(r_out[k], t_out[k], float(rms[k]), d[k], float(prev_out[k])) for k in range(len(rs))]
    return [(r_out[k], t_out[k], float(rms[k]), d[k]) for k in range(len(rs))]
