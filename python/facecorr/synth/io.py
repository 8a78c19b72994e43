"""Byte-exact binary PLY writing/reading for the synthetic database.

A small writer of our own (rather than a general mesh library) so that the same scan always gives
the same bytes: little-endian float32 vertices, int32 triangle lists, a fixed header.
"""

from __future__ import annotations

import numpy as np

_FACE_DTYPE = np.dtype([("n", "u1"), ("i", "<i4", (3,))])


def write_ply(path, vertices: np.ndarray, faces: np.ndarray, comment: str = "facecorr synthetic scan, millimetres") -> None:
    """Write a binary little-endian PLY (float32 x y z, int32 triangles)."""
    v = np.ascontiguousarray(vertices, dtype="<f4")
    f = np.empty(len(faces), dtype=_FACE_DTYPE)
    f["n"] = 3
    f["i"] = faces
    header = (
        "ply\nformat binary_little_endian 1.0\n"
        f"comment {comment}\n"
        f"element vertex {len(v)}\nproperty float x\nproperty float y\nproperty float z\n"
        f"element face {len(f)}\nproperty list uchar int vertex_indices\nend_header\n"
    )
    with open(path, "wb") as fh:
        fh.write(header.encode("ascii"))
        fh.write(v.tobytes())
        fh.write(f.tobytes())


def read_ply(path):
    """Read a PLY written by :func:`write_ply`: (vertices (N, 3) float64, faces (M, 3) int64)."""
    with open(path, "rb") as fh:
        data = fh.read()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    nv = nf = None
    for line in data[:end].decode("ascii").splitlines():
        if line.startswith("element vertex"):
            nv = int(line.split()[-1])
        elif line.startswith("element face"):
            nf = int(line.split()[-1])
    v = np.frombuffer(data, dtype="<f4", count=3 * nv, offset=end).reshape(nv, 3).astype(np.float64)
    f = np.frombuffer(data, dtype=_FACE_DTYPE, count=nf, offset=end + 12 * nv)["i"].astype(np.int64)
    return v, f
