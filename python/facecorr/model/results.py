"""Reading a folder of registration results (``facecorr batch`` output) as shapes in mm.

A result is ``<stem>.json`` (the JSON contract of ``facecorr register --json``: it names the
scan's ``units`` and carries ``flags``) with ``<stem>.ply`` beside it: the template deformed onto
the scan, in the scan's frame and units. ``<stem>_neutral.ply`` is the same registration with its
fitted expression removed (``--neutral``).

Which results are used (the policy of ``facecorr model build``):

* a result whose flags say the registration itself is doubtful (:data:`DOUBTFUL_FLAGS`: the fit
  was implausible, the template covers too little scan, the scan had several surfaces, a
  registered landmark lies off the scan, the face fit of the landmark stage failed) is skipped,
  unless ``include_flagged``; notes about single landmarks (``low_confidence``, ``patch_slid``,
  a wider search that was retried, ...) do not skip a result: the registration after them is
  checked by the result-level flags above;
* scans that failed (listed in ``failures.json``) have no result and are only counted;
* anything that makes the set unusable is refused with one line naming the file: a result JSON
  without its mesh, a mesh that is not the template (another vertex count or other triangles),
  unknown units, NaN coordinates, with ``neutral`` a missing ``<stem>_neutral.ply``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import ShapeModelError

#: Result flags (the part before ":") that skip a result unless ``include_flagged``.
DOUBTFUL_FLAGS = ("implausible_fit", "low_coverage", "several_pieces", "landmark_off_surface", "poor_face_fit")
#: The batch's list of failed scans (facecorr.pipeline.batch.FAILURES_NAME).
FAILURES_NAME = "failures.json"
#: Suffix of the expression-removed mesh beside ``<stem>.ply``.
NEUTRAL_SUFFIX = "_neutral.ply"


@dataclass
class ResultSet:
    """Shapes read from a results folder.

    Attributes
    ----------
    shapes : (S, N, 3) float64 mm, each in its scan's frame; names : list of S str (the result's
    path under the folder, without suffix); faces : (M, 3) int64; skipped : list of (name, flags)
    for the results left out (their doubtful flags); n_failed : int, scans listed in failures.json
    (no result).
    """

    shapes: np.ndarray
    names: list
    faces: np.ndarray
    skipped: list = field(default_factory=list)
    n_failed: int = 0


def doubtful_flags(flags) -> list[str]:
    """The flags of ``flags`` (a result JSON's list) that skip a result (:data:`DOUBTFUL_FLAGS`)."""
    return [f for f in flags if isinstance(f, str) and f.split(":", 1)[0] in DOUBTFUL_FLAGS]


def find_results(root) -> list[tuple[Path, dict]]:
    """(json path, parsed JSON) of every registration result under ``root``, sorted by path.

    A result JSON is one with ``landmarks_registered`` (failures.json, ground-truth files and
    other JSON are not results)."""
    out = []
    for path in sorted(Path(root).rglob("*.json")):
        if path.name == FAILURES_NAME or path.name.startswith("."):
            continue
        try:
            data = json.loads(path.read_text())
        except (OSError, ValueError, UnicodeDecodeError):
            continue
        if isinstance(data, dict) and "landmarks_registered" in data:
            out.append((path, data))
    return out


def _count_failed(root: Path) -> int:
    try:
        rows = json.loads((root / FAILURES_NAME).read_text())
    except (OSError, ValueError):
        return 0
    return len(rows) if isinstance(rows, list) else 0


def _read_vertices_faces(path: Path):
    """(V (N, 3) float64, F (M, 3) int64) of a result mesh, exactly as written (no merging)."""
    import trimesh

    try:
        m = trimesh.load(str(path), process=False, force="mesh")
        v = np.asarray(m.vertices, dtype=np.float64)
        f = np.asarray(m.faces, dtype=np.int64)
    except Exception as e:  # noqa: BLE001 - any reader failure is a broken file
        msg = str(e).splitlines()[0] if str(e) else ""
        raise ShapeModelError(f"{path}: cannot read the result mesh ({type(e).__name__}: {msg})") from None
    return v, f.reshape(-1, 3)


def select_results(results_dir, *, neutral: bool = False, include_flagged: bool = False):
    """Which results under ``results_dir`` a model is built from, before any mesh is read.

    Returns ``(chosen, skipped, n_failed)``: ``chosen`` a list of ``(name, mesh path, mm per
    unit)``, the mesh being ``<stem>_neutral.ply`` with ``neutral``; ``skipped`` (name, doubtful
    flags) pairs; ``n_failed`` the scans of failures.json. Raises ShapeModelError (one line): no
    folder, no result, unknown units, a JSON without its mesh, missing neutral shapes, fewer
    than 2 usable results."""
    from ..io import UNIT_TO_MM

    root = Path(results_dir)
    if not root.is_dir():
        raise ShapeModelError(f"{root}: not a folder (give the output folder of `facecorr batch`)")
    found = find_results(root)
    if not found:
        raise ShapeModelError(f"{root}: no registration results (<stem>.json + <stem>.ply as `facecorr batch` "
                              "writes them)")
    chosen, skipped = [], []
    for path, data in found:
        name = path.relative_to(root).with_suffix("").as_posix()
        units = data.get("units", "mm")
        if not isinstance(units, str) or units not in UNIT_TO_MM:
            raise ShapeModelError(f"{path}: unknown units {units!r} (known: {', '.join(UNIT_TO_MM)})")
        flags = data.get("flags") or []
        bad = doubtful_flags(flags if isinstance(flags, list) else [])
        if bad and not include_flagged:
            skipped.append((name, bad))
            continue
        mesh = path.with_suffix(".ply")
        if not mesh.is_file():
            raise ShapeModelError(f"{path}: the result has no mesh {mesh.name} beside it (an incomplete copy?)")
        chosen.append((name, mesh, UNIT_TO_MM[units]))
    if neutral:
        chosen = [(name, m.with_name(m.stem + NEUTRAL_SUFFIX), f) for name, m, f in chosen]
        missing = [m for _, m, _ in chosen if not m.is_file()]
        if missing:
            raise ShapeModelError(
                f"{root}: --neutral needs the expression-removed shape <stem>{NEUTRAL_SUFFIX} beside each result, "
                f"but {len(missing)} of {len(chosen)} are missing (e.g. {missing[0]}): run `facecorr batch IN "
                f"{root} --neutral` (it adds the missing ones)")
    if len(chosen) < 2:
        why = f" ({len(skipped)} skipped as flagged; --include-flagged keeps them)" if skipped else ""
        raise ShapeModelError(f"{root}: a shape model needs at least 2 results, {len(chosen)} usable{why}")
    return chosen, skipped, _count_failed(root)


def read_shape(mesh, to_mm: float, n_vertices: int):
    """(vertices (N, 3) float64 mm, faces (M, 3) int64) of one result mesh, checked: ``n_vertices``
    vertices, finite coordinates. Raises ShapeModelError naming the file."""
    v, f = _read_vertices_faces(Path(mesh))
    if len(v) != n_vertices:
        raise ShapeModelError(f"{mesh}: {len(v)} vertices, the template has {n_vertices}: not a facecorr "
                              "registration (or of another template)")
    if not np.isfinite(v).all():
        raise ShapeModelError(f"{mesh}: NaN or infinite coordinates")
    return v * to_mm, f


def same_faces(mesh, faces, first_faces, first_name: str) -> None:
    """Raise ShapeModelError unless ``faces`` (of ``mesh``) are ``first_faces`` (of ``first_name``)."""
    if faces.shape != first_faces.shape or not np.array_equal(faces, first_faces):
        raise ShapeModelError(f"{mesh}: its triangles differ from {first_name}'s: not the same template")


def read_results(results_dir, *, neutral: bool = False, include_flagged: bool = False, progress: bool = True,
                 n_vertices: int | None = None) -> ResultSet:
    """Read every usable result under ``results_dir`` (module docstring: which, and the errors).

    Parameters
    ----------
    results_dir : folder written by ``facecorr batch`` (results in sub-folders are found too).
    neutral : read ``<stem>_neutral.ply`` (the expression-removed shapes) instead of ``<stem>.ply``.
    include_flagged : keep results with :data:`DOUBTFUL_FLAGS` too.
    n_vertices : the vertex count every mesh must have (default: the packaged template's).

    Raises
    ------
    ShapeModelError (one line) for an unusable folder or result.
    """
    from tqdm import tqdm

    chosen, skipped, n_failed = select_results(results_dir, neutral=neutral, include_flagged=include_flagged)
    if n_vertices is None:
        from ..template import load_template

        n_vertices = load_template().n_vertices
    shapes = np.empty((len(chosen), n_vertices, 3))
    faces = None
    # the bar shows only when reading takes over a second (a few results are read at once)
    bar = tqdm(chosen, desc="reading", unit="result", disable=not progress, delay=1.0)
    for i, (name, mesh, to_mm) in enumerate(bar):
        shapes[i], f = read_shape(mesh, to_mm, n_vertices)
        if faces is None:
            faces = f
        else:
            same_faces(mesh, f, faces, chosen[0][1].name)
    return ResultSet(shapes=shapes, names=[c[0] for c in chosen], faces=faces, skipped=skipped, n_failed=n_failed)
