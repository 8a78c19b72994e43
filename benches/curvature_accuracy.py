"""Accuracy of principal curvatures on noisy ~1 mm meshes: facecorr's local quadric fitting vs
Rusinkiewicz's per-face tensor averaging (numpy implementation here, for the comparison only).

Run: .venv/bin/python benches/curvature_accuracy.py   (prints a markdown table; ~20 s)

Meshes (10,242 vertices each, mean edge length printed, ~1 mm): sphere R = 27 mm (icosphere) and
ellipsoid 45 x 30 x 18 mm; isotropic Gaussian noise of sigma mm on every coordinate.
Error: median over vertices of |k_i - k_i,true| (1/mm) for i = 1, 2, averaged over 3 noise seeds.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
import ref_mesh as R  # noqa: E402

from facecorr.geometry import curvature as C  # noqa: E402
from facecorr.geometry.mesh import Mesh  # noqa: E402


def _normalize(x):
    return x / np.linalg.norm(x, axis=-1, keepdims=True)


def _rot_coord_sys(old_u, old_v, new_norm):
    """Rotate the frame (old_u, old_v) so that its normal becomes new_norm (Rusinkiewicz 2004)."""
    old_norm = np.cross(old_u, old_v)
    ndot = np.einsum("ij,ij->i", old_norm, new_norm)[:, None]
    perp_old = new_norm - ndot * old_norm
    dperp = (old_norm + new_norm) / (1 + ndot)
    new_u = old_u - dperp * np.einsum("ij,ij->i", perp_old, old_u)[:, None]
    new_v = old_v - dperp * np.einsum("ij,ij->i", perp_old, old_v)[:, None]
    flip = (ndot[:, 0] <= -1)
    new_u[flip], new_v[flip] = -old_u[flip], -old_v[flip]
    return new_u, new_v


def rusinkiewicz(V, F):
    """Per-face second fundamental form from normal differences along the 3 edges (least squares),
    rotated into each corner's vertex frame and averaged with corner-area (area / 3) weights."""
    N = Mesh(V, F).vertex_normals
    p = [V[F[:, k]] for k in range(3)]
    n = [N[F[:, k]] for k in range(3)]
    e = [p[2] - p[1], p[0] - p[2], p[1] - p[0]]
    dn = [n[2] - n[1], n[0] - n[2], n[1] - n[0]]
    t = _normalize(e[0])
    fn = _normalize(np.cross(e[0], e[1]))
    b = np.cross(fn, t)
    M = len(F)
    A = np.zeros((M, 6, 3))
    rhs = np.zeros((M, 6))
    for k in range(3):
        u, v = np.einsum("ij,ij->i", e[k], t), np.einsum("ij,ij->i", e[k], b)
        A[:, 2 * k, 0], A[:, 2 * k, 1] = u, v
        A[:, 2 * k + 1, 1], A[:, 2 * k + 1, 2] = u, v
        rhs[:, 2 * k] = np.einsum("ij,ij->i", dn[k], t)
        rhs[:, 2 * k + 1] = np.einsum("ij,ij->i", dn[k], b)
    AtA = np.einsum("mki,mkj->mij", A, A)
    Atb = np.einsum("mki,mk->mi", A, rhs)
    ef = np.linalg.solve(AtA, Atb[..., None])[..., 0]  # (M, 3): e, f, g in the face frame
    # vertex frames
    up = _normalize(np.cross(N, np.where(np.abs(N[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]])))
    vp = np.cross(N, up)
    area = 0.5 * np.linalg.norm(np.cross(e[0], e[1]), axis=1) / 3
    acc = np.zeros((len(V), 3))
    wsum = np.zeros(len(V))
    for k in range(3):
        i = F[:, k]
        # rotate the vertex frame into the face plane, then express the face tensor in it
        ru, rv = _rot_coord_sys(up[i], vp[i], fn)
        u1, v1 = np.einsum("ij,ij->i", ru, t), np.einsum("ij,ij->i", ru, b)
        u2, v2 = np.einsum("ij,ij->i", rv, t), np.einsum("ij,ij->i", rv, b)
        ku, kuv, kv = ef[:, 0], ef[:, 1], ef[:, 2]
        nku = ku * u1 * u1 + 2 * kuv * u1 * v1 + kv * v1 * v1
        nkuv = ku * u1 * u2 + kuv * (u1 * v2 + u2 * v1) + kv * v1 * v2
        nkv = ku * u2 * u2 + 2 * kuv * u2 * v2 + kv * v2 * v2
        np.add.at(acc, i, area[:, None] * np.stack([nku, nkuv, nkv], 1))
        np.add.at(wsum, i, area)
    acc /= wsum[:, None]
    H = 0.5 * (acc[:, 0] + acc[:, 2])
    disc = np.sqrt(np.maximum(0.25 * (acc[:, 0] - acc[:, 2]) ** 2 + acc[:, 1] ** 2, 0))
    return H + disc, H - disc


def truth(name, V):
    if name == "sphere":
        return np.full(len(V), 1 / 27), np.full(len(V), 1 / 27)
    K, H = R.ellipsoid_curvature(V, 45, 30, 18)
    d = np.sqrt(np.maximum(H * H - K, 0))
    return H + d, H - d


def main():
    shapes = {"sphere": R.sphere(27.0, 5), "ellipsoid": R.ellipsoid(45, 30, 18, 5)}
    methods = {
        "Rusinkiewicz (1-ring tensor)": lambda V, F: rusinkiewicz(V, F),
        "quadric fit, 2 rings (default)": lambda V, F: C.principal_curvatures(V, F)[:2],
        "quadric fit, radius 3 mm": lambda V, F: C.principal_curvatures(V, F, radius=3.0)[:2],
    }
    sigmas = (0.0, 0.05, 0.1, 0.2)
    for name, (V, F) in shapes.items():
        e = Mesh(V, F).edges
        print(f"{name}: mean edge {np.linalg.norm(V[e[:, 0]] - V[e[:, 1]], axis=1).mean():.2f} mm")
    print()
    print("| mesh | method | " + " | ".join(f"σ={s} mm: k1, k2 err" for s in sigmas) + " |")
    print("|---|---|" + "---|" * len(sigmas))
    t0 = time.perf_counter()
    for name, (V0, F) in shapes.items():
        t1, t2 = truth(name, V0)
        for mname, fn in methods.items():
            cells = []
            for s in sigmas:
                e1, e2 = [], []
                for seed in range(3 if s > 0 else 1):
                    V = V0 + np.random.default_rng(seed).normal(scale=s, size=V0.shape)
                    k1, k2 = fn(V, F)
                    e1.append(np.median(np.abs(k1 - t1)))
                    e2.append(np.median(np.abs(k2 - t2)))
                cells.append(f"{np.mean(e1):.4f}, {np.mean(e2):.4f}")
            print(f"| {name} | {mname} | " + " | ".join(cells) + " |")
    print(f"\n(true curvatures: sphere {1 / 27:.4f}; ellipsoid k1 in [{t1.min():.3f}, {t1.max():.3f}], "
          f"k2 in [{t2.min():.3f}, {t2.max():.3f}] 1/mm; {time.perf_counter() - t0:.1f} s)")


if __name__ == "__main__":
    main()
