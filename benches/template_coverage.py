"""How much of each ICT expression shape the template's blendshapes reproduce.

For every ICT expression shape E (restricted to the template), fit weights alpha in [0, 1]
minimising ||sum_k alpha_k A_k - E||^2 (scipy lsq_linear) and report the share of E's squared
displacement that is left unexplained, over the whole template and over the mouth + chin regions.
Run: python benches/template_coverage.py
"""

import numpy as np
from scipy.optimize import lsq_linear

from facecorr.template import ICT_MODEL_PATH, REGION_NAMES, load_template

t = load_template()
with np.load(ICT_MODEL_PATH) as d:
    names = [str(s) for s in d["expression_names"]]
    expr = d["expression"][:, t.ict_vertex].astype(np.float64)
a = t.blendshapes.reshape(t.n_blendshapes, -1).T
lower = np.isin(t.regions, [REGION_NAMES.index("mouth"), REGION_NAMES.index("chin")])
print(f"{'ICT shape':18s} {'max mm':>7s} {'unexplained all':>16s} {'mouth+chin':>11s}  main weights")
for name, e in zip(names, expr):
    fit = lsq_linear(a, e.ravel(), bounds=(0, 1))
    r = (a @ fit.x - e.ravel()).reshape(-1, 3)
    un_all = (r ** 2).sum() / max((e ** 2).sum(), 1e-12)
    low_energy = (e[lower] ** 2).sum()
    un_low = (r[lower] ** 2).sum() / low_energy if low_energy > 0.05 * (e ** 2).sum() else np.nan
    low_text = "-" if np.isnan(un_low) else f"{100 * un_low:.0f}%"
    top = np.argsort(-fit.x)[:2]
    w = ", ".join(f"{t.blendshape_names[k]} {fit.x[k]:.2f}" for k in top if fit.x[k] > 0.05)
    print(f"{name:18s} {np.linalg.norm(e, axis=1).max():7.1f} {100 * un_all:15.0f}% {low_text:>11s}  {w}")
