"""--neutral measure (issue 15) on a batch results folder with one sub-folder per subject
(<subject>/<stem>.ply, BU-3DFE names, one *_NE00_* scan each): the mean vertex distance after
Kabsch between each expressive result (raw, and its neutral_shape) and the subject's NE00 result,
per expression.

    python benches/neutral_consistency.py RESULTS_DIR [--basis B.npz] [--residual R.npz]
        [--residual-modes 10 ...] [--residual-prior 300 ...]

--basis / --residual: the identity and residual expression bases (default: the packaged ones);
several --residual-modes / --residual-prior values: one table row set per pair (a sweep, for
choosing them on held-out training subjects: the packaged bases were learned from every
training subject).
"""
import argparse
import collections
import glob
import itertools
import time

import numpy as np
import trimesh

from facecorr.geometry.transforms import kabsch
from facecorr.registration.identity import load_identity_basis
from facecorr.registration.neutral import NeutralOptions, neutral_shape
from facecorr.template import load_template

ap = argparse.ArgumentParser()
ap.add_argument("results")
ap.add_argument("--basis")
ap.add_argument("--residual")
ap.add_argument("--residual-modes", type=int, nargs="+", default=[NeutralOptions.residual_modes])
ap.add_argument("--residual-prior", type=float, nargs="+", default=[NeutralOptions.residual_prior])
a = ap.parse_args()
tpl = load_template()
basis = load_identity_basis(a.basis) if a.basis else None
residual = load_identity_basis(a.residual) if a.residual else None


def dist(p, q):
    r, t = kabsch(p, q)
    return np.linalg.norm(p @ r.T + t - q, axis=1).mean()


scans = []
for subj in sorted(glob.glob(a.results + "/*/")):
    ne = glob.glob(subj + "*_NE00_F3D.ply")[0]
    vne = np.asarray(trimesh.load(ne, process=False).vertices)
    for f in sorted(glob.glob(subj + "*_F3D.ply")):
        if "NE00" not in f:
            scans.append((f.split("_")[-2][:2], np.asarray(trimesh.load(f, process=False).vertices), vne))
for modes, prior in itertools.product(a.residual_modes, a.residual_prior):
    opts = NeutralOptions(residual_modes=modes, residual_prior=prior)
    by, tt = collections.defaultdict(list), []
    for e, v, vne in scans:
        t = time.perf_counter()
        vn, _ = neutral_shape(v, tpl, basis, opts, residual)
        tt.append(time.perf_counter() - t)
        by[e].append((dist(v, vne), dist(vn, vne)))
    print(f"residual modes {modes}, residual prior {prior:g} mm^2:")
    print("| expression | scans | raw registration to the NE registration, mm | neutral shape, mm | ratio |\n"
          "|---|---|---|---|---|")
    allv = []
    for e, v in sorted(by.items()):
        v = np.array(v)
        allv += list(v)
        raw, neutral = v[:, 0].mean(), v[:, 1].mean()
        print(f"| {e} | {len(v)} | {raw:.2f} | {neutral:.2f} | {raw / neutral:.2f} |")
    v = np.array(allv)
    print(f"| all | {len(v)} | {v[:, 0].mean():.2f} | {v[:, 1].mean():.2f} | {v[:, 0].mean() / v[:, 1].mean():.2f} |")
    print("median seconds per neutral_shape", round(float(np.median(tt)), 4))
