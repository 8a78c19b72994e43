"""Contact sheet of scans with their ground-truth landmarks (for looking at the database)."""

from __future__ import annotations

import numpy as np

from ..geometry.raster import rasterize
from ..geometry.mesh import vertex_normals


def shade_frontal(vertices, faces, pose, mm_per_px=0.6, size_mm=(230.0, 260.0)):
    """Render a scan seen from the front of the face (pose undone), Lambert-shaded.

    Returns (image (H, W) float in [0, 1] with NaN background, to_pixels) where ``to_pixels``
    maps scan-frame points (K, 3) to (K, 2) image coordinates (u, v).
    """
    R, t = pose[:, :3], pose[:, 3]
    X = (vertices - t) @ R  # back to the model frame: +y up, +z towards the viewer
    centre = np.median(X, axis=0)
    W, H = int(size_mm[0] / mm_per_px), int(size_mm[1] / mm_per_px)

    def to_uv(p):
        return np.stack([(p[:, 0] - centre[0]) / mm_per_px + W / 2, (centre[1] - p[:, 1]) / mm_per_px + H / 2], 1)

    tri, bary, _ = rasterize(to_uv(X), -X[:, 2], faces, W, H)
    n = vertex_normals(X, faces)
    hit = tri >= 0
    nn = np.einsum("sk,skd->sd", bary[hit], n[faces[tri[hit]]])
    nn /= np.maximum(np.linalg.norm(nn, axis=1, keepdims=True), 1e-12)
    light = np.array([-0.3, 0.4, 1.0])
    light /= np.linalg.norm(light)
    img = np.full((H, W), np.nan)
    img[hit] = 0.15 + 0.85 * np.clip(nn @ light, 0.0, 1.0)

    def to_pixels(p):
        return to_uv((np.asarray(p, float) - t) @ R)

    return img, to_pixels


def contact_sheet(records, png_path, title=None):
    """Write a PNG grid: one panel per ground-truth JSON record (dicts with absolute paths)."""
    import json

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..io import load_mesh

    n = len(records)
    ncol = min(n, 7)
    nrow = (n + ncol - 1) // ncol
    fig, axes = plt.subplots(nrow, ncol, figsize=(3.2 * ncol, 3.7 * nrow), squeeze=False)
    for ax in axes.ravel():
        ax.axis("off")
    for ax, rec in zip(axes.ravel(), records):
        m = load_mesh(rec["scan"], units="mm", merge_duplicates=False)
        V, F = m.vertices, m.faces
        with open(rec["gt"]) as fh:
            gt = json.load(fh)
        pose = np.load(rec["dense"])["pose"]
        img, to_px = shade_frontal(V, F, pose)
        ax.imshow(img, cmap="gray", vmin=0, vmax=1, interpolation="bilinear")
        ib = np.array([p if p is not None else [np.nan] * 3 for p in gt["ibug68"]], float)
        ok = ~np.isnan(ib).any(1)
        if ok.any():
            q = to_px(ib[ok])
            ax.scatter(q[:, 0], q[:, 1], s=2, c="deepskyblue", linewidths=0)
        q = to_px(np.array(list(gt["landmarks"].values()), float))
        ax.scatter(q[:, 0], q[:, 1], s=9, c="red", linewidths=0)
        ax.set_title(f"{gt['subject']} {gt['expression']}{gt['level']:02d}  {len(V)} v", fontsize=8)
    if title:
        fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(png_path, dpi=110)
    plt.close(fig)
