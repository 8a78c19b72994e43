"""Read a ``facecorr batch`` output folder into the rows of its report.

A folder holds, per scan, ``<stem>.ply`` (the registered template) and ``<stem>.json``
(:meth:`facecorr.pipeline.Result.to_json`), with ``<stem>.png`` (the thumbnail,
:func:`facecorr.render.thumbnail_png`) when the batch ran with ``--png``, and the batch's
``failures.json``. :func:`read_batch` reads them all; a file it cannot use becomes a
:class:`Problem` of the report, not an error. A thumbnail the batch did not write is rendered
from the mesh and the JSON's per-vertex distances (:func:`render_job`, in worker processes).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import FacecorrError
from ..names import LANDMARK_NAMES


@dataclass
class ScanRow:
    """One registered scan of a batch (lengths in mm, whatever the scan's units).

    Attributes
    ----------
    name : the result's path under the folder without its suffix ("F0001/F0001_AN04_F3D").
    mhd, fit_rms : mm (``fit_rms`` None in results of versions without it); coverage in [0, 1] or None.
    confidence : landmark name -> confidence in [0, 1] (1 for landmarks a user gave).
    landmarks : landmark name -> [x, y, z], the landmarks used, in the scan's frame and ``units``.
    expression : blendshape name -> weight in [0, 1].
    flags : the result's warnings; seconds : the registration's time (None if not recorded).
    picture : the thumbnail PNG (bytes) or None; picture_source : "batch" (its --png), "rendered"
        (from the mesh and the JSON's distances) or None; notes : remarks on the row for the reader.
    """

    name: str
    json_path: Path
    units: str
    mhd: float
    fit_rms: float | None
    coverage: float | None
    confidence: dict
    landmarks: dict
    expression: dict
    flags: list
    seconds: float | None
    distances: dict | None = None  # the JSON's packed surface_distance, until rendered
    picture: bytes | None = None
    picture_source: str | None = None
    notes: list = field(default_factory=list)

    @property
    def lowest_confidence(self) -> tuple[str | None, float | None]:
        """(name, confidence) of the least confident landmark, (None, None) if none recorded."""
        if not self.confidence:
            return None, None
        name = min(self.confidence, key=self.confidence.get)
        return name, self.confidence[name]


@dataclass
class Failure:
    """A scan the batch could not register (a row of failures.json)."""

    scan: str
    error: str


@dataclass
class Problem:
    """A file of the folder the report could not use, and why (one line)."""

    path: str
    message: str


@dataclass
class BatchReport:
    """Everything a report shows: ``rows`` worst first (:func:`worst_first`), ``failures``,
    ``problems``."""

    root: Path
    rows: list
    failures: list
    problems: list


def worst_first(rows: list) -> list:
    """Rows ordered as the report opens: the most flags first, then the largest MHD."""
    return sorted(rows, key=lambda r: (-len(r.flags), -r.mhd, r.name))


def _number(data: dict, key: str, *, required: bool = False):
    """``data[key]`` as a finite float (None if absent or null); ValueError naming the key."""
    v = data.get(key)
    if v is None:
        if required:
            raise ValueError(f"no {key!r}")
        return None
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise ValueError(f"{key!r} is not a finite number: {json.dumps(v)[:40]}")
    return float(v)


def _dict_of_numbers(data: dict, key: str) -> dict:
    v = data.get(key) or {}
    if not isinstance(v, dict) or not all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)
                                          for x in v.values()):
        raise ValueError(f"{key!r} is not an object of finite numbers")
    return {str(k): float(x) for k, x in v.items()}


def parse_result(data, name: str, json_path: Path) -> ScanRow:
    """A :class:`ScanRow` from a result JSON's content; ValueError (one line) if it is not one."""
    from ..io import UNIT_TO_MM

    if not isinstance(data, dict) or not isinstance(data.get("landmarks_registered"), dict):
        raise ValueError("not a facecorr result (no \"landmarks_registered\" object)")
    units = data.get("units", "mm")
    if units not in UNIT_TO_MM:
        raise ValueError(f"unknown units {units!r}")
    mm = UNIT_TO_MM[units]
    mhd = _number(data, "mhd", required=True) * mm
    fit_rms = _number(data, "fit_rms")
    coverage = _number(data, "coverage")
    flags = data.get("flags") or []
    if not isinstance(flags, list):
        raise ValueError("'flags' is not a list")
    landmarks = data.get("landmarks") or {}
    if not isinstance(landmarks, dict):
        raise ValueError("'landmarks' is not an object")
    timings = data.get("timings_s") or {}
    seconds = timings.get("total") if isinstance(timings, dict) else None
    return ScanRow(
        name=name, json_path=json_path, units=units, mhd=mhd,
        fit_rms=None if fit_rms is None else fit_rms * mm, coverage=coverage,
        confidence=_dict_of_numbers(data, "confidence"), landmarks=landmarks,
        expression=_dict_of_numbers(data, "expression_weights"), flags=[str(f) for f in flags],
        seconds=float(seconds) if isinstance(seconds, (int, float)) and not isinstance(seconds, bool) else None,
        distances=data.get("surface_distance"))


def _read_failures(path: Path, problems: list, root: Path) -> list:
    try:
        rows = json.loads(path.read_text())
    except (OSError, ValueError, UnicodeDecodeError) as e:
        problems.append(Problem(str(path.relative_to(root)), f"unreadable ({_one_line(e)})"))
        return []
    if not isinstance(rows, list):
        problems.append(Problem(str(path.relative_to(root)), "not a list of failures"))
        return []
    out = []
    for r in rows:
        if isinstance(r, dict) and "scan" in r:
            out.append(Failure(str(r["scan"]), str(r.get("error", "(no message)"))))
        else:
            problems.append(Problem(str(path.relative_to(root)), f"a row that is not a failure: {json.dumps(r)[:60]}"))
    return out


def _one_line(e: BaseException) -> str:
    msg = e.strerror if isinstance(e, OSError) and e.strerror else str(e)
    return f"{type(e).__name__}: {msg.splitlines()[0] if msg else ''}"


def read_batch(root, *, workers: int = 2, progress: bool = True) -> BatchReport:
    """Read the batch output folder ``root``: its results, failures.json, and a thumbnail per row
    (the batch's ``<stem>.png`` when it is a current facecorr thumbnail, else rendered with
    ``workers`` processes).

    Every ``*.json`` other than failures.json is taken for a result; one that cannot be read or is
    not a result is a :class:`Problem`, as is a mesh a missing thumbnail cannot be rendered from.
    Raises FacecorrError when ``root`` is not a folder or holds no result and no failure.
    """
    from ..pipeline.batch import FAILURES_NAME
    from ..render import is_thumbnail_png

    root = Path(root)
    if not root.is_dir():
        raise FacecorrError(f"{root}: not a folder (the output folder of `facecorr batch`)")
    rows, problems, failures = [], [], []
    paths = sorted(p for p in root.rglob("*.json") if not p.name.startswith("."))  # .x.tmp: a killed run's
    for path in paths:  # quick (700 in ~1 s): no bar, so that a refused folder is one line
        rel = str(path.relative_to(root))
        if path.parent == root and path.name == FAILURES_NAME:
            failures = _read_failures(path, problems, root)
            continue
        try:
            data = json.loads(path.read_text())
            row = parse_result(data, str(path.relative_to(root).with_suffix("")), path)
        except (OSError, UnicodeDecodeError) as e:
            problems.append(Problem(rel, f"unreadable ({_one_line(e)})"))
            continue
        except ValueError as e:  # JSONDecodeError included
            what = "not JSON" if isinstance(e, json.JSONDecodeError) else "not a result"
            problems.append(Problem(rel, f"{what}: {str(e).splitlines()[0]}"))
            continue
        png = path.with_suffix(".png")
        # the batch writes the PNG after the JSON: an older one is a stale picture of an earlier run
        if png.is_file() and is_thumbnail_png(png) and png.stat().st_mtime >= path.stat().st_mtime - 2.0:
            row.picture, row.picture_source = png.read_bytes(), "batch"
        rows.append(row)
    if not rows and not failures:
        detail = f" ({len(problems)} unusable JSON files, e.g. {problems[0].path}: {problems[0].message})" if problems else ""
        raise FacecorrError(f"{root}: no results of `facecorr batch` in it (no <scan>.json, no {FAILURES_NAME}){detail}")
    _render_missing(root, rows, problems, workers, progress)
    return BatchReport(root=root, rows=worst_first(rows), failures=failures, problems=problems)


def _render_missing(root: Path, rows: list, problems: list, workers: int, progress: bool) -> None:
    """Render the thumbnails the batch did not write (in place in ``rows``)."""
    from ..threads import process_iter

    todo = [r for r in rows if r.picture is None]
    jobs = [(str(r.json_path.with_suffix(".ply")), r.units, r.distances,
             [r.landmarks.get(n) for n in LANDMARK_NAMES]) for r in todo]
    for row, (png, note, error) in zip(todo, process_iter(render_job, jobs, workers=workers, desc="rendering thumbnails",
                                                          progress=progress)):
        if error:
            problems.append(Problem(str(row.json_path.with_suffix(".ply").relative_to(root)), error))
            row.notes.append("no picture: " + error)
        else:
            row.picture, row.picture_source = png, "rendered"
        if note:
            row.notes.append(note)
    for r in rows:
        r.distances = None  # ~7 kB a row, no longer needed


def render_job(job):
    """Worker: (PNG bytes or None, note or None, error or None) of one result's thumbnail, from its
    mesh (``job`` = (mesh path, units, the JSON's packed distances or None, the 8 landmarks used
    or Nones)); never raises."""
    from ..io import load_mesh
    from ..pipeline.correspond import decode_distances
    from ..render import thumbnail_png
    from ..template import load_template

    mesh_path, units, packed, landmarks = job
    template = load_template()
    try:
        mesh = load_mesh(mesh_path, units=units, merge_duplicates=False)
    except FacecorrError as e:
        return None, None, f"mesh unreadable: {' '.join(str(e).splitlines())}"
    n = len(template.vertices)
    if mesh.n_vertices != n:
        return None, None, f"the mesh has {mesh.n_vertices} vertices, not the template's {n}: not a registered template"
    note, distance = None, None
    if packed is None:
        note = "no per-vertex distances in its JSON (a result of an older facecorr): the template is drawn grey"
    else:
        try:
            distance = decode_distances(packed) * mesh.to_mm
        except ValueError as e:
            note = f"its JSON's distances are unusable ({e}): the template is drawn grey"
        else:
            if len(distance) != n:
                note, distance = f"its JSON has {len(distance)} distances for {n} vertices: the template is drawn grey", None
    try:
        lm = np.array(landmarks, dtype=np.float64) * mesh.to_mm
        lm = lm if lm.shape == (len(LANDMARK_NAMES), 3) and np.isfinite(lm).all() else None
    except (TypeError, ValueError):
        lm = None
    try:
        png = thumbnail_png(mesh.vertices, template.faces, distance, template, landmarks=lm)
    except Exception as e:  # noqa: BLE001 - one bad result must not stop the report
        return None, note, f"could not be drawn ({_one_line(e)})"
    return png, note, None
