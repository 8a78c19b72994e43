"""Quick shaded renderings of triangle meshes with matplotlib (no OpenGL needed), and the small
thumbnails and histograms of a batch's report.

Triangles are projected orthographically, Lambert-shaded and painted far to near
(painter's algorithm) with ``tripcolor``: fast enough for 50k-triangle scans and good enough to
judge a face, a fit or an error map by eye. The thumbnails (:func:`thumbnail_png`) are z-buffer
rasterized instead (:mod:`facecorr.geometry.raster`), smoothly shaded: a noise-free small picture
compresses to a third of a painted one.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .geometry.transforms import kabsch
from .names import LANDMARK_NAMES


def draw_mesh(ax, vertices, faces, *, rotation=None, values=None, cmap="viridis", vmin=None,
              vmax=None, base_color=(0.85, 0.78, 0.72), points=None, point_color="red",
              face_colors=None):
    """Draw a shaded mesh on a 2-D matplotlib axis, viewed along -z after ``rotation``.

    Parameters
    ----------
    vertices : (N, 3) float, faces : (M, 3) int
    rotation : (3, 3) applied to the vertices first (default identity).
    values : (N,) per-vertex scalars to colour by (shaded), or None for a plain skin colour.
    points : (K, 3) optional points (same frame) drawn as dots on top.
    face_colors : (M, 3) optional RGB in [0, 1] per triangle (shaded), used when ``values`` is None.
    Returns the ScalarMappable of ``values`` (for a colour bar) or None.
    """
    import matplotlib
    import matplotlib.cm as cm
    import matplotlib.colors as mcolors

    rot = np.eye(3) if rotation is None else np.asarray(rotation)
    v = np.asarray(vertices, float) @ rot.T
    f = np.asarray(faces)
    tri = v[f]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True) + 1e-12
    light = np.array([0.3, 0.4, 1.0])
    light /= np.linalg.norm(light)
    shade = 0.25 + 0.75 * np.abs(n @ light)
    mappable = None
    if values is None and face_colors is not None:
        rgb = np.asarray(face_colors, float) * shade[:, None]
    elif values is None:
        rgb = np.outer(shade, base_color)
    else:
        fv = np.asarray(values, float)[f].mean(axis=1)
        norm = mcolors.Normalize(vmin=np.nanmin(fv) if vmin is None else vmin,
                                 vmax=np.nanmax(fv) if vmax is None else vmax)
        cmap_ = matplotlib.colormaps[cmap] if isinstance(cmap, str) else cmap  # cm.get_cmap is gone in mpl 3.9
        rgb = cmap_(norm(np.nan_to_num(fv)))[:, :3] * shade[:, None]
        mappable = cm.ScalarMappable(norm=norm, cmap=cmap_)
    order = np.argsort(tri[:, :, 2].mean(axis=1))  # far first
    from matplotlib.collections import PolyCollection

    col = np.clip(rgb[order], 0, 1)
    # edges in the face colour close the hairline seams antialiasing leaves between triangles
    pc = PolyCollection(tri[order][:, :, :2], facecolors=col, edgecolors=col, linewidths=0.25)
    ax.add_collection(pc)
    if points is not None:
        p = np.asarray(points, float) @ rot.T
        ax.scatter(p[:, 0], p[:, 1], s=14, c=point_color, zorder=5, edgecolors="white", linewidths=0.5)
    ax.set_xlim(v[:, 0].min(), v[:, 0].max())
    ax.set_ylim(v[:, 1].min(), v[:, 1].max())
    ax.set_aspect("equal")
    ax.axis("off")
    return mappable


def plot_registration(mesh, result, path, template, title=None) -> None:
    """PNG of the scan (a Mesh) beside the registered template (a pipeline Result) coloured by
    point-to-plane distance (mm).

    Both are drawn in the template's frame (a rigid fit of the result onto the template's rest
    pose), front view, like the paper's Fig. 11.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .io.atomic import atomic_path

    r, t = kabsch(result.vertices, np.asarray(template.vertices, float))
    scan_v = mesh.vertices @ r.T + t
    reg_v = result.vertices @ r.T + t
    # point-to-plane distance from each registered vertex to its nearest scan vertex's tangent plane
    dist, idx = mesh.kdtree.query(result.vertices, k=1)
    n = mesh.vertex_normals[idx]
    p2p = np.abs(np.einsum("ij,ij->i", result.vertices - mesh.vertices[idx], n))
    centre = reg_v.mean(axis=0)
    keep = np.linalg.norm(scan_v - centre, axis=1) < 1.3 * np.linalg.norm(reg_v - centre, axis=1).max()
    fkeep = keep[mesh.faces].all(axis=1)
    fig, axes = plt.subplots(1, 2, figsize=(10, 5.5))
    lm = np.array([result.landmarks[k] for k in LANDMARK_NAMES]) @ r.T + t
    draw_mesh(axes[0], scan_v, mesh.faces[fkeep], points=lm)
    axes[0].set_title("scan (red: the landmarks used)")
    sm = draw_mesh(axes[1], reg_v, result.faces, values=p2p, cmap="turbo", vmin=0.0, vmax=1.0)
    axes[1].set_title(f"registered template, MHD {result.mhd:.2f} mm")
    fig.colorbar(sm, ax=axes[1], fraction=0.04, label="point-to-plane distance to scan [mm] (clamped at 1)")
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)


def plot_landmarks(rows, path, reference, cols: int = 4) -> None:
    """PNG of scans with their true (green) and predicted (red) landmarks, one panel per row of
    ``evaluate_landmarks`` (needs "scan", "gt", "predicted"), each turned to a front view by a
    rigid fit of its true landmarks onto ``reference`` (8, 3) (the template's landmarks, mm),
    titled with its largest error (mm)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .io import load_mesh
    from .io.atomic import atomic_path

    ref = np.asarray(reference, dtype=np.float64)
    n = len(rows)
    nrow = (n + cols - 1) // cols
    fig, axes = plt.subplots(nrow, cols, figsize=(3.2 * cols, 3.6 * nrow), squeeze=False)
    for ax in axes.ravel()[n:]:
        ax.axis("off")
    for ax, row in zip(axes.ravel(), rows):
        mesh = load_mesh(row["scan"], units="mm")
        gt = json.loads(Path(row["gt"]).read_text())
        truth = np.array([gt["landmarks"][k] for k in LANDMARK_NAMES], float)
        pred = np.asarray(row["predicted"], float)
        r, t = kabsch(truth, ref)
        v = mesh.vertices @ r.T + t
        keep = np.linalg.norm(v - ref.mean(axis=0), axis=1) < 95.0  # the face, not the whole head
        draw_mesh(ax, v, mesh.faces[keep[mesh.faces].all(axis=1)])
        tp, pp = truth @ r.T + t, pred @ r.T + t
        ax.scatter(tp[:, 0], tp[:, 1], s=22, c="lime", edgecolors="black", linewidths=0.5, zorder=6)
        ax.scatter(pp[:, 0], pp[:, 1], s=30, c="red", marker="x", linewidths=1.2, zorder=7)
        name = Path(row["scan"]).stem.replace("_F3D", "")
        ax.set_title(f"{name}: max {max(row['errors'].values()):.1f} mm", fontsize=9)
        ax.axis("off")
    fig.suptitle("landmarks: true (green dots) and predicted (red crosses)")
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=100)
    plt.close(fig)


def plot_cumulative(worst, path) -> None:
    """PNG of the paper's Fig. 10: the share of scans (%) whose every evaluation point is under an
    error threshold (mm); ``worst`` (S,) is each scan's largest evaluation-point error, mm."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .io.atomic import atomic_path

    worst = np.asarray(worst, dtype=np.float64)
    th = np.linspace(0, max(10.0, float(np.nanmax(worst)) * 1.05), 300)
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.plot(th, [100 * (worst <= x).mean() for x in th])
    ax.set_xlabel("error threshold [mm]")
    ax.set_ylabel("scans with every evaluation point under it [%]")
    ax.set_ylim(0, 101)
    ax.grid(alpha=0.3)
    ax.set_title(f"cumulative registration error ({len(worst)} scans)")
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)


# --- thumbnails of registrations, for a batch and its report -----------------------------------

#: The distance colour scale of the thumbnails: 0 mm (blue) to this many mm or more (red).
DISTANCE_RANGE_MM = 3.0
#: PNG text key (and value) marking a picture :func:`thumbnail_png` made.
THUMBNAIL_TAG = ("facecorr", "registration-thumbnail-1")
#: Each panel of a thumbnail, pixels (width, height).
THUMBNAIL_PANEL = (200, 240)
_LIGHT = np.array([0.3, 0.4, 1.0]) / np.linalg.norm([0.3, 0.4, 1.0])
_SKIN = np.array([0.85, 0.78, 0.72])


def distance_colours(distance_mm) -> np.ndarray:
    """(N, 3) RGB in [0, 1] of distances (N,) mm on the thumbnails' scale: matplotlib's turbo
    from 0 to :data:`DISTANCE_RANGE_MM` (its darkest blues left out: they would hide the shading);
    NaN counts as far."""
    import matplotlib

    d = np.nan_to_num(np.asarray(distance_mm, dtype=np.float64), nan=np.inf)
    return matplotlib.colormaps["turbo"](0.12 + 0.88 * np.clip(d / DISTANCE_RANGE_MM, 0.0, 1.0))[..., :3]


def _vertex_shade(vertices, faces, smooth_rings: int = 0) -> np.ndarray:
    """(N,) Lambert shade in [0.25, 1] of the vertex normals (averaged over ``smooth_rings`` rings
    of neighbours: a scan's sensor noise would dominate a small picture)."""
    from .geometry.mesh import vertex_normals

    n = vertex_normals(vertices, faces)
    if smooth_rings:
        import scipy.sparse as sp

        e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
        adj = sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(len(vertices),) * 2).tocsr()
        adj = ((adj + adj.T) > 0).astype(np.float64) + sp.identity(len(vertices), format="csr")
        for _ in range(smooth_rings):
            n = adj @ n
        n /= np.linalg.norm(n, axis=1, keepdims=True) + 1e-12
    return 0.25 + 0.75 * np.abs(n @ _LIGHT)


def _raster_panel(project, vertices, faces, shade, distance=None, size=THUMBNAIL_PANEL, supersample=2):
    """(H, W, 3) uint8 front view of a mesh (white background, nearest surface wins): skin colour
    or, with ``distance`` (N,) mm, :func:`distance_colours`, both times ``shade`` (N,); values
    interpolated across each triangle, rendered ``supersample`` times larger and averaged down."""
    from .geometry.raster import rasterize

    w, h = size[0] * supersample, size[1] * supersample
    tri, bary, _ = rasterize(project(vertices) * supersample, -vertices[:, 2], faces, w, h)
    img = np.ones((h, w, 3))
    hit = tri >= 0
    corners = faces[tri[hit]]
    b = bary[hit]
    s = np.einsum("pk,pk->p", b, shade[corners])
    rgb = _SKIN[None, :] if distance is None else distance_colours(np.einsum("pk,pk->p", b, distance[corners]))
    img[hit] = np.clip(rgb * s[:, None], 0.0, 1.0)
    img = img.reshape(size[1], supersample, size[0], supersample, 3).mean(axis=(1, 3))
    return (img * 255 + 0.5).astype(np.uint8)


def thumbnail_png(vertices, faces, distance_mm, template, *, scan=None, landmarks=None) -> bytes:
    """A small PNG (~25 kB, 400 x 240) of one registration, for a batch's report.

    Left: the scan (a Mesh, mm) or, without it, the registered template in skin colour, with
    ``landmarks`` (K, 3) mm, the landmarks the registration used, as red dots. Right: the
    registered template coloured by ``distance_mm`` (N,), its vertices' distance to the scan
    (:func:`distance_colours`, grey where None). Both are front views in the template's frame (a
    rigid fit of ``vertices`` (N, 3) mm onto the template's rest pose), at the same scale. A
    64-colour palette keeps 700 of them in an HTML page of ~25 MB; a PNG text chunk
    (:data:`THUMBNAIL_TAG`) marks the picture as one of these.
    """
    import io

    from PIL import Image, ImageDraw
    from PIL.PngImagePlugin import PngInfo

    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    r, t = kabsch(vertices, np.asarray(template.vertices, dtype=np.float64))
    reg = vertices @ r.T + t
    lo, hi = reg[:, :2].min(axis=0), reg[:, :2].max(axis=0)
    (pw, ph), margin = THUMBNAIL_PANEL, 4
    scale = min((pw - 2 * margin) / max(hi[0] - lo[0], 1e-9), (ph - 2 * margin) / max(hi[1] - lo[1], 1e-9))
    cx, cy = (lo + hi) / 2

    def project(v):  # template frame (x right, y up, viewer on +z) -> panel pixels
        return np.column_stack([(v[:, 0] - cx) * scale + pw / 2, (cy - v[:, 1]) * scale + ph / 2])

    if scan is not None:
        sv = scan.vertices @ r.T + t
        near = np.linalg.norm(sv - reg.mean(axis=0), axis=1) < 1.3 * np.linalg.norm(reg - reg.mean(axis=0), axis=1).max()
        sf = scan.faces[near[scan.faces].all(axis=1)]
        left = _raster_panel(project, sv, sf, _vertex_shade(sv, sf, smooth_rings=2))  # the kept part only
    else:
        left = _raster_panel(project, reg, faces, _vertex_shade(reg, faces))
    shade = _vertex_shade(reg, faces)
    if distance_mm is None:
        right = _raster_panel(project, reg, faces, shade * 0.8)
    else:
        right = _raster_panel(project, reg, faces, shade, distance=np.asarray(distance_mm, dtype=np.float64))
    im = _palette_of_halves(left, right)
    if landmarks is not None:  # drawn after the quantization, in their own palette entries
        draw = ImageDraw.Draw(im)
        for x, y in project(np.asarray(landmarks, dtype=np.float64) @ r.T + t):
            draw.ellipse([x - 3.5, y - 3.5, x + 3.5, y + 3.5], fill=_DOT, outline=_DOT + 1)
    info = PngInfo()
    info.add_text(*THUMBNAIL_TAG)
    info.add_text("Description", "left: the scan with the landmarks used (red); right: the registered template "
                  f"coloured by its distance to the scan, 0 (blue) to {DISTANCE_RANGE_MM:g} mm or more (red)")
    buf = io.BytesIO()
    im.save(buf, format="PNG", optimize=True, pnginfo=info)
    return buf.getvalue()


#: Palette entries of a thumbnail: 30 colours of the left panel, the dots' red and white, 32 of
#: the right panel (one palette for both would spend the skin tones on the distance colours).
_HALF_COLOURS = 32
_DOT = _HALF_COLOURS - 2


def _palette_of_halves(left, right):
    """The two panels (H, W, 3) uint8 side by side as one palette image (:data:`_HALF_COLOURS`)."""
    from PIL import Image

    idx, pal = [], []
    for k, (half, n) in enumerate(((left, _DOT), (right, _HALF_COLOURS))):
        q = Image.fromarray(half).quantize(colors=n, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE)
        idx.append(np.asarray(q, dtype=np.uint8) + k * _HALF_COLOURS)
        pal += (q.getpalette() + [255] * 3 * n)[: 3 * n] + ([225, 25, 25, 255, 255, 255] if k == 0 else [])
    out = Image.fromarray(np.concatenate(idx, axis=1), mode="P")
    out.putpalette(pal)
    return out


def is_thumbnail_png(path) -> bool:
    """Whether ``path`` is a PNG :func:`thumbnail_png` made (False for any other or unreadable file)."""
    try:
        from PIL import Image

        with Image.open(path) as im:
            return im.format == "PNG" and im.text.get(THUMBNAIL_TAG[0]) == THUMBNAIL_TAG[1]
    except Exception:  # noqa: BLE001 - any unreadable picture is "not one of ours"
        return False


def histogram_png(values, *, xlabel: str, title: str, thresholds=(), bins: int = 30, log: bool = False) -> bytes:
    """A small PNG histogram (320 x 190) of ``values`` (finite ones counted) with dashed vertical
    lines at ``thresholds`` (pairs (x, label): where a flag is raised)."""
    import io

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    v = np.asarray(values, dtype=np.float64)
    v = v[np.isfinite(v)]
    from matplotlib.ticker import MaxNLocator

    fig, ax = plt.subplots(figsize=(3.2, 1.9), dpi=100)
    if len(v):
        # the bins span the thresholds too: a bar's width does not depend on where the lines are
        span = np.concatenate([v, [x for x, _ in thresholds]])
        lo, hi = float(span.min()), float(span.max())
        if hi - lo < 1e-9:
            lo, hi = lo - 0.5, hi + 0.5
        ax.hist(v, bins=np.linspace(lo, hi, bins + 1), color="#4a78b5", edgecolor="white", linewidth=0.4, log=log)
        ax.yaxis.set_major_locator(MaxNLocator(integer=True))
    else:
        ax.text(0.5, 0.5, "no values", transform=ax.transAxes, ha="center", va="center", color="grey")
    for x, label in thresholds:
        ax.axvline(x, color="#c0392b", linestyle="--", linewidth=1)
        ax.annotate(label, (x, 1), xycoords=("data", "axes fraction"), xytext=(3, -3), textcoords="offset points",
                    ha="left", va="top", fontsize=7, color="#c0392b")
    ax.set_title(title, fontsize=9)
    ax.set_xlabel(xlabel, fontsize=8)
    ax.tick_params(labelsize=7)
    for side in ("top", "right"):
        ax.spines[side].set_visible(False)
    fig.tight_layout(pad=0.4)
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    plt.close(fig)
    return buf.getvalue()


def plot_shape_modes(mean, components, std, faces, explained, path, *, n_modes: int = 3, sigma: float = 3.0,
                     title: str | None = None) -> None:
    """PNG of a shape model's first modes and its explained variance.

    One row per mode: the mean -/+ ``sigma`` standard deviations of the mode, front and side
    view, coloured by the signed displacement from the mean along the mean's normals (mm; red
    outwards, blue inwards), with the mean itself between them; below, each mode's share of the
    total variance (bars) and the cumulative share (line).

    Parameters
    ----------
    mean : (N, 3) mm in the template's frame (+y up, +z out of the face); components : (K, N, 3)
    orthonormal; std : (K,) standard deviations (mm); faces : (M, 3); explained : (K,) each mode's
    share of the total variance.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .geometry.mesh import vertex_normals
    from .geometry.transforms import view_rotation
    from .io.atomic import atomic_path

    mean = np.asarray(mean, dtype=np.float64)
    comps = np.asarray(components, dtype=np.float64)
    std = np.asarray(std, dtype=np.float64)
    explained = np.asarray(explained, dtype=np.float64)
    k = int(min(n_modes, len(std)))
    normals = vertex_normals(mean, faces)
    views = [("front", view_rotation(0, 0)), ("side", view_rotation(90, 0))]
    height = 2.6 * k + 3.0
    fig = plt.figure(figsize=(15, height))
    gs = fig.add_gridspec(k + 1, 7, height_ratios=[1] * k + [1.15], width_ratios=[1, 1, 1, 0.75, 0.75, 0.75, 0.08],
                          hspace=0.25, wspace=0.02)
    for i in range(k):
        lo, hi = mean - sigma * std[i] * comps[i], mean + sigma * std[i] * comps[i]
        d_hi = np.einsum("ij,ij->i", hi - mean, normals)
        vmax = max(float(np.abs(d_hi).max()), 1e-6)
        col = 0
        for vname, rot in views:
            for label, v, d in ((f"-{sigma:g} sd", lo, -d_hi), ("mean", mean, None), (f"+{sigma:g} sd", hi, d_hi)):
                ax = fig.add_subplot(gs[i, col])
                col += 1
                if d is None:
                    draw_mesh(ax, v, faces, rotation=rot)
                else:
                    sm = draw_mesh(ax, v, faces, rotation=rot, values=d, cmap="RdBu_r", vmin=-vmax, vmax=vmax)
                head = f"mode {i + 1} ({100 * explained[i]:.1f} %) " if col == 1 else f"mode {i + 1} "
                ax.set_title(f"{head}{label} ({vname})" if label != "mean" else f"mean ({vname})", fontsize=9)
        cax = fig.add_subplot(gs[i, 6])
        fig.colorbar(sm, cax=cax, label="mm along the normal")
    ax = fig.add_subplot(gs[k, 1:6])
    shown = min(len(explained), 40)
    x = np.arange(1, shown + 1)
    ax.bar(x, 100 * explained[:shown], color="#7a9cc6", label="each mode")
    cum = 100 * np.cumsum(explained)[:shown]
    ax.plot(x, cum, "o-", color="#c0392b", ms=3.5, label="cumulative")
    for level in (90, 98):
        ax.axhline(level, color="grey", lw=0.6, ls=":")
        ax.text(shown + 0.6, level, f"{level} %", fontsize=7, va="center", color="grey")
    ax.set_xlim(0.3, shown + 2.5)
    ax.set_ylim(0, 102)
    ax.set_xlabel("mode")
    ax.set_ylabel("share of the total variance [%]")
    ax.legend(loc="center right", fontsize=8)
    ax.grid(alpha=0.25)
    if title:
        fig.suptitle(title, fontsize=11, y=fig.subplotpars.top + 0.6 / height)  # ~0.6 in above the grid
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=85, bbox_inches="tight")
    plt.close(fig)
