"""A scan file's colour as the readers find it: per-vertex RGB, or texture coordinates and image.

The readers (:mod:`.load`, :mod:`.vrml`) return an :class:`Appearance` beside the raw vertices
and triangles; :func:`facecorr.io.load_mesh` renumbers it with the cleaning steps and puts it on
the :class:`~facecorr.geometry.mesh.Mesh`. Colour that a file declares but that cannot be used
(a texture image that is missing or unreadable, several texture images, colours on only some
vertices) is never an error: the scan loads without colour and ``note`` says why (it ends up in
``mesh.meta["colour_note"]`` and in the result's flags).

Texture images are read with Pillow (PNG, JPEG, BMP, TIFF, ...): :func:`read_image`. Wavefront
material files: :func:`read_mtl`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["Appearance", "read_image", "read_mtl"]


@dataclass
class Appearance:
    """Colour found in a file, indexed like the reader's raw arrays.

    vertex_colors : (N, 3) float in [0, 1] or None.
    corner_uv : (M, 3, 2) float texture coordinates of each raw triangle's corners, or None.
    texture : (H, W, 3) uint8 image (row 0 at the top), or None; set together with corner_uv.
    note : why colour the file declares was not kept, or None.
    """

    vertex_colors: np.ndarray | None = None
    corner_uv: np.ndarray | None = None
    texture: np.ndarray | None = None
    note: str | None = None

    def add_note(self, note: str) -> None:
        self.note = note if self.note is None else f"{self.note}; {note}"


def read_image(path) -> np.ndarray:
    """(H, W, 3) uint8 RGB of an image file (row 0 at the top; alpha dropped, grey expanded).

    Raises ValueError with a one-line reason if the file is missing or not an image Pillow reads.
    """
    from PIL import Image, UnidentifiedImageError

    path = Path(path)
    if not path.is_file():
        raise ValueError(f"texture image {path.name!r} not found beside the scan")
    try:
        with Image.open(path) as im:
            arr = np.asarray(im.convert("RGB"), dtype=np.uint8)
    except (OSError, UnidentifiedImageError, ValueError, Image.DecompressionBombError) as e:
        raise ValueError(f"texture image {path.name!r} is not readable ({type(e).__name__})") from None
    if arr.ndim != 3 or 0 in arr.shape:
        raise ValueError(f"texture image {path.name!r} is empty")
    return np.ascontiguousarray(arr)


def read_mtl(path) -> dict:
    """Materials of a Wavefront ``.mtl`` file: name -> texture image path (``map_Kd``, relative
    to the file's folder; None for a material without one). A missing or unreadable file -> {}."""
    path = Path(path)
    try:
        text = path.read_bytes().decode("utf-8", errors="replace")
    except OSError:
        return {}
    out: dict = {}
    name = None
    for line in text.splitlines():
        parts = line.split("#", 1)[0].split()
        if not parts:
            continue
        if parts[0] == "newmtl" and len(parts) > 1:
            name = " ".join(parts[1:])
            out.setdefault(name, None)
        elif parts[0].lower() == "map_kd" and name is not None and len(parts) > 1:
            # options (-s 1 1 1, -o ..., -clamp on, ...) come before the file name: the name is
            # what follows the last option; names with spaces are kept whole when there is none
            rest = parts[1:]
            out[name] = path.parent / (rest[-1] if any(p.startswith("-") for p in rest) else " ".join(rest))
    return out
