"""Rigid and similarity transforms: the one Kabsch/Umeyama fit and the rotation helpers.

Conventions: points are rows ((n, 3) arrays), a transform maps ``x -> R x + t`` (or ``s R x + t``),
and a 3x4 matrix ``[M | t]`` maps ``x -> M x + t``. Angles are radians unless a name says degrees.
"""

from __future__ import annotations

import numpy as np


def kabsch(source, target, *, allow_reflection: bool = False, with_scale: bool = False):
    """Least-squares fit of ``x -> s R x + t`` taking source (n, d) onto target (n, d).

    Kabsch (rigid, ``with_scale=False``, s = 1) or Umeyama 1991 (similarity, ``with_scale=True``).
    ``allow_reflection`` permits det R = -1 (an orthogonal Procrustes fit, for MDS embeddings whose
    handedness is arbitrary).

    Returns
    -------
    (R (d, d), t (d,)) when ``with_scale`` is False, else (R, s, t).

    Raises
    ------
    ValueError : shapes differ or fewer than 3 points; with ``with_scale`` also coincident or
        collinear source points (the scale or the rotation is undetermined).
    """
    s = np.asarray(source, dtype=np.float64)
    d = np.asarray(target, dtype=np.float64)
    if s.shape != d.shape or s.ndim != 2 or len(s) < 3:
        raise ValueError(f"kabsch: need two (n>=3, d) arrays of equal shape, got {s.shape} and {d.shape}")
    cs, cd = s.mean(0), d.mean(0)
    a = s - cs
    u, sig, vt = np.linalg.svd(a.T @ (d - cd))
    fix = np.ones(s.shape[1])
    if not allow_reflection and np.linalg.det(vt.T @ u.T) < 0:
        fix[-1] = -1.0
    r = vt.T @ np.diag(fix) @ u.T
    if not with_scale:
        return r, cd - r @ cs
    var_s = float(np.sum(a * a)) / len(s)
    if var_s <= 1e-12:
        raise ValueError("kabsch: the source points are coincident (no scale)")
    if sig[1] <= 1e-9 * max(sig[0], 1e-300):
        raise ValueError("kabsch: the points are collinear (the rotation is undetermined)")
    scale = float(np.sum(sig * fix)) / len(s) / var_s
    return r, scale, cd - scale * r @ cs


def as_matrix(r, t, scale: float = 1.0) -> np.ndarray:
    """The 3x4 matrix ``[s R | t]``."""
    return np.hstack([scale * np.asarray(r, float), np.asarray(t, float).reshape(3, 1)])


def apply_transform(t, points) -> np.ndarray:
    """Apply a 3x4 transform to (..., 3) points."""
    t = np.asarray(t, dtype=np.float64)
    return np.asarray(points, dtype=np.float64) @ t[:, :3].T + t[:, 3]


def rotation_from_vector(omega) -> np.ndarray:
    """(3, 3) rotation of the rotation vector ``omega`` (axis * angle, radians; Rodrigues)."""
    omega = np.asarray(omega, dtype=np.float64)
    theta = float(np.linalg.norm(omega))
    if theta < 1e-15:
        return np.eye(3)
    kx = np.array([[0.0, -omega[2], omega[1]], [omega[2], 0.0, -omega[0]], [-omega[1], omega[0], 0.0]]) / theta
    return np.eye(3) + np.sin(theta) * kx + (1.0 - np.cos(theta)) * kx @ kx


def axis_angle(axis, angle: float) -> np.ndarray:
    """(3, 3) rotation by ``angle`` (radians) about ``axis`` (any length > 0)."""
    axis = np.asarray(axis, dtype=np.float64)
    n = float(np.linalg.norm(axis))
    if n == 0.0:
        return np.eye(3)
    return rotation_from_vector(axis * (float(angle) / n))


def rotation_angle(rot) -> float:
    """Angle (radians, [0, pi]) of a (3, 3) rotation."""
    return float(np.arccos(np.clip((np.trace(rot) - 1.0) / 2.0, -1.0, 1.0)))


def rotation_between(a, b) -> np.ndarray:
    """A (3, 3) rotation taking the direction of ``a`` to that of ``b``."""
    a = np.asarray(a, float) / np.linalg.norm(a)
    b = np.asarray(b, float) / np.linalg.norm(b)
    v = np.cross(a, b)
    c = float(a @ b)
    if c < -1 + 1e-9:  # opposite: rotate by pi about any axis orthogonal to a
        axis = np.cross(a, [1.0, 0, 0]) if abs(a[0]) < 0.9 else np.cross(a, [0, 1.0, 0])
        axis /= np.linalg.norm(axis)
        return 2 * np.outer(axis, axis) - np.eye(3)
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + vx + vx @ vx / (1 + c)


def view_rotation(yaw_deg: float = 0.0, pitch_deg: float = 0.0) -> np.ndarray:
    """(3, 3) rotation of face-frame points (+y up, +z towards the viewer): yaw about +y (degrees),
    then pitch about +x (degrees)."""
    y, p = np.radians(yaw_deg), np.radians(pitch_deg)
    ry = np.array([[np.cos(y), 0, np.sin(y)], [0, 1, 0], [-np.sin(y), 0, np.cos(y)]])
    rx = np.array([[1, 0, 0], [0, np.cos(p), -np.sin(p)], [0, np.sin(p), np.cos(p)]])
    return rx @ ry
