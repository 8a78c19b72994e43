"""Accuracy of a registration against exact ground truth (the paper's Tables 1-3 and MHD).

A *registered template* is the template mesh deformed onto a scan: (N, 3) vertices in template
vertex order, in the scan's frame, millimetres. Ground truth comes from the synthetic database
(one JSON per scan, see :func:`load_ground_truth`).

- :func:`region_errors`: Euclidean error at the iBUG-68 points of the paper's evaluation regions
  (``facecorr.names.IBUG68_REGIONS``: eyebrows, eyes, nose, outer lips), read off the registered
  template at ``template.ibug68``.
- :func:`summarize_regions`: Table 3 rows (mean ± std over all points of all scans, max, and
  T10/T20/T30: the share of scans whose *every* point of the region is under 10/20/30 mm).
- :func:`dense_error`: dense correspondence error: each scan vertex was sampled from an ICT
  triangle at known barycentric coordinates; where that triangle belongs to the template, the
  registered template is interpolated at the same coordinates and compared with the vertex's
  noise-free position.
- :func:`landmark_errors`, :func:`summarize_landmarks`: the 8 predicted landmarks against the
  truth (paper Tables 1-2); :func:`format_region_table` prints either summary as Markdown.
- :func:`mhd`: the modified Hausdorff distance of the paper, mean over P of the distance to the
  nearest vertex of F (one-directional, as the paper defines it).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..geometry.spatial import mhd

__all__ = ["region_errors", "summarize_regions", "landmark_errors", "summarize_landmarks", "format_region_table",
           "dense_error", "mhd", "load_ground_truth"]

from ..errors import FacecorrError, MeshFileError
from ..names import IBUG68_REGIONS, LANDMARK_NAMES

#: Detection-rate thresholds of the paper's tables (mm).
THRESHOLDS_MM = (10.0, 20.0, 30.0)


def _template(template):
    if template is None:
        from ..template import load_template

        return load_template()
    return template


def _registered(registered, template) -> np.ndarray:
    r = np.asarray(registered, dtype=np.float64)
    n = template.n_vertices
    if r.shape != (n, 3):
        raise ValueError(f"registered vertices must have the template's shape ({n}, 3), got {r.shape}")
    if not np.isfinite(r).all():
        raise ValueError("registered vertices have NaN or infinite coordinates")
    return r


def region_errors(registered, gt_ibug68, template=None, keep_missing: bool = False) -> dict:
    """Errors at the iBUG-68 evaluation points, per region.

    Parameters
    ----------
    registered : (N, 3) registered template vertices, mm (scan frame).
    gt_ibug68 : (68, 3) ground-truth iBUG-68 positions, mm, NaN rows where a point is missing.
    template : Template (default: the packaged one).
    keep_missing : if True, keep one entry per region point, NaN where the ground truth is
        missing or the point is outside the template; if False (default) drop those entries.

    Returns
    -------
    dict region name -> (n,) float64 Euclidean errors in mm, regions in IBUG68_REGIONS order.
    """
    t = _template(template)
    r = _registered(registered, t)
    g = np.asarray(gt_ibug68, dtype=np.float64)
    if g.shape != (68, 3):
        raise ValueError(f"gt_ibug68 must have shape (68, 3), got {g.shape}")
    out = {}
    for name, pts in IBUG68_REGIONS.items():
        pts = np.asarray(pts)
        ids = t.ibug68[pts]
        err = np.full(len(pts), np.nan)
        ok = (ids >= 0) & np.isfinite(g[pts]).all(axis=1)
        err[ok] = np.linalg.norm(r[ids[ok]] - g[pts[ok]], axis=1)
        out[name] = err if keep_missing else err[ok]
    return out


def _summary_row(per_scan, thresholds) -> dict | None:
    """mean/std/max over all values, T<th> = % of scans whose every value is under th."""
    errs = [np.atleast_1d(np.asarray(e, float)) for e in per_scan]
    errs = [e[np.isfinite(e)] for e in errs]
    errs = [e for e in errs if len(e)]
    if not errs:
        return None
    allp = np.concatenate(errs)
    worst = np.array([e.max() for e in errs])
    row = {"mean": float(allp.mean()), "std": float(allp.std()), "max": float(allp.max())}
    for th in thresholds:
        row[f"T{th:g}"] = float(100.0 * (worst < th).mean())
    row["n_scans"] = len(errs)
    row["n_points"] = int(len(allp))
    return row


def summarize_regions(per_scan, thresholds=THRESHOLDS_MM) -> list[dict]:
    """Table 3 rows from per-scan :func:`region_errors` dicts.

    Mean and std are over all points of a region in all scans; a scan counts under a threshold
    when every (available) point of the region is strictly under it, as in the paper. Scans with
    no available point in a region are left out of that region's row.

    Returns
    -------
    list of dicts ``{"region", "mean", "std", "max", "T10", "T20", "T30" (percent), "n_scans",
    "n_points"}`` in IBUG68_REGIONS order (a region nobody measured is omitted).
    """
    rows = []
    for region in IBUG68_REGIONS:
        row = _summary_row([s[region] for s in per_scan if region in s], thresholds)
        if row is not None:
            rows.append({"region": region, **row})
    return rows


def landmark_errors(predicted: dict, gt_landmarks: dict) -> dict:
    """Euclidean error (mm) of each predicted landmark, name -> float (NaN where either is missing)."""
    out = {}
    for name in LANDMARK_NAMES:
        p, g = predicted.get(name), gt_landmarks.get(name)
        if p is None or g is None:
            out[name] = float("nan")
            continue
        out[name] = float(np.linalg.norm(np.asarray(p, float).reshape(3) - np.asarray(g, float).reshape(3)))
    return out


def summarize_landmarks(per_scan, thresholds=THRESHOLDS_MM) -> list[dict]:
    """Tables 1-2 rows from per-scan :func:`landmark_errors` dicts: per landmark mean ± std, max
    and T10/T20/T30 (% of scans with that landmark's error under the threshold).

    Returns
    -------
    list of dicts ``{"landmark", "mean", "std", "max", "T10", "T20", "T30", "n_scans",
    "n_points"}`` in LANDMARK_NAMES order (landmarks nobody measured are omitted).
    """
    rows = []
    for name in LANDMARK_NAMES:
        row = _summary_row([s[name] for s in per_scan if name in s], thresholds)
        if row is not None:
            rows.append({"landmark": name, **row})
    return rows


def format_region_table(rows) -> str:
    """Markdown table of :func:`summarize_regions` (or :func:`summarize_landmarks`) rows, laid
    out like the paper's Tables 1-3."""
    key = "landmark" if rows and "landmark" in rows[0] else "region"
    ts = [k for k in rows[0] if k.startswith("T")] if rows else []
    head = f"| {key.capitalize()} | Mean ± Std [mm] | Max [mm] | " + " | ".join(f"{k} [%]" for k in ts) + " | Scans |"
    lines = [head, "|" + "---|" * (4 + len(ts))]
    for r in rows:
        lines.append(f"| {r[key]} | {r['mean']:.2f} ± {r['std']:.2f} | {r['max']:.2f} | "
                     + " | ".join(f"{r[k]:.1f}" for k in ts) + f" | {r['n_scans']} |")
    return "\n".join(lines) + "\n"


def dense_error(registered, dense, template=None, return_mask: bool = False):
    """Dense correspondence error of a registered template.

    Parameters
    ----------
    registered : (N, 3) registered template vertices, mm (scan frame).
    dense : mapping with ``tri`` (S,) ICT triangle of each scan vertex (-1: geometry with no
        correspondence, e.g. the glasses or clothing of the ``bu3dfe-ood`` preset), ``bary`` (S, 3) its
        barycentric coordinates in that triangle (ICT corner order), ``clean`` (S, 3) its
        noise-free position in the scan frame, mm (the synthetic database's ``*_dense.npz``).
    template : Template (default: the packaged one).
    return_mask : also return the (S,) bool mask of the scan vertices that were measured.

    Returns
    -------
    (S',) float64 distances in mm, one per scan vertex whose ICT triangle is in the template
    (scan vertices on eyeballs, teeth, neck, ... and those with ``tri = -1`` have no counterpart
    and are skipped);
    ``(errors, mask)`` if ``return_mask``.
    """
    t = _template(template)
    r = _registered(registered, t)
    try:
        tri = np.asarray(dense["tri"]).astype(np.int64)
        bary = np.asarray(dense["bary"], dtype=np.float64)
        clean = np.asarray(dense["clean"], dtype=np.float64)
    except KeyError as e:
        raise ValueError(f"dense ground truth lacks {e.args[0]!r} (needs tri, bary, clean)") from None
    s = len(tri)
    if tri.shape != (s,) or bary.shape != (s, 3) or clean.shape != (s, 3):
        raise ValueError(f"dense ground truth shapes disagree: tri {tri.shape}, bary {bary.shape}, clean {clean.shape}")
    m_ict = len(t.ict_face_to_template_face)
    if s and (tri.min() < -1 or tri.max() >= m_ict):
        raise ValueError(f"dense ground truth triangle ids out of range [-1, {m_ict - 1}]")
    face = np.where(tri >= 0, t.ict_face_to_template_face[np.maximum(tri, 0)], -1)
    mask = face >= 0
    corners = r[t.faces[face[mask]]]  # (S', 3 corners, 3)
    p = np.einsum("sk,skd->sd", bary[mask], corners)
    err = np.linalg.norm(p - clean[mask], axis=1)
    return (err, mask) if return_mask else err


def load_ground_truth(json_path, load_dense: bool = True) -> dict:
    """Read one scan's ground truth (the synthetic database's per-scan JSON contract).

    Returns
    -------
    dict with the JSON's fields, plus: ``scan`` and ``dense_path`` made absolute (relative to the
    JSON's folder), ``landmarks`` name -> (3,) float64 mm, ``ibug68`` (68, 3) float64 mm with NaN
    rows for missing points, ``dense`` dict of arrays (``tri`` int64, ``bary``, ``clean``
    float64, ``pose`` (3, 4) when present) if ``load_dense``, else None.
    """
    path = Path(json_path)
    try:
        raw = json.loads(path.read_text())
    except FileNotFoundError:
        raise MeshFileError(f"{path}: ground-truth file not found") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise MeshFileError(f"{path}: unreadable ground truth ({type(e).__name__}: {e})") from None
    try:
        units = raw.get("units", "mm")
        if units != "mm":
            raise FacecorrError(f"{path}: ground truth in {units!r}; expected 'mm'")
        gt = dict(raw)
        base = path.parent
        gt["scan"] = str((base / raw["scan"]).resolve()) if "scan" in raw else None
        lm = raw["landmarks"]
        missing = [n for n in LANDMARK_NAMES if n not in lm]
        if missing:
            raise FacecorrError(f"{path}: ground truth lacks landmarks {missing}")
        gt["landmarks"] = {n: np.asarray(lm[n], dtype=np.float64).reshape(3) for n in lm}
        ib = raw["ibug68"]
        if len(ib) != 68:
            raise FacecorrError(f"{path}: ibug68 must have 68 entries, got {len(ib)}")
        gt["ibug68"] = np.array([[np.nan] * 3 if q is None else q for q in ib], dtype=np.float64).reshape(68, 3)
        gt["dense_path"] = str((base / raw["dense"]).resolve()) if raw.get("dense") else None
    except KeyError as e:
        raise FacecorrError(f"{path}: ground truth lacks {e.args[0]!r}") from None
    except (TypeError, ValueError) as e:
        raise FacecorrError(f"{path}: malformed ground truth ({e})") from None
    if load_dense:
        if gt["dense_path"] is None:
            raise FacecorrError(f"{path}: ground truth names no dense file")
        try:
            with np.load(gt["dense_path"]) as d:
                dense = {k: d[k] for k in d.files}
        except FileNotFoundError:
            raise MeshFileError(f"{gt['dense_path']}: dense ground truth not found") from None
        except (OSError, ValueError) as e:
            raise MeshFileError(f"{gt['dense_path']}: unreadable dense ground truth ({e})") from None
        for k in ("tri", "bary", "clean"):
            if k not in dense:
                raise FacecorrError(f"{gt['dense_path']}: dense ground truth lacks {k!r}")
        dense["tri"] = dense["tri"].astype(np.int64)
        dense["bary"] = dense["bary"].astype(np.float64)
        dense["clean"] = dense["clean"].astype(np.float64)
        gt["dense"] = dense
    else:
        gt["dense"] = None
    return gt
