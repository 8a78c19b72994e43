"""Writing a shape model for other tools: the statismo HDF5 layout, and PLY meshes of its modes.

The statismo file follows the layout statismo 0.9 writes (``statismo::IO::SaveStatisticalModel``
with an ``itkStandardMeshRepresenter``) and Scalismo's ``StatismoIO`` reads::

    /version/majorVersion             int32 scalar 0
    /version/minorVersion             int32 scalar 9
    /representer                      group; attributes name "itkStandardMeshRepresenter",
                                      version "0.1", datasetType "POLYGON_MESH"
    /representer/points               float32 (3, N), the reference mesh (here: the mean)
    /representer/cells                uint32 (3, M), its triangles
    /representer/pointData            group (empty: no per-point data)
    /model/mean                       float32 (3N,), x0 y0 z0 x1 ...
    /model/pcaBasis                   float32 (3N, K), orthonormal columns (0.9: not scaled by
                                      the standard deviations, unlike 0.8)
    /model/pcaVariance                float32 (K,)
    /model/noiseVariance              float32 scalar 0
    /modelinfo/build-time             string
    /modelinfo/scores                 float32 (K, n_scans), the training shapes' coefficients
    /modelinfo/modelBuilder-0/        builderName, buildTime (strings); dataInfo/URI_<i> (the
                                      scans' names), parameters/<name> (strings)

Strings are fixed-length ASCII, as statismo's ``HDF5Utils::writeString`` makes them. h5py is an
optional dependency: ``pip install facecorr[hdf5]``.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from ..errors import FacecorrError, OutputError
from .shape_model import ShapeModel


def _ascii(s: str) -> np.bytes_:
    return np.bytes_(str(s).encode("ascii", "replace"))


def _h5py():
    try:
        import h5py
    except ImportError:
        raise FacecorrError("--statismo needs h5py: pip install 'facecorr[hdf5]'") from None
    return h5py


def write_statismo(model: ShapeModel, path) -> None:
    """Write ``model`` to ``path`` (.h5) in the statismo layout (module docstring), atomically.

    Raises FacecorrError when h5py is not installed, OutputError when the path cannot be written."""
    export_model(model, statismo=path)


def write_mode_plys(model: ShapeModel, folder, *, n_modes: int | None = None, sigma: float = 3.0) -> list[Path]:
    """Write the mean and mean -/+ ``sigma`` standard deviations of each of the first ``n_modes``
    modes (default: all) as PLY meshes (mm, the template's triangles) into ``folder``, as a
    group (all or none). Returns the paths written."""
    return export_model(model, ply_dir=folder, n_modes=n_modes, sigma=sigma)


def mode_mesh_names(n_modes: int, sigma: float = 3.0) -> list[str]:
    """The file names of the mode meshes: mean.ply, then per mode minus and plus."""
    tag = f"{sigma:g}sd".replace(".", "p")
    out = ["mean.ply"]
    for k in range(n_modes):
        out += [f"mode{k + 1:02d}_minus{tag}.ply", f"mode{k + 1:02d}_plus{tag}.ply"]
    return out


def export_model(model: ShapeModel, *, statismo=None, ply_dir=None, n_modes: int | None = None,
                 sigma: float = 3.0) -> list[Path]:
    """Write the statismo file and/or the mode meshes (``ply_dir``: mean.ply and mean -/+
    ``sigma`` sd of the first ``n_modes`` modes, default all) as one group: every file or none.
    Every output is checked before anything is written. Returns the paths written."""
    from ..io import save_mesh
    from ..io.atomic import atomic_paths, check_output_paths

    h5py = _h5py() if statismo is not None else None
    outputs = []
    if statismo is not None:
        outputs.append(("--statismo", Path(statismo)))
    k = 0
    if ply_dir is not None:
        folder = Path(ply_dir)
        if folder.exists() and not folder.is_dir():
            raise OutputError(f"{folder}: exists and is not a folder (--ply-modes needs a folder)")
        k = model.n_modes if n_modes is None else int(min(max(n_modes, 0), model.n_modes))
        outputs += [("--ply-modes", folder / n) for n in mode_mesh_names(k, sigma)]
    check_output_paths(outputs)
    paths = [p for _, p in outputs]
    with atomic_paths(*paths) as tmps:
        rest = tmps
        if statismo is not None:
            _write_statismo_file(h5py, model, tmps[0])
            rest = tmps[1:]
        if ply_dir is not None:
            shapes = [model.mean]
            for i in range(k):
                for sign in (-1.0, 1.0):
                    a = np.zeros(i + 1)
                    a[i] = sign * sigma
                    shapes.append(model.sample(a))
            for tmp, v in zip(rest, shapes):
                save_mesh(tmp, (v, model.faces))
    return paths


def _write_statismo_file(h5py, model: ShapeModel, path) -> None:
    n, k = model.n_vertices, model.n_modes
    stamp = time.asctime()
    with h5py.File(path, "w") as f:
        f.create_dataset("version/majorVersion", data=np.int32(0))
        f.create_dataset("version/minorVersion", data=np.int32(9))
        rep = f.create_group("representer")
        rep.attrs["name"] = _ascii("itkStandardMeshRepresenter")
        rep.attrs["version"] = _ascii("0.1")
        rep.attrs["datasetType"] = _ascii("POLYGON_MESH")
        rep.create_dataset("points", data=model.mean.T.astype(np.float32))
        rep.create_dataset("cells", data=model.faces.T.astype(np.uint32))
        rep.create_group("pointData")
        m = f.create_group("model")
        m.create_dataset("mean", data=model.mean.reshape(-1).astype(np.float32))
        m.create_dataset("pcaBasis", data=model.components.reshape(k, 3 * n).T.astype(np.float32))
        m.create_dataset("pcaVariance", data=model.variances.astype(np.float32))
        m.create_dataset("noiseVariance", data=np.float32(0.0))
        info = f.create_group("modelinfo")
        info.create_dataset("build-time", data=_ascii(stamp))
        if model.scores is None or model.scores.size == 0:
            scores = np.zeros((1, 1), np.float32)  # statismo's own "no scores" placeholder
        else:
            scores = np.asarray(model.scores, np.float32).T  # (K, n_scans)
        info.create_dataset("scores", data=scores)
        b = info.create_group("modelBuilder-0")
        b.create_dataset("builderName", data=_ascii("facecorr model build (Procrustes + PCAModelBuilder)"))
        b.create_dataset("buildTime", data=_ascii(stamp))
        di = b.create_group("dataInfo")
        for i, name in enumerate(model.names):
            di.create_dataset(f"URI_{i}", data=_ascii(name))
        par = b.create_group("parameters")
        for key, value in (("NoiseVariance", "0"), ("alignment", model.alignment), ("source", model.source),
                           ("units", "mm"), ("n_scans", str(model.n_scans)),
                           ("total_variance_mm2", repr(float(model.total_variance)))):
            par.create_dataset(key, data=_ascii(value))

