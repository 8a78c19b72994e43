"""Many scans: register a file, and a resumable folder run that survives bad scans.

:func:`register_file` loads, registers and writes one scan; :func:`plan_batch` lists the jobs of a
folder that still lack results; :func:`register_job` runs one job in a worker and never raises,
so one bad scan cannot stop a batch.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import NamedTuple

#: File suffixes a batch treats as scans.
SCAN_SUFFIXES = (".ply", ".obj", ".stl", ".off", ".glb", ".wrl")


def read_landmarks_json(path, mesh) -> dict:
    """Landmarks from a JSON ({"units": u, "landmarks": {name: xyz}}) converted to mm.

    Checked: all 8 landmarks present, each 3 finite numbers, the units known. Raises a one-line
    LandmarkError naming the file (and the landmark)."""
    import math

    from ..errors import LandmarkError
    from ..io import UNIT_TO_MM
    from ..names import LANDMARK_NAMES

    try:
        data = json.loads(Path(path).read_text())
    except (OSError, ValueError) as e:
        msg = e.strerror if isinstance(e, OSError) and e.strerror else str(e).splitlines()[0]
        raise LandmarkError(f"{path}: not a landmarks JSON ({type(e).__name__}: {msg})") from None
    if not isinstance(data, dict) or not isinstance(data.get("landmarks"), dict):
        raise LandmarkError(f"{path}: not a landmarks JSON (needs an object with \"landmarks\": {{name: [x, y, z]}})")
    lms = data["landmarks"]
    if "units" in data:
        if not isinstance(data["units"], str) or data["units"] not in UNIT_TO_MM:
            raise LandmarkError(f"{path}: unknown units {data['units']!r} (known: {', '.join(UNIT_TO_MM)})")
        factor = UNIT_TO_MM[data["units"]]
    else:
        factor = mesh.to_mm
    missing = [n for n in LANDMARK_NAMES if n not in lms]
    if missing:
        raise LandmarkError(f"{path}: landmarks missing: {', '.join(missing)}")
    out = {}
    for n in LANDMARK_NAMES:
        v = lms[n]
        ok = (isinstance(v, list) and len(v) == 3
              and all(isinstance(c, (int, float)) and not isinstance(c, bool) and math.isfinite(c) for c in v))
        if not ok:
            shown = json.dumps(v)
            shown = shown if len(shown) <= 60 else shown[:57] + "..."
            raise LandmarkError(f"{path}: landmark {n} must be 3 finite numbers [x, y, z], got {shown}")
        out[n] = [float(c) * factor for c in v]
    return out


def check_register_outputs(scan_path, out_mesh, out_json=None, png=None, neutral=None) -> None:
    """Refuse, before any work, outputs that cannot be written (OutputError / MeshFileError naming
    the path): an unknown mesh extension, an output naming the scan or another output, a folder,
    a parent that is a file, a folder without write permission."""
    from ..errors import OutputError
    from ..io.atomic import check_output_paths
    from ..io.load import format_of

    outputs = [("-o", out_mesh)] + ([("--json", out_json)] if out_json else []) + ([("--png", png)] if png else [])
    outputs += [("--neutral", neutral)] if neutral else []
    check_output_paths(outputs, inputs=[scan_path])
    format_of(Path(out_mesh))
    if neutral:
        format_of(Path(neutral))
    if png is not None and Path(png).suffix.lower() not in _PICTURE_SUFFIXES:
        raise OutputError(f"{png}: unknown picture format {Path(png).suffix or '(no extension)'!r} "
                          f"(supported: {', '.join(_PICTURE_SUFFIXES)})")


#: Picture formats ``--png`` can write (matplotlib's, without extra dependencies).
_PICTURE_SUFFIXES = (".png", ".pdf", ".svg", ".jpg", ".jpeg")


def register_file(scan_path, out_mesh, out_json=None, png=None, units="auto", landmarks_json=None, point_set=None,
                  picture="registration", model=None, neutral=None):
    """Load, register and write one scan. Returns the Result (raises FacecorrError on bad input).

    ``point_set``: a point-set JSON on the template (:mod:`facecorr.template.point_sets`), read off
    the result into its JSON's ``point_set``; ``picture``: what ``png`` shows (see
    :func:`save_registration`); ``model``: as in :func:`register_scan`; ``neutral``: a mesh path for
    the expression-removed shape (:attr:`Result.neutral_vertices`). The outputs are checked
    before the work and written as a group: all of them or none."""
    check_register_outputs(scan_path, out_mesh, out_json, png, neutral)
    points = None
    if point_set is not None:
        from ..template import load_template
        from ..template.point_sets import read_point_set

        points = read_point_set(point_set, load_template())
    mesh, result = register_scan(scan_path, units=units, landmarks_json=landmarks_json, points=points, model=model)
    save_registration(mesh, result, out_mesh, out_json, png, title=Path(scan_path).name, inputs=[scan_path],
                      picture=picture, neutral=neutral)
    return result


def register_scan(scan_path, *, units="auto", landmarks_json=None, points=None, model=None):
    """(mesh, Result) of one scan file: loaded, registered, ``points`` (a PointSet) read off it.

    ``model``: a loaded landmark model (default: the packaged one); a batch passes
    :func:`packaged_model` so a worker reads it once. Raises FacecorrError on bad input."""
    from ..io import load_mesh
    from .correspond import correspond

    mesh = load_mesh(scan_path, units=units)
    lms = read_landmarks_json(landmarks_json, mesh) if landmarks_json else None
    result = correspond(mesh, landmarks=lms, model=model)
    if points is not None:
        result.point_set = points.on(result.vertices)
    return mesh, result


def save_registration(mesh, result, out_mesh, out_json=None, png=None, *, title, inputs=(),
                      picture="registration", neutral=None) -> None:
    """Write a registration's files as a group (all or none): the mesh, the JSON, the picture
    (titled ``title``, the scan's file name). The one writer of ``register``, the local batch and
    the Dask workers, so all three write the same bytes. ``picture``: what ``png`` shows,
    "registration" (the scan beside the registered template, :func:`facecorr.render.
    plot_registration`) or "thumbnail" (a small one for a batch's report,
    :func:`facecorr.render.thumbnail_png`; PNG only)."""
    from ..render import plot_registration
    from ..template import load_template

    also = []
    if png and picture == "thumbnail":
        import numpy as np

        from ..names import LANDMARK_NAMES
        from ..render import thumbnail_png

        also.append((png, lambda tmp: tmp.write_bytes(thumbnail_png(
            result.vertices, result.faces, result.surface_distance, load_template(), scan=mesh,
            landmarks=np.array([result.landmarks[n] for n in LANDMARK_NAMES])))))
    elif png:
        also.append((png, lambda tmp: plot_registration(mesh, result, tmp, load_template(), title=title)))
    result.save(out_mesh, out_json, neutral_path=neutral, also=also, inputs=inputs)


def packaged_model():
    """The packaged landmark model, read once per process (a batch worker keeps it warm)."""
    global _PACKAGED_MODEL
    if _PACKAGED_MODEL is None:
        from ..landmarks.model import load_model

        _PACKAGED_MODEL = load_model(None)
    return _PACKAGED_MODEL


_PACKAGED_MODEL = None


#: The batch's own record in OUTPUT_DIR.
FAILURES_NAME = "failures.json"


def _list_scans(src: Path, dst: Path) -> list:
    """Scan files under ``src``, skipping ``dst`` and everything under it (an output folder inside
    the input folder is not input)."""
    import os

    dst_key = os.path.realpath(dst)
    scans = []
    for root, dirs, files in os.walk(src):
        dirs[:] = sorted(d for d in dirs if os.path.realpath(os.path.join(root, d)) != dst_key)
        for f in files:
            p = Path(root) / f
            if p.suffix.lower() in SCAN_SUFFIXES and p.is_file():
                scans.append(p)
    return sorted(scans)


def result_paths(src: Path, dst: Path, scan: Path, png: bool = False, neutral: bool = False) -> list:
    """The result files of ``scan``: [mesh, json] (+ png) (+ neutral: ``<stem>_neutral.ply``)."""
    out_mesh = dst / scan.relative_to(src).with_suffix(".ply")
    return ([out_mesh, out_mesh.with_suffix(".json")] + ([out_mesh.with_suffix(".png")] if png else [])
            + ([neutral_path(out_mesh)] if neutral else []))


#: Suffix of the expression-removed shape beside a result ``<stem>.ply``.
NEUTRAL_SUFFIX = "_neutral.ply"


def neutral_path(out_mesh) -> Path:
    """``<stem>_neutral.ply`` beside the result mesh ``<stem>.ply``: the expression-removed shape."""
    out_mesh = Path(out_mesh)
    return out_mesh.with_name(out_mesh.stem + NEUTRAL_SUFFIX)


class BatchJob(NamedTuple):
    """One scan of a batch and the files its result is made of (written as one group).

    ``scan``: the scan file; ``out_mesh`` / ``out_json``: ``<stem>.ply`` / ``<stem>.json``;
    ``png``: the thumbnail or None; ``units``: the scan's units ("auto", "mm", ...);
    ``point_set``: a point-set JSON path or None; ``neutral``: ``<stem>_neutral.ply`` or None.
    """

    scan: Path
    out_mesh: Path
    out_json: Path
    png: Path | None = None
    units: str = "auto"
    point_set: str | None = None
    neutral: Path | None = None

    @property
    def outputs(self) -> list:
        """The files this job writes, in the order [mesh, json, (png), (neutral)]."""
        return [p for p in (self.out_mesh, self.out_json, self.png, self.neutral) if p is not None]


def plan_batch(src: Path, dst: Path, *, overwrite: bool = False, png: bool = False, units: str = "auto",
               point_set=None, neutral: bool = False):
    """(jobs, n_skipped): one :class:`BatchJob` per scan under ``src`` that lacks one of its result
    files under ``dst`` (same relative path: .ply + .json, + .png with ``png``, +
    ``_neutral.ply`` with ``neutral``). A scan counts as done only when all of them exist; a job
    writes all of its scan's files again, as one group.

    A ``<stem>_neutral.ply`` already beside a result that is redone (``overwrite``, or another file
    missing) is rewritten with it even without ``neutral``: it must not describe an older
    registration than the ``<stem>.ply`` beside it.

    Refused (FacecorrError): ``src`` not a folder, ``dst`` an existing file or ``src`` itself, no
    scans, two scans with the same result (``face.ply`` and ``face.wrl``; with ``neutral`` also
    ``face_neutral.ply`` and the neutral shape of ``face.ply``). Temporary files a killed run left
    beside the results are removed."""
    import os

    from ..errors import FacecorrError, OutputError
    from ..io.atomic import _existing_ancestor, remove_stale_temps

    src, dst = Path(src), Path(dst)
    if not src.is_dir():
        raise FacecorrError(f"{src}: not a folder")
    if os.path.lexists(dst) and not dst.is_dir():
        raise OutputError(f"{dst}: exists and is not a folder (the output folder)")
    if os.path.realpath(dst) == os.path.realpath(src):
        raise OutputError(f"{dst}: the output folder must not be the input folder")
    anc = dst if dst.is_dir() else _existing_ancestor(dst)
    if not anc.is_dir():
        raise OutputError(f"{dst}: cannot create the output folder: {anc} is a file, not a folder")
    if not os.access(anc, os.W_OK | os.X_OK):
        raise OutputError(f"{dst}: cannot write there: no permission to write in {anc}")
    scans = _list_scans(src, dst)
    if not scans:
        raise FacecorrError(f"{src}: no scan files ({', '.join(SCAN_SUFFIXES)})")
    owner = {}
    failures = os.path.realpath(dst / FAILURES_NAME)
    for s in scans:
        out_mesh, out_json = result_paths(src, dst, s)
        if os.path.realpath(out_json) == failures:
            raise FacecorrError(f"{s}: its result {out_json} would clash with the batch's {FAILURES_NAME}: rename the scan")
        if out_mesh in owner:
            raise FacecorrError(f"{owner[out_mesh]} and {s} would both be registered to {out_mesh} "
                                "(same name, other format): rename one or move it to another folder")
        owner[out_mesh] = s
    if neutral:
        for s in scans:
            shape = neutral_path(result_paths(src, dst, s)[0])
            if shape in owner:
                raise FacecorrError(f"{s}'s expression-removed shape would be written to {shape}, the result of "
                                    f"{owner[shape]}: rename that scan")
    jobs, skipped = [], 0
    for s in scans:
        out_mesh, out_json, out_png, out_neutral = result_paths(src, dst, s, png=True, neutral=True)
        for p in (out_mesh, out_json, out_png, out_neutral):
            remove_stale_temps(p)
        wanted = [out_mesh, out_json] + ([out_png] if png else []) + ([out_neutral] if neutral else [])
        if not overwrite and all(p.exists() for p in wanted):
            skipped += 1
            continue
        keep_neutral = neutral or out_neutral.exists()
        jobs.append(BatchJob(s, out_mesh, out_json, out_png if png else None, units, point_set,
                             out_neutral if keep_neutral else None))
    remove_stale_temps(dst / FAILURES_NAME)
    return jobs, skipped


def register_job(job):
    """Worker: register one scan into its result files (its PNG, if any, the report's thumbnail);
    never raises (returns a status row, :func:`status_row`)."""
    job = BatchJob(*job)
    scan = job.scan
    t0 = time.perf_counter()
    try:
        result = register_file(scan, job.out_mesh, job.out_json, job.png, job.units, point_set=job.point_set,
                               picture="thumbnail", model=packaged_model(), neutral=job.neutral)
        return status_row(scan, t0, result)
    except Exception as e:  # noqa: BLE001 - one bad scan must not stop the batch
        return failure_row(scan, e)


def status_row(scan, t0: float, result) -> dict:
    """The row of a registered scan: ``scan``, ``ok`` (True), ``seconds`` (wall, load to written),
    and what a run log records of it: ``mhd`` (scan units), ``coverage``, ``flags``, ``timings_s``."""
    js = result.to_json()
    return {"scan": str(scan), "ok": True, "seconds": round(time.perf_counter() - t0, 3), "mhd": js["mhd"],
            "coverage": js["coverage"], "flags": js["flags"], "timings_s": js["timings_s"]}


def failure_row(scan, e: BaseException) -> dict:
    """The row of a failed scan, as failures.json holds it: ``scan``, ``ok`` (False), ``error``
    ("bad input: ..." for a FacecorrError, else "internal error (Type): ...", one line)."""
    from ..errors import FacecorrError

    kind = "bad input" if isinstance(e, FacecorrError) else f"internal error ({type(e).__name__})"
    return {"scan": str(scan), "ok": False, "error": f"{kind}: {str(e).splitlines()[0] if str(e) else ''}"}


def collect_points(results_dir) -> list[dict]:
    """The points of every result JSON under ``results_dir`` (as ``facecorr register --json`` and
    ``facecorr batch`` write them), one row per point: ``{"scan", "point", "x", "y", "z",
    "units"}`` with ``point`` = ``ibug68_<k>`` (0-based) or a landmark name; coordinates in the
    scan's frame and units, None where the template has no such point. Sorted by scan, then point.
    Raises FacecorrError if the folder holds no result."""
    from ..errors import FacecorrError

    root = Path(results_dir)
    if not root.is_dir():
        raise FacecorrError(f"{root}: not a folder")
    rows = []
    for path in sorted(root.rglob("*.json")):
        try:
            data = json.loads(path.read_text())
        except (OSError, ValueError):
            continue
        if not isinstance(data, dict) or "landmarks_registered" not in data:
            continue  # failures.json and other files
        scan = str(path.relative_to(root).with_suffix(""))
        points = [(f"ibug68_{k}", p) for k, p in enumerate(data.get("ibug68") or [])]
        points += list(data["landmarks_registered"].items()) + list((data.get("point_set") or {}).items())
        for name, p in points:
            x, y, z = (None, None, None) if p is None else (float(c) for c in p)
            rows.append({"scan": scan, "point": name, "x": x, "y": y, "z": z, "units": data.get("units", "mm")})
    if not rows:
        raise FacecorrError(f"{root}: no registration results (JSON files with landmarks_registered)")
    return rows
