"""facecorr.io: round trips of every format, units, and every bad-input case (files in tmp_path)."""

import os

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings, strategies as st

import ref_mesh as R
from facecorr import io
from facecorr.errors import MeshError, MeshFileError, UnitsError
from facecorr.geometry.mesh import Mesh


def face_like():
    """A 160 mm sphere patch: plausible face size in mm."""
    V, F = R.sphere(80.0, 2)
    return V, F


EXACT = {".ply", ".obj", ".off", ".wrl", ".vrml"}  # float64 text/binary
FLOAT32 = {".stl", ".glb"}  # formats that store float32


@pytest.mark.parametrize("ext", sorted(EXACT | FLOAT32))
def test_round_trip_every_format(tmp_path, ext):
    V, F = face_like()
    p = tmp_path / f"m{ext}"
    io.save_mesh(p, Mesh(V, F))
    m = io.load_mesh(p)
    assert m.units == "mm" and m.to_mm == 1.0 and m.meta["units_inferred"]
    assert m.meta["n_components"] == 1 and m.meta["n_degenerate_faces_dropped"] == 0
    tol = 0 if ext in EXACT else 1e-4  # float32 of ~80 mm: ~5e-6 mm
    if ext == ".stl":  # STL stores triangles only: vertex ids come from merging, order by first use
        assert m.meta["n_duplicate_vertices_merged"] == 3 * len(F) - len(V)
        np.testing.assert_allclose(m.vertices[m.faces], V[F], atol=tol, rtol=0)
    else:
        assert m.meta["n_duplicate_vertices_merged"] == 0
        np.testing.assert_allclose(m.vertices, V, atol=tol, rtol=0)
        np.testing.assert_array_equal(m.faces, F)


@pytest.mark.parametrize("units,factor", [("cm", 10.0), ("m", 1000.0), ("mm", 1.0)])
@pytest.mark.parametrize("ext", [".ply", ".obj", ".wrl"])
def test_units_auto_and_back(tmp_path, units, factor, ext):
    V, F = face_like()  # mm
    p = tmp_path / f"m{ext}"
    io.save_mesh(p, (V, F), units=units)  # file in `units`
    raw = io.load_mesh(p, units="mm")
    np.testing.assert_allclose(raw.vertices, V / factor, rtol=1e-12)
    m = io.load_mesh(p)  # auto
    assert m.units == units and m.to_mm == factor
    np.testing.assert_allclose(m.vertices, V, rtol=1e-12)
    np.testing.assert_allclose(m.to_source_units(m.vertices), V / factor, rtol=1e-12)
    # written back in the scan's own units by default
    q = tmp_path / f"back{ext}"
    io.save_mesh(q, m)
    np.testing.assert_allclose(io.load_mesh(q, units="mm").vertices, V / factor, rtol=1e-12)
    # explicit units override the file's size
    assert io.load_mesh(p, units="cm").to_mm == 10.0


@pytest.mark.parametrize("size", [0.01, 2.0, 5000.0])
def test_units_implausible_size(tmp_path, size):
    V, F = face_like()
    p = tmp_path / "m.ply"
    io.save_mesh(p, (V / 160.0 * size, F))
    with pytest.raises(UnitsError, match="cannot infer units"):
        io.load_mesh(p)
    assert io.load_mesh(p, units="mm").units == "mm"


def test_infer_units_thresholds():
    box = lambda s: np.array([[0, 0, 0], [s, s / 2, s / 3]], float)  # noqa: E731
    assert [io.infer_units(box(s)) for s in (0.03, 0.2, 1.0, 3.0, 25.0, 59.9, 60.0, 200.0, 1000.0)] == \
        ["m", "m", "m", "cm", "cm", "cm", "mm", "mm", "mm"]
    for s in (0.029, 1.5, 1001.0):
        with pytest.raises(UnitsError):
            io.infer_units(box(s))


def test_unknown_units(tmp_path):
    V, F = face_like()
    p = tmp_path / "m.ply"
    io.save_mesh(p, (V, F))
    with pytest.raises(UnitsError, match="unknown units"):
        io.load_mesh(p, units="inch")
    with pytest.raises(UnitsError, match="unknown units"):
        io.save_mesh(tmp_path / "n.ply", (V, F), units="ft")
    assert not (tmp_path / "n.ply").exists()


# ----------------------------------------------------------------------------- bad files


def one_line(e):
    s = str(e.value)
    assert "\n" not in s and len(s) < 300
    return s


def test_missing_file(tmp_path):
    with pytest.raises(MeshFileError, match="no such file") as e:
        io.load_mesh(tmp_path / "nope.ply")
    one_line(e)


def test_directory(tmp_path):
    d = tmp_path / "dir.obj"
    d.mkdir()
    with pytest.raises(MeshFileError, match="directory"):
        io.load_mesh(d)


def test_unreadable_file(tmp_path, monkeypatch):
    p = tmp_path / "m.ply"
    io.save_mesh(p, face_like())

    def denied(*a, **k):
        raise PermissionError(13, "Permission denied")

    from facecorr.io import load as io_load  # the module whose open() the readability check uses

    monkeypatch.setattr(io_load, "open", denied, raising=False)  # root ignores chmod; simulate it
    with pytest.raises(MeshFileError, match="cannot read: Permission denied"):
        io.load_mesh(p)


@pytest.mark.parametrize("name", ["scan.xyz", "scan", "scan.ply.gz"])
def test_unknown_format(tmp_path, name):
    p = tmp_path / name
    p.write_text("1 2 3\n")
    with pytest.raises(MeshFileError, match="unknown mesh format") as e:
        io.load_mesh(p)
    one_line(e)
    with pytest.raises(MeshFileError, match="unknown mesh format"):
        io.save_mesh(p, face_like())


@pytest.mark.parametrize("ext", sorted(EXACT | FLOAT32))
def test_zero_byte_file(tmp_path, ext):
    p = tmp_path / f"e{ext}"
    p.write_bytes(b"")
    with pytest.raises(MeshFileError, match="empty"):
        io.load_mesh(p)


EMPTY_MESHES = {
    "e.off": "OFF\n0 0 0\n",
    "e.ply": "ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nproperty float y\n"
             "property float z\nelement face 0\nproperty list uchar int vertex_indices\nend_header\n",
    "e.wrl": "#VRML V2.0 utf8\nShape { geometry IndexedFaceSet { coord Coordinate { point [ ] } "
             "coordIndex [ ] } }\n",
    "f.wrl": "#VRML V2.0 utf8\nWorldInfo { title \"nothing\" }\n",
    "e.obj": "# nothing\n",
}


@pytest.mark.parametrize("name", sorted(EMPTY_MESHES))
def test_empty_mesh(tmp_path, name):
    p = tmp_path / name
    p.write_text(EMPTY_MESHES[name])
    with pytest.raises(MeshError, match="empty") as e:
        io.load_mesh(p)
    one_line(e)


POINT_CLOUDS = {
    "pc.ply": "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
              "property float z\nend_header\n0 0 0\n100 0 0\n0 100 0\n",
    "pc.obj": "v 0 0 0\nv 100 0 0\nv 0 100 0\n",
    "pc.off": "OFF\n3 0 0\n0 0 0\n100 0 0\n0 100 0\n",
    "pc.wrl": "#VRML V2.0 utf8\nShape { geometry IndexedFaceSet { coord Coordinate { point "
              "[ 0 0 0, 100 0 0, 0 100 0 ] } } }\n",
}


@pytest.mark.parametrize("name", sorted(POINT_CLOUDS))
def test_point_cloud(tmp_path, name):
    p = tmp_path / name
    p.write_text(POINT_CLOUDS[name])
    with pytest.raises(MeshError, match="point cloud without faces"):
        io.load_mesh(p)


def tri_files(x):
    """One triangle with the coordinate token x, in several formats."""
    return {
        "t.obj": f"v {x} 0 0\nv 100 0 0\nv 0 100 0\nf 1 2 3\n",
        "t.ply": "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                 "property float z\nelement face 1\nproperty list uchar int vertex_indices\n"
                 f"end_header\n{x} 0 0\n100 0 0\n0 100 0\n3 0 1 2\n",
        "t.wrl": "#VRML V2.0 utf8\nShape { geometry IndexedFaceSet { coord Coordinate { point "
                 f"[ {x} 0 0, 100 0 0, 0 100 0 ] }} coordIndex [ 0 1 2 -1 ] }} }}\n",
        "t.off": f"OFF\n3 1 0\n{x} 0 0\n100 0 0\n0 100 0\n3 0 1 2\n",
    }


@pytest.mark.parametrize("token", ["nan", "inf", "-inf"])
@pytest.mark.parametrize("name", ["t.obj", "t.ply", "t.wrl", "t.off"])
def test_nan_inf(tmp_path, token, name):
    p = tmp_path / name
    p.write_text(tri_files(token)[name])
    with pytest.raises(MeshError, match="NaN or infinite") as e:
        io.load_mesh(p, units="mm")
    one_line(e)


OUT_OF_RANGE = {
    "o.obj": "v 0 0 0\nv 100 0 0\nv 0 100 0\nf 1 2 9\n",
    "o.ply": "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
             "property float z\nelement face 1\nproperty list uchar int vertex_indices\n"
             "end_header\n0 0 0\n100 0 0\n0 100 0\n3 0 1 7\n",
    "o.wrl": "#VRML V2.0 utf8\nShape { geometry IndexedFaceSet { coord Coordinate { point "
             "[ 0 0 0, 100 0 0, 0 100 0 ] } coordIndex [ 0 1 5 -1 ] } }\n",
    "n.wrl": "#VRML V2.0 utf8\nShape { geometry IndexedFaceSet { coord Coordinate { point "
             "[ 0 0 0, 100 0 0, 0 100 0 ] } coordIndex [ 0 -3 2 -1 ] } }\n",
    "o.off": "OFF\n3 1 0\n0 0 0\n100 0 0\n0 100 0\n3 0 1 3\n",
}


@pytest.mark.parametrize("name", sorted(OUT_OF_RANGE))
def test_out_of_range_indices(tmp_path, name):
    p = tmp_path / name
    p.write_text(OUT_OF_RANGE[name])
    with pytest.raises(MeshError, match="out") as e:
        io.load_mesh(p, units="mm")
    one_line(e)


def test_degenerate_duplicates_and_pieces(tmp_path):
    # square (2 triangles) + a vertex duplicated + a zero-area triangle + a repeated-index triangle
    # + the same triangle twice + a separate small triangle
    p = tmp_path / "d.obj"
    p.write_text("\n".join([
        "v 0 0 0", "v 100 0 0", "v 100 100 0", "v 0 100 0",
        "v 100 0 0",  # 5 = duplicate of 2
        "v 50 0 0",  # 6 on the edge 1-2: (1, 6, 2) has zero area
        "v 200 0 0", "v 210 0 0", "v 200 10 0",  # separate piece
        "f 1 2 3", "f 1 3 4", "f 1 6 5", "f 1 1 3", "f 3 4 1", "f 7 8 9", "",
    ]))
    m = io.load_mesh(p, units="mm")
    assert m.meta["n_duplicate_vertices_merged"] == 1
    assert m.meta["n_degenerate_faces_dropped"] == 2
    assert m.meta["n_duplicate_faces_dropped"] == 1
    assert m.meta["n_components"] == 2
    assert m.n_vertices == 8 and m.n_faces == 3
    np.testing.assert_array_equal(m.vertices[:4], [[0, 0, 0], [100, 0, 0], [100, 100, 0], [0, 100, 0]])
    big, old = m.largest_component()
    assert big.n_faces == 2 and set(old.tolist()) == {0, 1, 2, 3}


def test_all_faces_degenerate(tmp_path):
    p = tmp_path / "z.obj"
    p.write_text("v 0 0 0\nv 100 0 0\nv 200 0 0\nf 1 2 3\nf 1 1 2\n")
    with pytest.raises(MeshError, match="all 2 faces are degenerate"):
        io.load_mesh(p, units="mm")


def test_merge_duplicates_can_be_turned_off(tmp_path):
    V, F = face_like()
    p = tmp_path / "s.stl"
    io.save_mesh(p, (V, F))
    m = io.load_mesh(p, merge_duplicates=False)
    assert m.n_vertices == 3 * len(F) and m.meta["n_duplicate_vertices_merged"] == 0


def truncations(tmp_path, ext):
    V, F = face_like()
    p = tmp_path / f"full{ext}"
    io.save_mesh(p, (V, F))
    data = p.read_bytes()
    return data


@pytest.mark.parametrize("ext", [".ply", ".stl", ".glb", ".obj", ".off", ".wrl"])
@pytest.mark.parametrize("frac", [0.05, 0.5, 0.97])
def test_truncated_files(tmp_path, ext, frac):
    data = truncations(tmp_path, ext)
    p = tmp_path / f"cut{ext}"
    p.write_bytes(data[: int(len(data) * frac)])
    if ext == ".obj":
        # OBJ has no length or closing token: a cut between lines is a smaller valid mesh; a cut
        # inside a face line leaves a short face, which must still be a typed error or a mesh.
        try:
            m = io.load_mesh(p, units="mm")
            assert m.n_faces > 0
        except (MeshError, MeshFileError) as e:
            assert "\n" not in str(e)
        return
    with pytest.raises((MeshFileError, MeshError)) as e:
        io.load_mesh(p, units="mm")
    one_line(e)
    if ext in (".ply", ".stl", ".glb", ".wrl"):
        assert e.type is MeshFileError


GARBAGE = [b"\x00\xff\x13garbage" * 50, b"ply\nformat ascii 1.0\nelement vertex 3\nend_header\n1 2",
           b"solid x\nfacet normal 0 0 1\nouter loop\nvertex 1 2\n", b"glTF\x02\x00\x00\x00xx",
           b"OFF\n3 1\n0 0 0\n1 1\n"]


@pytest.mark.parametrize("ext", [".ply", ".stl", ".glb", ".off", ".obj", ".wrl"])
@pytest.mark.parametrize("k", range(len(GARBAGE)))
def test_garbage_never_leaks_a_trimesh_traceback(tmp_path, ext, k):
    p = tmp_path / f"g{ext}"
    p.write_bytes(GARBAGE[k])
    with pytest.raises((MeshFileError, MeshError)) as e:
        io.load_mesh(p, units="mm")
    one_line(e)


# ----------------------------------------------------------------------------- VRML


BU3DFE_LIKE = """#VRML V2.0 utf8
# BU-3DFE-like file: comments, texture and normal nodes, several shapes, quads
WorldInfo { title "F0001_NE00WH_F3D" info [ "not # a comment" ] }
Transform {
  children [
    Shape {
      appearance Appearance { texture ImageTexture { url "F0001_NE00WH_F3D.bmp" } }
      geometry DEF IFS IndexedFaceSet {
        solid FALSE  creaseAngle 0.5
        coord DEF C Coordinate { point [ 0 0 0, 100 0 0, 100 100 0, # a comment
                                         0 100 0 ] }
        texCoord TextureCoordinate { point [ 0 0, 1 0, 1 1, 0 1 ] }
        texCoordIndex [ 0 1 2 3 -1 ]
        normal Normal { vector [ 0 0 1 ] }
        coordIndex [ 0, 1, 2, 3, -1 ]
      }
    }
    Shape { geometry IndexedFaceSet {
        coord Coordinate { point [ 200 0 0 210 0 0 210 10 0 200 10 0 205 15 0 ] }
        coordIndex [ 0 1 2 3 4 -1 0 1 -1 ]  color Color { color [ 1 0 0 ] } } }
  ]
}
Transform { translation 0 0 50 scale 2 2 2
  children Shape { geometry IndexedFaceSet { ccw FALSE coord Coordinate { point [ 0 0 0 10 0 0 0 10 0 ] }
                                            coordIndex [ 0 1 2 ] } } }
ROUTE a.b TO c.d
"""


def test_wrl_bu3dfe_like(tmp_path):
    p = tmp_path / "F0001_NE00WH_F3D.wrl"
    p.write_text(BU3DFE_LIKE)
    V, F = io.read_wrl(p)
    assert len(V) == 4 + 5 + 3
    # quad -> 2 fans, pentagon -> 3 fans, a 2-gon kept as degenerate, the last triangle flipped
    np.testing.assert_array_equal(F[:2], [[0, 1, 2], [0, 2, 3]])
    np.testing.assert_array_equal(F[2:5], [[4, 5, 6], [4, 6, 7], [4, 7, 8]])
    np.testing.assert_array_equal(F[-1], [11, 10, 9])
    np.testing.assert_allclose(V[9:], [[0, 0, 50], [20, 0, 50], [0, 20, 50]])  # transform applied
    m = io.load_mesh(p, units="mm")
    assert m.meta["n_degenerate_faces_dropped"] == 1
    assert m.meta["n_components"] == 3 and m.n_faces == 6


def test_wrl_def_use_and_rotation(tmp_path):
    p = tmp_path / "r.wrl"
    p.write_text("#VRML V2.0 utf8\n"
                 "Shape { geometry IndexedFaceSet { coord DEF C Coordinate { point [ 0 0 0, 100 0 0, 0 100 0 ] }"
                 " coordIndex [ 0 1 2 -1 ] } }\n"
                 "Transform { rotation 0 0 1 1.5707963267948966 translation 0 0 10"
                 " children [ Shape { geometry IndexedFaceSet { coord USE C coordIndex [ 0 1 2 -1 ] } } ] }\n")
    V, F = io.read_wrl(p)
    np.testing.assert_allclose(V[3:], [[0, 0, 10], [0, 100, 10], [-100, 0, 10]], atol=1e-12)
    np.testing.assert_array_equal(F, [[0, 1, 2], [3, 4, 5]])


@pytest.mark.parametrize("text,match", [
    ("#VRML V1.0 ascii\nSeparator { }\n", "only VRML 2.0"),
    ("Shape { }\n", "not a VRML file"),
    ("#VRML V2.0 utf8\nShape { geometry IndexedFaceSet { coord Coordinate { point [ 0 0 x ] } } }\n",
     "unexpected 'x' in point"),
    ("#VRML V2.0 utf8\nShape { geometry IndexedFaceSet { coord Coordinate { point [ 0 0 1.2.3 ] } } }\n",
     "'1.2.3' is not a number"),
    ("#VRML V2.0 utf8\nShape { geometry IndexedFaceSet { coord Coordinate { point [ 0 0 0 1 ] } } }\n",
     "not a multiple of 3"),
    ("#VRML V2.0 utf8\nShape { geometry IndexedFaceSet { coord Coordinate { point [ 0 0 0 ] }"
     " coordIndex [ 0 0.5 ] } }\n", "not an integer"),
    ("#VRML V2.0 utf8\nShape { geometry IndexedFaceSet { coord USE NOPE } }\n", "undefined name"),
    ("#VRML V2.0 utf8\nShape { geometry IndexedFaceSet { coord Coordinate { point [ 0 0 0 ",
     "end of file"),
    ("#VRML V2.0 utf8\nShape { geometry IndexedFaceSet { } } }\n", "line 2"),
])
def test_wrl_broken(tmp_path, text, match):
    p = tmp_path / "b.wrl"
    p.write_text(text)
    with pytest.raises(MeshFileError, match=match) as e:
        io.load_mesh(p, units="mm")
    one_line(e)


# ----------------------------------------------------------------------------- .bnd


def test_bnd(tmp_path):
    p = tmp_path / "F0001_NE00WH_F3D.bnd"
    p.write_text("# landmarks\n8017  -55.0880 31.4430 58.2150\n\n 2  1e1 -2.5 3\n44.000000 0 0 0\n")
    ids, pts = io.load_bnd(p)
    np.testing.assert_array_equal(ids, [8017, 2, 44])
    np.testing.assert_allclose(pts, [[-55.088, 31.443, 58.215], [10, -2.5, 3], [0, 0, 0]])
    assert ids.dtype == np.int64 and pts.shape == (3, 3)
    _, cm = io.load_bnd(p, to_mm=10.0)
    np.testing.assert_allclose(cm, pts * 10)


@pytest.mark.parametrize("text,match", [
    ("1 2 3\n", "line 1: expected 'index x y z'"),
    ("1 2 3 4\n5 a 1 2\n", "line 2: not numbers"),
    ("1.5 0 0 0\n", "not a non-negative integer"),
    ("-1 0 0 0\n", "not a non-negative integer"),
    ("1 0 nan 0\n", "NaN or infinite"),
    ("# only a comment\n\n", "no landmarks"),
])
def test_bnd_bad(tmp_path, text, match):
    p = tmp_path / "x.bnd"
    p.write_text(text)
    with pytest.raises(MeshFileError, match=match) as e:
        io.load_bnd(p)
    one_line(e)


def test_bnd_missing(tmp_path):
    with pytest.raises(MeshFileError, match="no such file"):
        io.load_bnd(tmp_path / "x.bnd")


# ----------------------------------------------------------------------------- save errors


def test_save_errors_leave_no_file(tmp_path):
    V, F = face_like()
    with pytest.raises(MeshFileError, match="does not exist"):
        io.save_mesh(tmp_path / "no" / "m.ply", (V, F))
    with pytest.raises(MeshError):
        io.save_mesh(tmp_path / "m.ply", (V, F + 10_000))
    with pytest.raises(MeshError, match="Mesh or a"):
        io.save_mesh(tmp_path / "m.ply", V)
    assert os.listdir(tmp_path) == []


def test_write_bytes_atomic_failure_is_mesh_file_error_and_leaves_nothing(tmp_path):
    from facecorr.io.atomic import write_bytes_atomic

    (tmp_path / "d.ply").mkdir()  # the rename onto a directory fails
    with pytest.raises(MeshFileError, match="cannot write") as e:
        write_bytes_atomic(tmp_path / "d.ply", b"ply\n")
    one_line(e)
    assert os.listdir(tmp_path) == ["d.ply"] and os.listdir(tmp_path / "d.ply") == []
    with pytest.raises(MeshFileError, match="does not exist"):
        write_bytes_atomic(tmp_path / "no" / "x.bin", b"x")
    write_bytes_atomic(tmp_path / "x.bin", b"\x00\x01")
    assert (tmp_path / "x.bin").read_bytes() == b"\x00\x01"


# ----------------------------------------------------------------------------- hypothesis


@st.composite
def random_meshes(draw):
    n = draw(st.integers(3, 25))
    coords = draw(st.lists(st.floats(-500, 500, allow_nan=False, allow_infinity=False, width=64),
                           min_size=3 * n, max_size=3 * n))
    V = np.array(coords).reshape(n, 3)
    m = draw(st.integers(1, 30))
    F = np.array([draw(st.lists(st.integers(0, n - 1), min_size=3, max_size=3, unique=True))
                  for _ in range(m)])
    assume(len(np.unique(V, axis=0)) == n)  # no duplicate vertices (they would be merged)
    a, b, c = (V[F[:, k]] for k in range(3))
    diag = np.linalg.norm(V.max(0) - V.min(0))
    assume((np.linalg.norm(np.cross(b - a, c - a), axis=1) > 1e-9 * diag * diag).all())
    assume(len(np.unique(np.sort(F, axis=1), axis=0)) == len(F))  # no repeated triangles
    return V, F


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.filter_too_much,
                                                                  HealthCheck.function_scoped_fixture])
@given(mesh=random_meshes(), ext=st.sampled_from([".ply", ".obj", ".wrl", ".off"]))
def test_hypothesis_round_trip(tmp_path, mesh, ext):
    V, F = mesh
    p = tmp_path / f"h{ext}"
    io.save_mesh(p, (V, F))
    m = io.load_mesh(p, units="mm")
    # vertex order kept, coordinates exact (PLY float64, OBJ repr, WRL %.17g)
    np.testing.assert_array_equal(m.vertices, V)
    np.testing.assert_array_equal(m.faces, F)
    assert m.meta["n_degenerate_faces_dropped"] == 0 and m.meta["n_duplicate_vertices_merged"] == 0


def test_saved_file_has_umask_permissions(tmp_path):
    old = os.umask(0o022)
    try:
        io.save_mesh(tmp_path / "m.ply", face_like())
    finally:
        os.umask(old)
    assert (tmp_path / "m.ply").stat().st_mode & 0o777 == 0o644
    assert os.listdir(tmp_path) == ["m.ply"]


@pytest.mark.parametrize("where,bad,match", [("point", "1.2.3", "'1.2.3' is not a number in point"),
                                             ("coordIndex", "0.5", "'0.5' is not an integer in coordIndex"),
                                             ("point", "nan 0 0", "NaN or infinite")])
def test_wrl_big_arrays_fast_path_errors(tmp_path, where, bad, match):
    """Long number lists take a vectorised path; its errors still name the value and the line."""
    V, F = R.sphere(80.0, 3)  # 642 vertices: lists of > 1000 characters
    p = tmp_path / "big.wrl"
    io.save_mesh(p, (V, F))
    text = p.read_text()
    at = text.index(f"{where} [") + 3000
    at = text.index(",", at) + 1
    lines_before = text.count("\n", 0, at) + 1
    p.write_text(text[:at] + f" {bad} " + text[at:])
    with pytest.raises((MeshFileError, MeshError), match=match) as e:
        io.load_mesh(p, units="mm")
    if not bad.startswith("nan"):
        assert f"line {lines_before}:" in str(e.value)
    # and the intact file reads back exactly through the same path
    p.write_text(text)
    m = io.load_mesh(p, units="mm")
    np.testing.assert_array_equal(m.vertices, V)


def test_glb_scene_with_two_meshes_and_a_transform(tmp_path):
    import trimesh

    V, F = face_like()
    scene = trimesh.Scene()
    scene.add_geometry(trimesh.Trimesh(V, F, process=False), node_name="a", geom_name="a")
    T = np.eye(4)
    T[:3, 3] = [500.0, 0, 0]
    small = trimesh.Trimesh(V[:3] * 0.1, [[0, 1, 2]], process=False)
    scene.add_geometry(small, node_name="b", geom_name="b", transform=T)
    p = tmp_path / "s.glb"
    p.write_bytes(scene.export(file_type="glb"))
    m = io.load_mesh(p, units="mm")
    assert m.n_faces == len(F) + 1 and m.meta["n_components"] == 2
    big, old = m.largest_component()
    assert big.n_faces == len(F)
    far = m.vertices[m.components == 1]
    np.testing.assert_allclose(far, V[:3] * 0.1 + [500.0, 0, 0], atol=1e-4)  # transform applied


def test_obj_with_texture_coordinates_keeps_vertex_order(tmp_path):
    p = tmp_path / "t.obj"
    p.write_text("v 0 0 0\nv 100 0 0\nv 100 100 0\nv 0 100 0\nv 50 50 30\n"
                 "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nvt 0.5 0.5\n"
                 "f 1/1 2/2 5/5\nf 2/2 3/3 5/5\nf 3/3 4/4 5/5\nf 4/4 1/1 5/5\n")
    m = io.load_mesh(p, units="mm")
    np.testing.assert_array_equal(m.vertices, [[0, 0, 0], [100, 0, 0], [100, 100, 0], [0, 100, 0], [50, 50, 30]])
    np.testing.assert_array_equal(m.faces, [[0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4]])


def test_polygons_are_triangulated(tmp_path):
    p = tmp_path / "q.ply"
    p.write_text("ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\n"
                 "property float z\nelement face 1\nproperty list uchar int vertex_indices\n"
                 "end_header\n0 0 0\n100 0 0\n100 100 0\n0 100 0\n4 0 1 2 3\n")
    m = io.load_mesh(p, units="mm")
    assert m.n_faces == 2 and np.isclose(m.face_areas.sum(), 100 * 100)
    q = tmp_path / "q.off"
    q.write_text("OFF\n4 1 0\n0 0 0\n100 0 0\n100 100 0\n0 100 0\n4 0 1 2 3\n")
    m = io.load_mesh(q, units="mm")
    assert m.n_faces == 2 and np.isclose(m.face_areas.sum(), 100 * 100)


@pytest.mark.parametrize("ext", sorted(EXACT))
def test_tiny_and_huge_coordinates_round_trip_exactly(tmp_path, ext):
    """Fixed-point writers would turn 1e-308 into 0 (a duplicate vertex); ours write repr digits."""
    V = np.array([[0, 0, 0], [0, 100, 0], [0, 0, 100], [1.1125369292536007e-308, 0, 0],
                  [123.456789012345678, -9.87654321e-12, 5e2]])
    F = np.array([[0, 1, 2], [3, 1, 2], [4, 1, 2]])
    p = tmp_path / f"x{ext}"
    io.save_mesh(p, (V, F))
    m = io.load_mesh(p, units="mm")
    np.testing.assert_array_equal(m.vertices, V)
    assert m.meta["n_duplicate_vertices_merged"] == 0


def test_units_inferred_from_the_largest_piece(tmp_path):
    """Debris 2 m away must not turn a face in mm into an implausible size."""
    V, F = face_like()
    V2 = np.vstack([V, [[2000, 0, 0], [2001, 0, 0], [2000, 1, 0]]])
    F2 = np.vstack([F, [[len(V), len(V) + 1, len(V) + 2]]])
    p = tmp_path / "debris.ply"
    io.save_mesh(p, (V2, F2))
    m = io.load_mesh(p)
    assert m.units == "mm" and m.meta["n_components"] == 2
    np.testing.assert_array_equal(m.components, R.components(m.vertices, m.faces))
    q = tmp_path / "debris_m.ply"
    io.save_mesh(q, (V2, F2), units="m")
    assert io.load_mesh(q).units == "m"


# ----------------------------------------------------------------------------- careful-user inputs

SQUARE_V = "v 0 0 0\nv 100 0 0\nv 0 100 0\nv 100 100 0\n"
SQUARE_OBJ = SQUARE_V + "f 1 2 3\nf 2 4 3\n"
SQUARE_OFF = "OFF\n4 2 0\n0 0 0\n100 0 0\n0 100 0\n100 100 0\n3 0 1 2\n3 1 3 2\n"
SQUARE_PLY = ("ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\n"
              "property float z\nelement face 2\nproperty list uchar int vertex_indices\nend_header\n"
              "0 0 0\n100 0 0\n0 100 0\n100 100 0\n3 0 1 2\n3 1 3 2\n")
SQUARE_VERTS = [[0, 0, 0], [100, 0, 0], [0, 100, 0], [100, 100, 0]]
SQUARE_FACES = [[0, 1, 2], [1, 3, 2]]


def load_bytes(tmp_path, name, data, **kw):
    p = tmp_path / name
    p.write_bytes(data if isinstance(data, bytes) else data.encode())
    return io.load_mesh(p, units="mm", **kw)


def assert_square(m):
    np.testing.assert_array_equal(m.vertices, SQUARE_VERTS)
    np.testing.assert_array_equal(m.faces, SQUARE_FACES)


def test_obj_relative_indices_load_like_absolute(tmp_path):
    """OBJ spec: -1 is the last vertex defined so far (was read as a single face)."""
    rel = "v 0 0 0\nv 100 0 0\nv 0 100 0\nf -3 -2 -1\nv 100 100 0\nf -3 -1 -2\n"
    assert_square(load_bytes(tmp_path, "rel.obj", rel))
    # with texture / normal indices, and mixed with absolute indices
    rel_vt = ("v 0 0 0\nv 100 0 0\nv 0 100 0\nvt 0 0\nvt 1 0\nvt 0 1\nvn 0 0 1\n"
              "f -3/-3/-1 -2/-2/-1 -1/-1/-1\nv 100 100 0\nf 2//1 -1//1 3//1\n")
    assert_square(load_bytes(tmp_path, "relvt.obj", rel_vt))
    with pytest.raises(MeshError, match="relative face index -4 is out of range") as e:
        load_bytes(tmp_path, "relbad.obj", "v 0 0 0\nv 100 0 0\nv 0 100 0\nf -4 -2 -1\n")
    one_line(e)


def test_obj_texture_and_normal_indices(tmp_path):
    obj = (SQUARE_V + "vt 0 0\nvt 1 0\nvt 0 1\nvn 0 0 1\n"
           "o part\ng grp\nusemtl skin\ns 1\nf 1/1/1 2/2/1 3/3/1\nf 2//1 4//1 3//1\nl 1 2\n")
    assert_square(load_bytes(tmp_path, "vt.obj", obj))


def test_obj_non_utf8_comment(tmp_path):
    """Was 'ModuleNotFoundError: No module named charset_normalizer' (trimesh guessing the encoding)."""
    assert_square(load_bytes(tmp_path, "l1.obj", b"# caf\xe9 scan \xff\xfe\n" + SQUARE_OBJ.encode()
                             + b"g t\xeate\n"))


@pytest.mark.parametrize("name,text,bom", [("c.obj", SQUARE_OBJ, False), ("c.off", SQUARE_OFF, False),
                                           ("c.ply", SQUARE_PLY, False), ("c.obj", SQUARE_OBJ, True),
                                           ("c.off", SQUARE_OFF, True)])  # a PLY starts with 'ply'
def test_crlf_and_bom(tmp_path, name, text, bom):
    data = text.replace("\n", "\r\n").encode()
    assert_square(load_bytes(tmp_path, name, (b"\xef\xbb\xbf" if bom else b"") + data))
    if bom:  # BOM with LF line endings too (was 'face indices out of range' for OBJ)
        assert_square(load_bytes(tmp_path, name, b"\xef\xbb\xbf" + text.encode()))


def test_obj_polygons_and_line_continuation(tmp_path):
    m = load_bytes(tmp_path, "q.obj", "v 0 0 0\nv 100 0 0\nv 100 100 0\nv 0 100 0\nf 1 2 \\\n 3 4\n")
    np.testing.assert_array_equal(m.faces, [[0, 1, 2], [0, 2, 3]])


@pytest.mark.parametrize("name,data,match", [
    ("gz.obj", "gzip", "gzip-compressed data"),
    ("png.ply", b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR" + bytes(60), "PNG image"),
    ("zip.off", b"PK\x03\x04" + bytes(60), "ZIP archive"),
    ("jpg.wrl", b"\xff\xd8\xff\xe0" + bytes(60), "JPEG image"),
    ("nul.obj", b"v 0 0 0\x00\x00\nf 1 2 3\n", "binary data"),
])
def test_misnamed_files(tmp_path, name, data, match):
    import gzip

    if data == "gzip":
        data = gzip.compress(SQUARE_OBJ.encode())
    with pytest.raises(MeshFileError, match=match) as e:
        load_bytes(tmp_path, name, data)
    assert name in one_line(e)


@pytest.mark.parametrize("name,text,exc,match", [
    ("e.obj", "", MeshFileError, "empty"),
    ("e2.obj", "# only a comment\r\n\r\n", MeshError, "empty"),
    ("vo.obj", SQUARE_V, MeshError, "point cloud without faces"),
    ("oor.obj", SQUARE_V + "f 1 2 9\n", MeshError, r"face 0 has vertex indices \[0, 1, 8\] outside"),
    ("zero.obj", SQUARE_V + "f 0 1 2\n", MeshError, "index 0 is out of range"),
    ("huge.obj", SQUARE_V + "f 1 2 99999999999999999999999\n", MeshError, "out of range"),
    ("oor.off", SQUARE_OFF.replace("3 1 3 2", "3 1 7 2"), MeshError, "outside"),
    ("neg.off", SQUARE_OFF.replace("3 1 3 2", "3 1 -1 2"), MeshError, "outside"),
    ("fl.obj", SQUARE_V + "f 1.5 2 3\n", MeshFileError, "'1.5' is not an integer index"),
    ("fl2.obj", SQUARE_V + "f 1.0/1 2 3\n", MeshFileError, "'1.0/1' is not an integer index"),
    ("fl.off", SQUARE_OFF.replace("3 1 3 2", "3 1.5 3 2"), MeshFileError, "face 1 is not integers"),
    ("fln.off", SQUARE_OFF.replace("3 1 3 2", "3.0 1 3 2"), MeshFileError, "face 1 is not integers"),
    ("v2.obj", "v 1 2\nf 1 1 1\n", MeshFileError, "line 1: a vertex needs x y z"),
    ("vx.obj", "v 1 2 x\n", MeshFileError, "line 1: not numbers"),
    ("4off.off", "4OFF\n1 0 0\n1 2 3 4\n", MeshFileError, "unsupported OFF variant"),
])
def test_careful_user_bad_text_meshes(tmp_path, name, text, exc, match):
    with pytest.raises(exc, match=match) as e:
        load_bytes(tmp_path, name, text)
    assert name in one_line(e)


def test_obj_float_index_is_refused_not_truncated(tmp_path):
    """'f 1.5 2 3' must not be read as 'f 1 2 3'."""
    with pytest.raises(MeshFileError):
        load_bytes(tmp_path, "f.obj", SQUARE_V + "f 1.5 2 3\nf 2 4 3\n")


# ----------------------------------------------------------------------------- fuzzer findings
# Minimal inputs of the crashes found by tests/test_io_fuzz.py / benches/fuzz_readers.py.

TRI_WRL = ("#VRML V2.0 utf8\nShape { geometry IndexedFaceSet { coord Coordinate { point "
           "[ 0 0 0, 100 0 0, 0 100 0 ] } coordIndex [ 0 1 2 -1 ] } }\n")


@pytest.mark.parametrize("long_list", [False, True])
def test_fuzz_wrl_index_beyond_int64(tmp_path, long_list):
    """Was StopIteration (the int64 overflow was not found by the 'is it an integer' scan)."""
    pad = " 0 1 2 -1" * (200 if long_list else 0)  # > 1000 chars: the numpy fast path
    text = TRI_WRL.replace("coordIndex [ 0 1 2 -1", "coordIndex [" + pad + " 0 1 99999999999999999999 -1")
    with pytest.raises(MeshFileError, match="'99999999999999999999' is out of range in coordIndex") as e:
        load_bytes(tmp_path, "big.wrl", text)
    one_line(e)


def test_fuzz_wrl_nul_byte(tmp_path):
    """Was ValueError (a NUL byte collided with the parser's internal marker of long lists)."""
    with pytest.raises(MeshFileError, match="NUL bytes") as e:
        load_bytes(tmp_path, "nul.wrl", TRI_WRL.replace("Shape {", "Shape { \x00", 1))
    one_line(e)


def test_wrl_deep_nesting_is_an_error_not_a_recursion_error(tmp_path):
    text = "#VRML V2.0 utf8\n" + "Group { children [ " * 3000 + "] }" * 3000
    with pytest.raises(MeshFileError, match="nested more than 100 deep") as e:
        load_bytes(tmp_path, "deep.wrl", text)
    one_line(e)


@pytest.mark.parametrize("field", ["rotation nan 0 1 1", "center 1e999 0 0", "scale 1 inf 1"])
def test_wrl_non_finite_transform(tmp_path, field):
    text = TRI_WRL.replace("Shape", f"Transform {{ {field} children Shape", 1).rstrip() + " }\n"
    with pytest.raises(MeshFileError, match=r"Transform\.\w+ has NaN or infinite numbers") as e:
        load_bytes(tmp_path, "t.wrl", text)
    assert "line 2" in one_line(e)


def test_wrl_gzip_compressed_loads(tmp_path):
    import gzip

    m = load_bytes(tmp_path, "z.wrl", gzip.compress(TRI_WRL.encode()))
    np.testing.assert_array_equal(m.faces, [[0, 1, 2]])
    with pytest.raises(MeshFileError, match="broken gzip-compressed VRML") as e:
        load_bytes(tmp_path, "zz.wrl", gzip.compress(TRI_WRL.encode())[:30])
    one_line(e)


def test_wrl_gzip_concatenated_members_load(tmp_path):
    import gzip

    m = load_bytes(tmp_path, "z.wrl", gzip.compress(TRI_WRL.encode()) + gzip.compress(b"\n# more\n"))
    np.testing.assert_array_equal(m.faces, [[0, 1, 2]])


def test_wrl_gzip_bomb_is_refused_without_inflating_it(tmp_path, monkeypatch):
    """A 64 MiB-inflating .wrl (70 kB on disk) against an 8 MiB limit: refused at the limit."""
    import zlib

    from facecorr.io import vrml

    monkeypatch.setattr(vrml, "MAX_GUNZIPPED_BYTES", 8 * 1024**2)
    c = zlib.compressobj(9, zlib.DEFLATED, 16 + zlib.MAX_WBITS)
    bomb = c.compress(TRI_WRL.encode() + b" " * (64 * 1024**2)) + c.flush()
    assert len(bomb) < 100_000
    with pytest.raises(MeshFileError, match="inflates to more than") as e:
        load_bytes(tmp_path, "bomb.wrl", bomb)
    one_line(e)


def test_fuzz_bnd_huge_index(tmp_path):
    """Was OverflowError: Python int too large to convert to C long."""
    p = tmp_path / "x.bnd"
    p.write_text("8017 -55.0880 31.4430 58.2150\n1e308 1,2,3\n")
    with pytest.raises(MeshFileError, match="line 2: index '1e308' is too large") as e:
        io.load_bnd(p)
    one_line(e)


def test_ply_ascii_body_shorter_than_header(tmp_path):
    """Was read silently as a point cloud of the rows present."""
    text = SQUARE_PLY.replace("element vertex 4", "element vertex 99999999999")
    with pytest.raises(MeshFileError, match="declares 100000000001 element rows, the body has 6 lines") as e:
        load_bytes(tmp_path, "c.ply", text)
    one_line(e)
    with pytest.raises(MeshFileError, match="broken PLY header"):
        load_bytes(tmp_path, "d.ply", SQUARE_PLY.replace("element face 2", "element face two"))


@pytest.mark.parametrize("x", ["1e308", "-1.7e308", "1e16"])
def test_huge_finite_coordinates_are_refused(tmp_path, x):
    """1e308 overflowed the area computation and was reported as 'all faces are degenerate'."""
    with pytest.raises(MeshError, match="coordinates beyond") as e:
        load_bytes(tmp_path, "h.obj", f"v {x} 0 0\nv 0 100 0\nv 0 0 100\nf 1 2 3\n")
    one_line(e)


def test_units_error_names_the_file(tmp_path):
    p = tmp_path / "tiny.obj"
    p.write_text("v 0 0 0\nv 1.5 0 0\nv 0 1.5 0\nf 1 2 3\n")
    with pytest.raises(UnitsError, match="cannot infer units") as e:
        io.load_mesh(p)
    assert str(p) in one_line(e)


def test_wrl_exponential_use_expansion_is_refused_quickly(tmp_path):
    """'Billion laughs': 40 lines of DEF Lk Group { children [ USE Lk-1 USE Lk-1 ] } = 2^39 shapes
    (was a hang)."""
    import time

    lines = ["#VRML V2.0 utf8", "DEF L0 Group { children [ " + TRI_WRL.split("\n", 1)[1] + " ] }"]
    lines += [f"DEF L{k} Group {{ children [ USE L{k - 1} USE L{k - 1} ] }}" for k in range(1, 40)]
    t = time.perf_counter()
    with pytest.raises(MeshFileError, match="once DEF/USE are expanded") as e:
        load_bytes(tmp_path, "laughs.wrl", "\n".join(lines))
    one_line(e)
    assert time.perf_counter() - t < 5
    # a few USEs are fine: L0..L3 at the top level = 1 + 2 + 4 + 8 copies of the triangle
    m = load_bytes(tmp_path, "few.wrl", "\n".join(lines[:5]))
    assert m.n_faces == 1 and m.meta["n_duplicate_faces_dropped"] == 1 + 2 + 4 + 8 - 1


def _equal_rows_by_lexsort(a):
    """The numpy reference of ``io.load._equal_rows`` (its implementation before the Rust hash):
    first occurrences in file order, each row's group numbered in that order."""
    order = np.lexsort(a.T[::-1])  # stable: equal rows keep their file order
    s = a[order]
    new = np.ones(len(a), dtype=bool)
    new[1:] = (s[1:] != s[:-1]).any(axis=1)
    lex_group = np.empty(len(a), dtype=np.int64)
    lex_group[order] = np.cumsum(new) - 1
    first_lex = order[new]
    rank = np.empty(len(first_lex), np.int64)
    rank[np.argsort(first_lex)] = np.arange(len(first_lex))
    return np.sort(first_lex), rank[lex_group]


@settings(max_examples=60, deadline=None)
@given(n=st.integers(1, 300), distinct=st.integers(1, 40), ints=st.booleans(), seed=st.integers(0, 2**31))
def test_equal_rows_hash_matches_the_lexsort_reference(n, distinct, ints, seed):
    """Rows drawn from a few distinct ones (many repeats), float64 (with -0.0 against 0.0, which
    are equal) or int64: the same first occurrences and groups as the lexsort."""
    from facecorr.io.load import _equal_rows

    rng = np.random.default_rng(seed)
    pool = rng.integers(-3, 4, (distinct, 3))
    a = pool[rng.integers(0, distinct, n)]
    if not ints:
        a = a.astype(np.float64) * 0.5
        a[rng.random(a.shape) < 0.2] *= -1.0  # 0.0 -> -0.0 in places
    first, group = _equal_rows(a)
    ref_first, ref_group = _equal_rows_by_lexsort(a)
    np.testing.assert_array_equal(first, ref_first)
    np.testing.assert_array_equal(group, ref_group)
