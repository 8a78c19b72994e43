"""The Rust PLY fast path (``facecorr._core.read_ply``) against today's loader (trimesh).

On every layout it takes (binary both byte orders and ASCII; float or double coordinates; with or
without uchar RGB / RGBA colours; face lists with uint8 or int32 counts and int32 / uint32
indices; triangles or quads) the loaded mesh must be the one trimesh gives, bit for bit; on
every other file (mutated, broken, unusual) it must step aside, so the outcome (mesh or the
one-line error) is exactly trimesh's.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from facecorr import _core, io
from facecorr.errors import FacecorrError
from facecorr.io import load as load_module

sys.path.insert(0, str(Path(__file__).parent))
from test_io_fuzz import SEEDS, mutated  # noqa: E402

_TYPES = {"float": "f4", "double": "f8", "uchar": "u1", "int": "i4", "uint": "u4", "short": "i2"}


def make_ply(V, F, *, encoding="binary_little_endian", coord="float", colors=None, count="uchar", index="int",
             normals=False, extra_comment=None) -> bytes:
    """A PLY of (V, F) written by hand (not by our writer) in the layout asked for."""
    V = np.asarray(V, np.float64)
    F = np.asarray(F, np.int64)
    props = [(a, coord) for a in "xyz"] + ([(a, "float") for a in ("nx", "ny", "nz")] if normals else [])
    if colors is not None:
        props += [(c, "uchar") for c in ("red", "green", "blue", "alpha")[: colors.shape[1]]]
    head = ["ply", f"format {encoding} 1.0", "comment hand-made"] + ([extra_comment] if extra_comment else [])
    head += [f"element vertex {len(V)}"] + [f"property {t} {n}" for n, t in props]
    head += [f"element face {len(F)}", f"property list {count} {index} vertex_indices", "end_header"]
    cols = [V[:, 0], V[:, 1], V[:, 2]] + ([np.ones(len(V)) * 0.5] * 3 if normals else [])
    if colors is not None:
        cols += [colors[:, k] for k in range(colors.shape[1])]
    if encoding == "ascii":
        rows = [" ".join(repr(float(c[i])) if t in ("float", "double") else str(int(c[i]))
                         for c, (_, t) in zip(cols, props)) for i in range(len(V))]
        rows += [" ".join(map(str, [len(f), *f])) for f in F]
        return ("\n".join(head + rows) + "\n").encode()
    e = ">" if "big" in encoding else "<"
    vt = np.dtype([(n, e + _TYPES[t]) for n, t in props])
    va = np.empty(len(V), vt)
    for (n, _), c in zip(props, cols):
        va[n] = c
    ft = np.dtype([("n", e + _TYPES[count]), ("i", e + _TYPES[index], F.shape[1])])
    fa = np.empty(len(F), ft)
    fa["n"] = F.shape[1]
    fa["i"] = F
    return ("\n".join(head) + "\n").encode() + va.tobytes() + fa.tobytes()


def _mesh(seed=0, quads=False):
    rng = np.random.default_rng(seed)
    n = 12
    x, y = np.meshgrid(np.linspace(0, 110, n), np.linspace(0, 130, n))
    V = np.column_stack([x.ravel(), y.ravel(), 20 * np.sin(x.ravel() / 30) + rng.normal(0, 0.3, n * n)])
    V = V + rng.normal(0, 1e-3, V.shape)  # digits float32 cannot hold
    a = (np.arange(n - 1)[:, None] * n + np.arange(n - 1)[None, :]).ravel()
    F = np.column_stack([a, a + 1, a + n + 1, a + n]) if quads else np.vstack(
        [np.column_stack([a, a + 1, a + n + 1]), np.column_stack([a, a + n + 1, a + n])])
    colors = rng.integers(0, 256, (len(V), 4))
    return V, F, colors


def _trimesh_only(path):
    """(V, F, vertex colours) as today's loader reads the file (trimesh)."""
    V, F, app = load_module._read_trimesh(Path(path), "ply")
    return V, F, app.vertex_colors


def _fast(path):
    V, F, app = load_module._read_ply(Path(path))
    return V, F, app.vertex_colors


LAYOUTS = [dict(encoding=e, coord=c, count=n, index=i)
           for e in ("binary_little_endian", "binary_big_endian", "ascii")
           for c, n, i in (("float", "uchar", "int"), ("double", "int", "uint"), ("float", "int", "int"))]


@pytest.mark.parametrize("layout", LAYOUTS, ids=lambda d: "-".join(d.values()))
@pytest.mark.parametrize("colour", [None, 3, 4])
@pytest.mark.parametrize("quads", [False, True])
def test_same_mesh_as_trimesh(tmp_path, layout, colour, quads):
    V, F, C = _mesh(1, quads)
    p = tmp_path / "s.ply"
    p.write_bytes(make_ply(V, F, colors=None if colour is None else C[:, :colour], normals=quads, **layout))
    assert _core.read_ply(str(p)) is not None  # the fast path took it
    v0, f0, c0 = _trimesh_only(p)
    v1, f1, c1 = _fast(p)
    assert v1.dtype == np.float64 and f1.dtype == np.int64
    np.testing.assert_array_equal(v1, v0)
    np.testing.assert_array_equal(f1, f0)
    if colour is None:
        assert c0 is None and c1 is None
    else:
        np.testing.assert_array_equal(c1, c0)
    # and the whole loader (cleaning, units, colour renumbering) gives the same Mesh
    m1 = io.load_mesh(p)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(_core, "read_ply", lambda path: None)
        m0 = io.load_mesh(p)
    np.testing.assert_array_equal(m1.vertices, m0.vertices)
    np.testing.assert_array_equal(m1.faces, m0.faces)
    assert m1.meta == m0.meta and m1.units == m0.units
    if colour is not None:
        np.testing.assert_array_equal(m1.vertex_colors, m0.vertex_colors)


def test_our_writer_and_the_synthetic_scans_take_the_fast_path(tmp_path):
    V, F, _ = _mesh(2)
    io.save_mesh(tmp_path / "w.ply", (V, F))
    assert _core.read_ply(str(tmp_path / "w.ply")) is not None
    np.testing.assert_array_equal(io.load_mesh(tmp_path / "w.ply").vertices, V)


@pytest.mark.parametrize("change", [
    lambda b: b.replace(b"comment hand-made", b"comment TextureFile skin.png"),  # a texture
    lambda b: b.replace(b"element face", b"element edge 0\nelement face"),     # another element
    lambda b: b.replace(b"property uchar red", b"property float red"),         # float colours
    lambda b: b[:-1],                                                          # one byte short
    lambda b: b + b"\0",                                                       # one byte long
    lambda b: b.replace(b"vertex_indices", b"vertex_indices\nproperty uchar flags"),
])
def test_unusual_files_go_to_trimesh(tmp_path, change):
    V, F, C = _mesh(3)
    p = tmp_path / "u.ply"
    p.write_bytes(change(make_ply(V, F, colors=C[:, :3])))
    assert _core.read_ply(str(p)) is None


def _outcome(path, fast: bool):
    """What load_mesh makes of ``path``: ("ok", V, F, colours) or ("error", type, message)."""
    with pytest.MonkeyPatch.context() as mp:
        if not fast:
            mp.setattr(_core, "read_ply", lambda p: None)
        try:
            m = io.load_mesh(path)
        except FacecorrError as e:
            return ("error", type(e).__name__, str(e))
    return ("ok", m.vertices.tobytes(), m.faces.tobytes(), None if m.vertex_colors is None else m.vertex_colors.tobytes())


_MORE_SEEDS = []
for _kw in LAYOUTS[::2]:
    _V, _F, _C = _mesh(4, quads=_kw["encoding"] == "ascii")
    _MORE_SEEDS.append(make_ply(_V[:20] * (1.0 if _kw["coord"] == "double" else 1.0), _F[:6] % 20, colors=_C[:20, :3],
                                **_kw))


@st.composite
def _mutated_ply(draw):
    if draw(st.booleans()):
        return draw(mutated("ply"))
    data = bytearray(draw(st.sampled_from(_MORE_SEEDS)))
    for _ in range(draw(st.integers(1, 3))):
        k = draw(st.integers(0, len(data) - 1))
        kind = draw(st.sampled_from(["truncate", "flip", "insert"]))
        if kind == "truncate":
            data = data[:k]
        elif kind == "flip":
            data[k] = draw(st.integers(0, 255))
        else:
            data[k:k] = draw(st.sampled_from([b" ", b"\n", b"-1", b"1e999", b"nan", b"4 ", b"\r"]))
        if not data:
            break
    return bytes(data)


@settings(max_examples=150, deadline=None, derandomize=True, suppress_health_check=list(HealthCheck))
@given(data=_mutated_ply())
def test_mutated_files_same_outcome_as_trimesh(tmp_path_factory, data):
    """Fuzzed PLY files: the loader with the fast path gives exactly today's mesh or error."""
    assert SEEDS["ply"]
    p = tmp_path_factory.mktemp("fz") / "m.ply"
    p.write_bytes(data)
    assert _outcome(p, fast=True) == _outcome(p, fast=False)
