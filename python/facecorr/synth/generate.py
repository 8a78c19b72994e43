"""Generate a BU-3DFE-like database of simulated scans with exact ground truth.

Layout (like BU-3DFE)::

    OUT/index.json
    OUT/F0001/F0001_NE00_F3D.ply            the scan (mm, binary PLY)
    OUT/F0001/F0001_NE00_F3D.json           ground truth (contract below)
    OUT/F0001/F0001_NE00_F3D_dense.npz      dense ground truth: tri, bary, clean, pose (+ extras)
    OUT/F0001/F0001_HA04_F3D.ply ...

Ground-truth JSON: ``{"scan": FILE, "subject": "F0001", "expression": "HA", "level": 4,
"split": "train"|"test", "units": "mm", "landmarks": {name: [x, y, z]}, "ibug68": [[x, y, z] or
null, ... 68], "dense": FILE.npz}`` (file names relative to the JSON's folder), plus ``"colour":
{"source": "vertex"|"texture", "function": "facecorr.synth.colour.skin_colour"}`` for a coloured
database (``colour=``, :mod:`facecorr.synth.colour`): ``vertex`` writes PLY scans with per-vertex
RGB, ``texture`` OBJ scans with an MTL and a PNG texture (``F0001_HA04_F3D.obj/.mtl/.png``).
Colour draws no random numbers: the geometry is the same with or without it.

Subjects are named F0001, M0001, F0002, M0002, ... (alternating; the letter is only a label:
identities are sampled from the ICT identity space, which has no gender variable). The split is
fixed and does not depend on the seed: subject number ``n`` of letter ``g`` (F = 0, M = 1) is in
the training half when ``n + g`` is odd (F0001, M0002, F0003, ...), so every run of 2k subjects
has k training and k test subjects, balanced over the letters.

Reproducibility: the identity of a subject is drawn from ``SeedSequence(seed, spawn_key=(1, g,
n))`` and everything random in a scan from ``SeedSequence(seed, spawn_key=(2, g, n, e, l))``
(e = expression index in NE, AN, DI, FE, HA, SA, SU; l = level), so the output bytes depend
only on the seed, never on the number of workers or the order of the scans.
"""

from __future__ import annotations

import json
import os
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np

from ..errors import FacecorrError
from ..geometry.mesh import Mesh
from ..io import save_mesh
from ..names import LANDMARK_NAMES
from .expressions import EXPRESSION_CODES, expression_weights
from .model import deform, load_ict, sample_identity
from .scanner import ScannerConfig, scan_head

#: Presets: number of subjects. ``bu3dfe-ood``: out-of-model subjects with the artefacts of real
#: scans, all test-only (:mod:`facecorr.synth.ood_preset`).
PRESETS = {"tiny": 2, "bu3dfe": 100, "bu3dfe-ood": 30}


class SynthError(FacecorrError, ValueError):
    """Bad arguments to the synthetic database generator."""


def subject_name(i: int) -> str:
    """Name of the i-th subject (0-based): F0001, M0001, F0002, ..."""
    return f"{'FM'[i % 2]}{i // 2 + 1:04d}"


def _parse_subject(name: str) -> tuple[int, int]:
    if len(name) != 5 or name[0] not in "FM" or not name[1:].isdigit() or int(name[1:]) < 1:
        raise SynthError(f"bad subject name {name!r} (expected like F0001 or M0012)")
    return "FM".index(name[0]), int(name[1:])


def subject_split(name: str) -> str:
    """"train" or "test": fixed, seed-independent, balanced (see the module docstring)."""
    g, n = _parse_subject(name)
    return "train" if (n + g) % 2 == 1 else "test"


def preset_split(preset: str, subject: str) -> str:
    """The split of ``subject`` in ``preset``: :func:`subject_split`, or for ``bu3dfe-ood``
    "ood_test" / "ood_holdout" (:func:`facecorr.synth.ood.ood_split`)."""
    if preset == "bu3dfe-ood":
        from .ood import ood_split

        g, n = _parse_subject(subject)
        return ood_split(2 * (n - 1) + g)
    return subject_split(subject)


def scan_stem(subject: str, expression: str, level: int) -> str:
    return f"{subject}_{expression}{level:02d}_F3D"


def subject_identity(seed: int, subject: str) -> np.ndarray:
    """(100,) identity weights of ``subject`` for database ``seed``."""
    g, n = _parse_subject(subject)
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(1, g, n)))
    return sample_identity(rng, load_ict().identity.shape[0])


def _scan_rng(seed, subject, expression, level):
    g, n = _parse_subject(subject)
    e = EXPRESSION_CODES.index(expression)
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(2, g, n, e, level)))


def model_vertices(seed: int, subject: str, expression: str, level: int) -> tuple[np.ndarray, np.ndarray]:
    """The deformed ICT head of one scan (before scanning): ((N, 3) mm model frame, (53,) weights).

    Together with the scan's ``pose`` this reproduces the dense ground truth:
    ``clean = (sum_k bary[:, k] * V[ict_triangles[tri, k]]) @ R.T + t``.
    """
    model = load_ict()
    rng = _scan_rng(seed, subject, expression, level)
    alpha = expression_weights(model.expression_names, expression, level, rng)
    return deform(model, subject_identity(seed, subject), alpha), alpha


def make_scan(seed: int, subject: str, expression: str, level: int, config: ScannerConfig | None = None):
    """Simulate one scan: returns (:class:`facecorr.synth.scanner.Scan`, expression weights (53,))."""
    model = load_ict()
    rng = _scan_rng(seed, subject, expression, level)
    alpha = expression_weights(model.expression_names, expression, level, rng)
    V = deform(model, subject_identity(seed, subject), alpha)
    scan = scan_head(model, V, config or ScannerConfig(), rng)
    return scan, alpha


def _scan_suffix(colour) -> str:
    return ".obj" if colour == "texture" else ".ply"


def _save_scan(path: Path, scan, colour) -> None:
    """The scan's mesh file: binary PLY (float64 mm), with per-vertex colours for ``vertex``; an
    OBJ + MTL + PNG for ``texture``."""
    from .colour import material_positions, scan_texture_coordinates, skin_colour, texture_atlas

    if colour is None:
        save_mesh(path, (scan.vertices, scan.faces))
    elif colour == "vertex":
        rgb = skin_colour(material_positions(scan.tri, scan.bary))
        save_mesh(path, (scan.vertices, scan.faces), colors=np.round(rgb * 255.0).astype(np.uint8))
    else:
        uv = scan_texture_coordinates(scan.tri, scan.bary)
        save_mesh(path, Mesh(scan.vertices, scan.faces, face_uv=uv[scan.faces], texture=texture_atlas()[0]))


def _job(args):
    out_dir, seed, subject, expression, level, cfg, colour, preset = args
    t0 = time.perf_counter()
    extra, extra_npz = {}, {}
    if preset == "bu3dfe-ood":
        from .ood_preset import make_ood_scan, save_ood_scan, subject_of

        scan, alpha, labels, plan, details = make_ood_scan(seed, subject, expression, level, cfg)
        colour = plan.get("colour", {}).get("source")
        identity = subject_of(seed, subject).identity
        extra = {"artefacts": [k for k in plan], "artefact_details": details,
                 "ood": subject_of(seed, subject).info()}
        extra_npz = {"artefact_label": labels.astype(np.uint8)}
    else:
        scan, alpha = make_scan(seed, subject, expression, level, cfg)
        identity = subject_identity(seed, subject)
    stem = scan_stem(subject, expression, level)
    d = Path(out_dir) / subject
    d.mkdir(parents=True, exist_ok=True)
    if preset == "bu3dfe-ood":
        g, n = _parse_subject(subject)
        save_ood_scan(d / f"{stem}{_scan_suffix(colour)}", scan, labels, colour, seed * 7919 + 2 * n + g)
    else:
        _save_scan(d / f"{stem}{_scan_suffix(colour)}", scan, colour)
    with open(d / f"{stem}_dense.npz", "wb") as fh:
        np.savez(
            fh, tri=scan.tri.astype(np.int32), bary=scan.bary.astype(np.float32),
            clean=scan.clean.astype(np.float32), pose=scan.pose.astype(np.float64),
            expression_weights=alpha.astype(np.float32),
            identity_weights=identity.astype(np.float32), **extra_npz,
        )
    r = lambda p: [round(float(x), 4) for x in p]  # noqa: E731  (0.1 um is plenty)
    gt = {
        "scan": f"{stem}{_scan_suffix(colour)}",
        "subject": subject,
        "expression": expression,
        "level": level,
        "split": preset_split(preset, subject),
        "units": "mm",
        "landmarks": {name: r(p) for name, p in zip(LANDMARK_NAMES, scan.landmarks)},
        "ibug68": [None if np.isnan(p).any() else r(p) for p in scan.ibug68],
        "dense": f"{stem}_dense.npz",
        **extra,
    }
    if colour is not None:
        gt["colour"] = {"source": colour, "function": "facecorr.synth.colour.skin_colour"}
    with open(d / f"{stem}.json", "w") as fh:
        json.dump(gt, fh, indent=1)
        fh.write("\n")
    return stem, len(scan.vertices), len(scan.faces), time.perf_counter() - t0, gt["scan"]


def _init_worker():
    os.environ["FACECORR_THREADS"] = "1"  # one process per core; the raster kernel runs serially
    load_ict()


def scan_list(preset="tiny", subjects=None, expressions=None, levels=None, subset=None):
    """The (subject, expression, level) triples a preset and filters select, in a fixed order."""
    if preset not in PRESETS:
        raise SynthError(f"unknown preset {preset!r}; expected one of {', '.join(PRESETS)}")
    n_sub = PRESETS[preset] if subjects is None else int(subjects)
    if n_sub < 1:
        raise SynthError("the number of subjects must be at least 1")
    exprs = EXPRESSION_CODES if expressions is None else tuple(expressions)
    for e in exprs:
        if e not in EXPRESSION_CODES:
            raise SynthError(f"unknown expression {e!r}; expected some of {', '.join(EXPRESSION_CODES)}")
    lv = (1, 2, 3, 4) if levels is None else tuple(int(x) for x in levels)
    if subset == "eval":
        lv = tuple(x for x in lv if x == 4)
    elif subset not in (None, "all"):
        raise SynthError(f"unknown subset {subset!r}; expected 'all' or 'eval'")
    for x in lv:
        if not 1 <= x <= 4:
            raise SynthError(f"bad level {x}: levels are 1..4")
    out = []
    for i in range(n_sub):
        s = subject_name(i)
        for e in exprs:
            if e == "NE":
                out.append((s, "NE", 0))
            else:
                out.extend((s, e, x) for x in lv)
    if not out:
        raise SynthError("the filters select no scan")
    return out


def generate(out_dir, preset="tiny", seed=0, workers=2, crop="face", subjects=None, expressions=None,
             levels=None, subset=None, progress=True, config: ScannerConfig | None = None, colour=None, on_scan=None,
             **scanner_options):
    """Generate the database into ``out_dir`` and return the index records.

    Parameters
    ----------
    out_dir : path, created if needed.
    preset : "tiny" (2 subjects), "bu3dfe" (100 subjects) or "bu3dfe-ood" (30 out-of-model
        subjects with the artefacts of real scans, :mod:`facecorr.synth.ood_preset`), x 25 scans each.
    seed : int, the database seed (bitwise reproducible).
    workers : processes (scans are independent; the result does not depend on this).
    crop : "face" (BU-3DFE-like cropped faces) or "none" (raw scans: head, neck, ears).
    subjects : int, override the preset's number of subjects.
    expressions : iterable of codes ("NE", "AN", ...), default all seven.
    levels : iterable of levels 1..4 for the non-neutral expressions, default all.
    subset : "eval" = NE + level 4 only (the paper's 700-scan evaluation subset on bu3dfe).
    config : a ScannerConfig; ``scanner_options`` override its fields (e.g. yaw=90, spacing=1.2).
    colour : None (no colour), "vertex" (PLY with per-vertex RGB) or "texture" (OBJ + MTL + PNG);
        see :mod:`facecorr.synth.colour`.
    on_scan : optional callable, called with ``{"scan", "status", "seconds", "vertices", "faces"}``
        (the scan's path relative to ``out_dir``) as each scan is written (a run log).

    Returns
    -------
    list of index records (dicts with relative paths, as written to ``index.json``).
    """
    if int(workers) < 1:
        raise SynthError("workers must be at least 1")
    if preset == "bu3dfe-ood" and (colour is not None or crop != "face"):
        raise SynthError("the bu3dfe-ood preset chooses colour and raw crops per scan (its artefacts); "
                         "drop --colour / --crop")
    _check_colour(colour)
    cfg = _scanner_config(crop, config, scanner_options)
    jobs = scan_list(preset, subjects, expressions, levels, subset)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    args = [(str(out), int(seed), s, e, lv, cfg, colour, preset) for s, e, lv in jobs]
    from tqdm import tqdm

    bar = tqdm(total=len(args), desc="synth", unit="scan", disable=not progress)
    results = []

    def done(r):  # results come in job order
        subject = jobs[len(results)][0]
        results.append(r)
        bar.update()
        if on_scan is not None:
            stem, n_v, n_f, secs, name = r
            on_scan({"scan": f"{subject}/{name}", "status": "ok", "seconds": round(secs, 3),
                     "vertices": n_v, "faces": n_f})

    if int(workers) == 1:
        for a in args:
            done(_job(a))
    else:
        import multiprocessing as mp

        with ProcessPoolExecutor(int(workers), mp_context=mp.get_context("spawn"), initializer=_init_worker) as ex:
            for r in ex.map(_job, args, chunksize=1):
                done(r)
    bar.close()
    records = []
    for (s, e, lv), res in zip(jobs, results):
        stem = scan_stem(s, e, lv)
        records.append({"scan": f"{s}/{res[4]}", "gt": f"{s}/{stem}.json", "subject": s, "expression": e,
                        "level": lv, "split": preset_split(preset, s)})
    index = {"preset": preset, "seed": int(seed), "crop": "per-scan" if preset == "bu3dfe-ood" else crop, "scans": records}
    if colour is not None:
        index["colour"] = colour
    with open(out / "index.json", "w") as fh:
        json.dump(index, fh, indent=1)
        fh.write("\n")
    return records


def _check_colour(colour) -> None:
    from .colour import COLOUR_SOURCES

    if colour is not None and colour not in COLOUR_SOURCES:
        raise SynthError(f"unknown colour {colour!r}; expected None, {', '.join(map(repr, COLOUR_SOURCES))}")


def _scanner_config(crop, config, scanner_options) -> ScannerConfig:
    if crop not in ("face", "none"):
        raise SynthError(f"unknown crop {crop!r}; expected 'face' or 'none'")
    cfg = config or ScannerConfig()
    bad = set(scanner_options) - set(asdict(cfg))
    if bad:
        raise SynthError(f"unknown scanner option(s): {', '.join(sorted(bad))}")
    if crop == "none" and "spacing" not in scanner_options and config is None:
        scanner_options = {**scanner_options, "spacing": 1.5}  # a whole head at 1 mm: ~125k vertices; 1.5 mm: ~55k
    return replace(cfg, crop=crop, **scanner_options)


def generate_scan(out_dir, subject=1, expression="HA", level=4, seed=0, crop="face",
                  config: ScannerConfig | None = None, colour=None, **scanner_options) -> dict:
    """Simulate one scan and write it like a database entry (for demos and quick checks).

    Writes ``out_dir/F0001/F0001_HA04_F3D.ply`` + ``.json`` + ``_dense.npz`` (no ``index.json``);
    the scan is byte-identical to the same scan of :func:`generate` with the same seed and options.

    Parameters
    ----------
    out_dir : path, created if needed.
    subject : int (1-based position in the database order F0001, M0001, F0002, ...) or a name
        like "F0001".
    expression : "NE", "AN", "DI", "FE", "HA", "SA" or "SU".
    level : 1..4 (ignored and set to 0 for "NE").
    seed : int, the database seed.
    crop : "face" or "none"; ``config`` / ``scanner_options`` / ``colour`` as in :func:`generate`.

    Returns
    -------
    dict like an :func:`load_index` record: ``scan``, ``gt``, ``dense`` (absolute paths),
    ``subject``, ``expression``, ``level``, ``split``.
    """
    if isinstance(subject, str):
        _parse_subject(subject)
        name = subject
    else:
        if isinstance(subject, bool) or not isinstance(subject, (int, np.integer)) or subject < 1:
            raise SynthError(f"bad subject {subject!r}: a 1-based number or a name like 'F0001'")
        name = subject_name(int(subject) - 1)
    if expression not in EXPRESSION_CODES:
        raise SynthError(f"unknown expression {expression!r}; expected one of {', '.join(EXPRESSION_CODES)}")
    if expression == "NE":
        level = 0
    elif isinstance(level, bool) or not isinstance(level, (int, np.integer)) or not 1 <= level <= 4:
        raise SynthError(f"bad level {level!r}: levels are 1..4")
    cfg = _scanner_config(crop, config, scanner_options)
    _check_colour(colour)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    _job((str(out), int(seed), name, expression, int(level), cfg, colour, "bu3dfe"))
    stem = scan_stem(name, expression, int(level))
    d = (out / name).resolve()
    return {"scan": str(d / f"{stem}{_scan_suffix(colour)}"), "gt": str(d / f"{stem}.json"), "dense": str(d / f"{stem}_dense.npz"),
            "subject": name, "expression": expression, "level": int(level), "split": subject_split(name)}


def load_index(db_dir):
    """Records of ``db_dir/index.json`` with absolute ``scan``, ``gt`` and ``dense`` paths."""
    db = Path(db_dir)
    p = db / "index.json"
    if not p.is_file():
        raise SynthError(f"{p}: no index.json (not a synthetic database?)")
    with open(p) as fh:
        index = json.load(fh)
    out = []
    for rec in index["scans"]:
        r = dict(rec)
        r["scan"] = str((db / rec["scan"]).resolve())
        r["gt"] = str((db / rec["gt"]).resolve())
        r["dense"] = r["gt"][: -len(".json")] + "_dense.npz"
        out.append(r)
    return out
