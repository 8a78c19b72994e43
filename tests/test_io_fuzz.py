"""Fuzzing of the hand-written readers (VRML plain and gzipped, .bnd, OBJ, OFF) and of the formats
read through trimesh (ASCII and binary PLY, ASCII and binary STL, GLB).

Valid files are mutated (truncated, bytes flipped, a bracket/brace deleted, huge/odd numbers
inserted, a line duplicated or deleted); the only allowed outcomes are a valid Mesh (finite
vertices, face indices in range) / valid landmarks, or a one-line FacecorrError naming the file,
each within a time bound. The run here is small and derandomized; ``benches/fuzz_readers.py``
runs thousands of seeded examples per format and prints the outcome counts.
"""

from __future__ import annotations

import gzip
import signal
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from facecorr import io
from facecorr.errors import FacecorrError
from facecorr.geometry.mesh import Mesh

TIME_LIMIT_S = 5.0  # a single read of these small files must never take this long

_OBJ = """# a scan \xe9
mtllib scan.mtl
o face
v 0 0 0
v 100 0 0
v 100 100 0
v 0 100 0 1.0
v 50 50 30 0.5 0.5 0.5
vt 0 0
vt 1 0
vt 1 1
vn 0 0 1
usemtl skin
s 1
f 1/1/1 2/2/1 5/3/1
f 2//1 3//1 5//1
f 3 4 5
v 150 50 0
f -4 -1 -3
f 4/1 1/2 5/3 2/1
l 1 2
"""

# one small mesh (6 vertices, a quad among the triangles) for the OFF and PLY seeds
_VERTEX_ROWS = "0 0 0\n100 0 0\n100 100 0\n0 100 0\n50 50 30\n150 50 0\n"
_TRIANGLE_ROWS = "3 0 1 4\n3 1 2 4\n3 2 3 4\n"

_OFF = ("OFF\n# a comment\n6 5 0\n" + _VERTEX_ROWS + _TRIANGLE_ROWS
        + "4 3 0 4 2 255 0 0\n3 1 5 2\n")

_PLY = """ply
format ascii 1.0
comment a scan
element vertex 6
property float x
property float y
property float z
element face 5
property list uchar int vertex_indices
end_header
""" + _VERTEX_ROWS + _TRIANGLE_ROWS + "4 3 0 4 2\n3 1 5 2\n"

_WRL = """#VRML V2.0 utf8
# BU-3DFE-like
WorldInfo { title "F0001" info [ "not # a comment" ] }
Transform {
  translation 0 0 5 rotation 0 0 1 0.5 scale 1 1 1 center 1 2 3
  children [
    Shape {
      appearance Appearance { texture ImageTexture { url "F0001.bmp" } }
      geometry DEF IFS IndexedFaceSet {
        solid FALSE creaseAngle 0.5 ccw TRUE
        coord DEF C Coordinate { point [ 0 0 0, 100 0 0, 100 100 0, # a comment
                                         0 100 0, 50 50 30 ] }
        texCoord TextureCoordinate { point [ 0 0, 1 0, 1 1, 0 1 ] }
        texCoordIndex [ 0 1 2 3 -1 ]
        coordIndex [ 0, 1, 4, -1, 1, 2, 4, -1, 2, 3, 4, 0, -1 ]
      }
    }
    Shape { geometry IndexedFaceSet { ccw FALSE coord USE C coordIndex [ 0 1 2 -1 ] } }
  ]
}
LOD { level [ Group { children [ Shape { geometry IndexedFaceSet {
  coord Coordinate { point [ 200 0 0 210 0 0 210 10 0 ] } coordIndex [ 0 1 2 ] } } ] } ] }
ROUTE a.b TO c.d
"""


def _big_wrl() -> str:
    """A VRML file whose point / coordIndex lists are long enough (> 1000 chars) for the fast path."""
    n = 12
    xs, ys = np.meshgrid(np.arange(n) * 10.0, np.arange(n) * 10.0)
    pts = ",\n".join(f"{x:.1f} {y:.1f} {(x * y) % 7:.1f}" for x, y in zip(xs.ravel(), ys.ravel()))
    faces = []
    for i in range(n - 1):
        for j in range(n - 1):
            a = i * n + j
            faces.append(f"{a}, {a + 1}, {a + n}, -1")
    return ("#VRML V2.0 utf8\nShape {\n geometry IndexedFaceSet {\n  coord Coordinate {\n   point [\n"
            f"{pts}\n   ]\n  }}\n  coordIndex [\n{', '.join(faces)}\n  ]\n }}\n}}\n")


_BND = """# BU-3DFE landmarks
8017  -55.0880 31.4430 58.2150
2  1e1 -2.5 3
44.000000 0 0 0
9 1,2,3
"""

def _binary_seeds() -> dict[str, list[bytes]]:
    """The OFF/PLY seeds' mesh as binary PLY (both byte orders), STL (binary, ASCII) and GLB."""
    import trimesh

    V = np.array([r.split() for r in _VERTEX_ROWS.split("\n") if r], float)
    F = np.array([r.split()[1:] for r in _TRIANGLE_ROWS.split("\n") if r], int)
    m = trimesh.Trimesh(V, F, process=False)
    ply_le = trimesh.exchange.ply.export_ply(m, encoding="binary")
    head, body = ply_le.split(b"end_header\n", 1)
    n = len(V) * 3 * 4  # float32 xyz; faces: uint8 count + 3 int32 (trimesh's layout)
    verts = np.frombuffer(body[:n], "<f4").astype(">f4").tobytes()
    faces = np.frombuffer(body[n:], np.dtype([("n", "u1"), ("i", "<i4", 3)])).astype(
        np.dtype([("n", "u1"), ("i", ">i4", 3)])).tobytes()
    ply_be = head.replace(b"binary_little_endian", b"binary_big_endian") + b"end_header\n" + verts + faces
    return {
        "ply": [ply_le, ply_be],
        "stl": [trimesh.exchange.stl.export_stl(m), trimesh.exchange.stl.export_stl_ascii(m).encode()],
        "glb": [m.export(file_type="glb")],
    }


SEEDS: dict[str, list[bytes]] = {
    "obj": [_OBJ.encode("latin-1"), _OBJ.replace("\n", "\r\n").encode("latin-1")],
    "off": [_OFF.encode(), b"\xef\xbb\xbf" + _OFF.replace("\n", "\r\n").encode()],
    "ply": [_PLY.encode(), _PLY.replace("\n", "\r\n").encode()],
    "wrl": [_WRL.encode(), _big_wrl().encode(), gzip.compress(_WRL.encode(), mtime=0)],
    "bnd": [_BND.encode(), _BND.replace("\n", "\r\n").encode()],
}
for _fmt, _seeds in _binary_seeds().items():
    SEEDS[_fmt] = SEEDS.get(_fmt, []) + _seeds

ODD_NUMBERS = [b"1e308", b"-1e308", b"1e999", b"-1e999", b"-0", b"nan", b"-nan", b"inf", b"1e-320",
               b"99999999999999999999", b"-99999999999999999999", b"9223372036854775808", b"-1",
               b"0", b"1.5", b"1_0", b"0x10", b"+3", b".", b"-", b"1e", b"2147483648", b"4294967296"]


@st.composite
def mutated(draw, fmt: str) -> bytes:
    """A valid file of ``fmt`` with 1-3 random mutations."""
    data = bytearray(draw(st.sampled_from(SEEDS[fmt])))
    for _ in range(draw(st.integers(1, 3))):
        kind = draw(st.sampled_from(["truncate", "flip", "bracket", "number", "dup_line", "del_line"]))
        if not data:
            break
        if kind == "truncate":
            data = data[:draw(st.integers(0, len(data) - 1))]
        elif kind == "flip":
            for _ in range(draw(st.integers(1, 4))):
                data[draw(st.integers(0, len(data) - 1))] = draw(st.integers(0, 255))
        elif kind == "bracket":
            where = [k for k, c in enumerate(data) if c in b"[]{}"]
            if where:
                del data[draw(st.sampled_from(where))]
        elif kind == "number":  # replace a number-like token by an odd one
            toks = [k for k in range(len(data)) if data[k:k + 1].isdigit()
                    and (k == 0 or data[k - 1:k] in b" \t\n,[-")]
            if toks:
                a = draw(st.sampled_from(toks))
                b = a
                while b < len(data) and data[b:b + 1] not in b" \t\r\n,]}/":
                    b += 1
                data[a:b] = draw(st.sampled_from(ODD_NUMBERS))
        else:
            lines = bytes(data).split(b"\n")
            k = draw(st.integers(0, len(lines) - 1))
            if kind == "dup_line":
                lines.insert(k, lines[k])
            else:
                del lines[k]
            data = bytearray(b"\n".join(lines))
    return bytes(data)


class _Timeout(Exception):
    pass


def _alarm(signum, frame):
    raise _Timeout


def read(path: Path, fmt: str):
    """Read ``path`` (a mesh, or .bnd landmarks) with a hard time limit: returns the result or
    the FacecorrError; anything else (another exception, a timeout) propagates."""
    old = signal.signal(signal.SIGALRM, _alarm)
    signal.setitimer(signal.ITIMER_REAL, TIME_LIMIT_S)
    try:
        if fmt == "bnd":
            return io.load_bnd(path)
        return io.load_mesh(path, units="mm")
    except FacecorrError as e:
        return e
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


def check(path: Path, fmt: str) -> str:
    """Read ``path`` and assert the outcome is allowed; returns the outcome's name."""
    try:
        out = read(path, fmt)
    except _Timeout:
        raise AssertionError(f"{fmt}: reading took more than {TIME_LIMIT_S} s") from None
    if isinstance(out, FacecorrError):
        msg = str(out)
        assert "\n" not in msg and len(msg) < 400, msg
        assert str(path) in msg, msg
        return type(out).__name__
    if fmt == "bnd":
        ids, pts = out
        assert ids.dtype == np.int64 and (ids >= 0).all()
        assert pts.shape == (len(ids), 3) and np.isfinite(pts).all()
        return "landmarks"
    assert isinstance(out, Mesh)
    V, F = out.vertices, out.faces
    assert V.ndim == 2 and V.shape[1] == 3 and len(V) > 0 and np.isfinite(V).all()
    assert F.ndim == 2 and F.shape[1] == 3 and len(F) > 0
    assert F.dtype.kind == "i" and F.min() >= 0 and F.max() < len(V)
    return "Mesh"


FUZZ = settings(max_examples=60, derandomize=True, deadline=int(TIME_LIMIT_S * 1000),
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
                database=None)


def _run(tmp_path, fmt, data):
    p = tmp_path / f"fuzz.{fmt}"
    p.write_bytes(data)
    check(p, fmt)


def test_seeds_are_valid(tmp_path):
    for fmt, seeds in SEEDS.items():
        for data in seeds:
            p = tmp_path / f"seed.{fmt}"
            p.write_bytes(data)
            assert check(p, fmt) in ("Mesh", "landmarks"), (fmt, read(p, fmt))


@pytest.mark.parametrize("fmt", sorted(SEEDS))
@FUZZ
@given(data=st.data())
def test_fuzz_reader(tmp_path, fmt, data):
    _run(tmp_path, fmt, data.draw(mutated(fmt)))
