"""BU-3DFE ``.bnd`` landmark files: :func:`load_bnd` (vertex index and x y z per line)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..errors import MeshFileError

__all__ = ["load_bnd"]

_MAX_ID = 2**53  # larger "indices" are not vertex ids (and 1e308 would overflow int64)


def load_bnd(path, to_mm: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Read a BU-3DFE landmark file: one ``index x y z`` per line.

    Parameters
    ----------
    path : str or Path.
    to_mm : factor applied to the coordinates (the scan's ``mesh.to_mm`` to get millimetres).

    Returns
    -------
    ids : (L,) int64, the vertex index given on each line.
    points : (L, 3) float64, the coordinates (times ``to_mm``).

    Blank lines and ``#`` comments are skipped; anything else that is not four numbers (an
    integer index and three finite coordinates) raises MeshFileError naming the line.
    """
    path = Path(path)
    _check_readable_text(path)
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except OSError as e:
        raise MeshFileError(f"{path}: cannot read: {e.strerror or e}") from None
    ids, pts = [], []
    for n, line in enumerate(text.splitlines(), 1):
        s = line.split("#", 1)[0].strip()
        if not s:
            continue
        parts = s.replace(",", " ").split()
        if len(parts) != 4:
            raise MeshFileError(f"{path}: line {n}: expected 'index x y z', found {len(parts)} fields")
        try:
            idx = float(parts[0])
            xyz = [float(x) for x in parts[1:]]
        except ValueError:
            raise MeshFileError(f"{path}: line {n}: not numbers: {s[:60]!r}") from None
        if not idx.is_integer() or idx < 0:
            raise MeshFileError(f"{path}: line {n}: index {parts[0]!r} is not a non-negative integer")
        if idx > _MAX_ID:
            raise MeshFileError(f"{path}: line {n}: index {parts[0][:30]!r} is too large for a vertex index")
        if not all(math.isfinite(x) for x in xyz):
            raise MeshFileError(f"{path}: line {n}: NaN or infinite coordinate")
        ids.append(int(idx))
        pts.append(xyz)
    if not ids:
        raise MeshFileError(f"{path}: no landmarks in the file")
    return np.array(ids, np.int64), np.array(pts, np.float64) * float(to_mm)


def _check_readable_text(path: Path) -> None:
    """MeshFileError if ``path`` is missing or a directory."""
    if not path.exists():
        raise MeshFileError(f"{path}: no such file")
    if path.is_dir():
        raise MeshFileError(f"{path}: is a directory")
