"""Many scans: register a file, and a resumable folder run that survives bad scans.

:func:`register_file` loads, registers and writes one scan; :func:`plan_batch` lists the jobs of a
folder that still lack results; :func:`register_job` runs one job in a worker and never raises,
so one bad scan cannot stop a batch.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

#: File suffixes a batch treats as scans.
SCAN_SUFFIXES = (".ply", ".obj", ".stl", ".off", ".glb", ".wrl")


def read_landmarks_json(path, mesh) -> dict:
    """Landmarks from a JSON ({"units": u, "landmarks": {name: xyz}}) converted to mm."""
    from ..errors import LandmarkError
    from ..io import UNIT_TO_MM

    try:
        data = json.loads(Path(path).read_text())
        lms = data["landmarks"]
        factor = UNIT_TO_MM[data["units"]] if "units" in data else mesh.to_mm
        return {k: [float(c) * factor for c in v] for k, v in lms.items()}
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise LandmarkError(f"{path}: not a landmarks JSON ({type(e).__name__}: {e})") from None


def register_file(scan_path, out_mesh, out_json=None, png=None, units="auto", landmarks_json=None):
    """Load, register and write one scan. Returns the Result (raises FacecorrError on bad input)."""
    from ..io import load_mesh
    from ..render import plot_registration
    from ..template import load_template
    from .correspond import correspond

    mesh = load_mesh(scan_path, units=units)
    lms = read_landmarks_json(landmarks_json, mesh) if landmarks_json else None
    result = correspond(mesh, landmarks=lms)
    result.save(out_mesh, out_json)
    if png:
        plot_registration(mesh, result, png, load_template(), title=Path(scan_path).name)
    return result


def plan_batch(src: Path, dst: Path, *, overwrite: bool = False, png: bool = False, units: str = "auto"):
    """(jobs, n_skipped): one job ``(scan, out_mesh, out_json, png, units)`` per scan under ``src``
    without both result files under ``dst`` (same relative path, .ply + .json)."""
    from ..errors import FacecorrError

    if not src.is_dir():
        raise FacecorrError(f"{src}: not a folder")
    scans = sorted(p for p in src.rglob("*") if p.suffix.lower() in SCAN_SUFFIXES and p.is_file())
    if not scans:
        raise FacecorrError(f"{src}: no scan files ({', '.join(SCAN_SUFFIXES)})")
    jobs, skipped = [], 0
    for s in scans:
        out_mesh = dst / s.relative_to(src).with_suffix(".ply")
        out_json = out_mesh.with_suffix(".json")
        if not overwrite and out_mesh.exists() and out_json.exists():
            skipped += 1
            continue
        jobs.append((s, out_mesh, out_json, out_mesh.with_suffix(".png") if png else None, units))
    return jobs, skipped


def register_job(job):
    """Worker: register one scan; never raises (returns a status row)."""
    scan, out_mesh, out_json, png, units = job
    t0 = time.perf_counter()
    try:
        register_file(scan, out_mesh, out_json, png, units)
        return {"scan": str(scan), "ok": True, "seconds": round(time.perf_counter() - t0, 3)}
    except Exception as e:  # noqa: BLE001 - one bad scan must not stop the batch
        from ..errors import FacecorrError

        kind = "bad input" if isinstance(e, FacecorrError) else f"internal error ({type(e).__name__})"
        return {"scan": str(scan), "ok": False, "error": f"{kind}: {str(e).splitlines()[0] if str(e) else ''}"}
