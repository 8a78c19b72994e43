"""Out-of-model identities for the ``bu3dfe-ood`` preset (issue 14): faces the identity basis and
the landmark model were not learned from.

A subject of the preset is built in three steps, all on the ICT topology (so the dense ground
truth stays exact: a scan vertex is still a barycentric point of an ICT triangle of the final
head):

1. **Identity at 2-3 sigma** (:func:`ood_identity`): the weights of the ``extreme_modes`` (10)
   leading ICT identity modes (the largest: they carry most of the shape variance) have
   magnitude uniform in ``identity_sigma`` (2-3 standard deviations) and a random sign, the
   others are ``N(0, 1)`` truncated at 2.5 like the ``bu3dfe`` preset's subjects, from which the
   packaged identity basis and landmark model were learned. (All 100 modes at 2-3 sigma give
   caricatures no scanner meets: mouths above the subnasal, 40 mm chins.)
2. **Per-feature changes** (:func:`feature_displacement`, :data:`FEATURES`): each of eye width,
   eye spacing, nose length, nose width, brow-ridge height, brow-ridge projection, lip thickness,
   chin slope and forehead slope is scaled by a factor ``1 + U(-0.2, 0.2)``. A feature is a
   displacement field of the subject's neutral face, defined by its iBUG-68 points (module
   constants below) and confined to a soft region (weight 1 inside, a cosine falloff to 0; see
   :func:`soft_weight`). The displacement is a function of the material point, so it moves
   with the skin under expression.
3. **A smooth non-linear warp** (:func:`smooth_warp`): a sum of 4-8 Gaussian radial bumps with
   widths of 30-60 mm and random directions, scaled so that its largest displacement over the
   face is 3-8 mm.

The head of one scan is ``V = deform(identity, expression) + D_feat(X) + D_warp(X + D_feat(X))``
with ``X`` the subject's neutral (identity only), everything in mm, model frame (+y up, +z out
of the face, the subject's right at -x).

Subjects of the preset are test-only: :func:`ood_split` puts a fixed third of them
(``F0002, M0003, F0005, ...``: 0-based position ``i`` with ``i % 3 == 2``) in ``"ood_holdout"``,
which nobody tunes on, and the rest in ``"ood_test"``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .model import ICTModel, deform, sample_identity

__all__ = ["OODConfig", "FEATURES", "OOD_SPLITS", "ood_split", "ood_identity", "smooth_warp", "SmoothWarp",
           "soft_weight", "feature_displacement", "OODSubject", "ood_subject", "ood_head"]

#: The features whose size the preset changes, in the order their factors are drawn.
FEATURES = ("eye_width", "eye_spacing", "nose_length", "nose_width", "brow_height", "brow_projection",
            "lip_thickness", "chin_slope", "forehead_slope")

#: The two splits of the preset.
OOD_SPLITS = ("ood_test", "ood_holdout")

_R_EYE, _L_EYE = tuple(range(36, 42)), tuple(range(42, 48))
_R_BROW, _L_BROW = tuple(range(17, 22)), tuple(range(22, 27))
_NOSE = tuple(range(27, 36))
_OUTER_LIPS, _INNER_LIPS = tuple(range(48, 60)), tuple(range(60, 68))


@dataclass(frozen=True)
class OODConfig:
    """Ranges of the out-of-model changes (uniform (low, high); mm, standard deviations)."""

    identity_sigma: tuple = (2.0, 3.0)
    extreme_modes: int = 10
    warp_amplitude_mm: tuple = (3.0, 8.0)
    warp_scale_mm: tuple = (30.0, 60.0)
    warp_bumps: tuple = (4, 8)
    feature_change: float = 0.20


def ood_split(index: int) -> str:
    """"ood_holdout" for every third subject (0-based position ``index % 3 == 2``), else "ood_test"."""
    return OOD_SPLITS[1] if int(index) % 3 == 2 else OOD_SPLITS[0]


def ood_identity(rng: np.random.Generator, n_modes: int, sigma=(2.0, 3.0), extreme_modes: int = 10) -> np.ndarray:
    """(n_modes,) identity weights: the first ``extreme_modes`` with ``|w_k| ~ U(sigma)`` and random
    signs, the rest ``N(0, 1)`` truncated at 2.5 (:func:`facecorr.synth.model.sample_identity`)."""
    w = sample_identity(rng, n_modes)
    k = min(int(extreme_modes), n_modes)
    w[:k] = rng.uniform(sigma[0], sigma[1], k) * rng.choice([-1.0, 1.0], k)
    return w


@dataclass(frozen=True)
class SmoothWarp:
    """A smooth displacement field ``d(x) = sum_j a_j exp(-|x - c_j|^2 / (2 s_j^2))``.

    Attributes
    ----------
    centres : (K, 3) mm. directions : (K, 3) mm (the bump amplitudes ``a_j``). scales : (K,) mm.
    """

    centres: np.ndarray
    directions: np.ndarray
    scales: np.ndarray

    def __call__(self, X: np.ndarray) -> np.ndarray:
        """(N, 3) displacement (mm) at the points ``X`` (N, 3) mm."""
        X = np.asarray(X, dtype=np.float64)
        out = np.zeros_like(X)
        for c, a, s in zip(self.centres, self.directions, self.scales):
            g = np.exp(-np.sum((X - c) ** 2, axis=1) / (2.0 * s * s))
            out += g[:, None] * a
        return out

    def lipschitz_bound(self) -> float:
        """An upper bound of ``|d(x) - d(y)| / |x - y|`` (each bump's gradient is at most
        ``|a_j| / (s_j sqrt(e))``)."""
        return float(np.sum(np.linalg.norm(self.directions, axis=1) / (self.scales * np.sqrt(np.e))))


def smooth_warp(rng: np.random.Generator, face_points: np.ndarray, cfg: OODConfig = OODConfig()) -> SmoothWarp:
    """A random :class:`SmoothWarp` whose largest displacement over ``face_points`` (N, 3) mm is
    uniform in ``cfg.warp_amplitude_mm``, with bump widths in ``cfg.warp_scale_mm`` centred on
    random face points."""
    k = int(rng.integers(cfg.warp_bumps[0], cfg.warp_bumps[1] + 1))
    centres = face_points[rng.choice(len(face_points), k, replace=False)]
    scales = rng.uniform(cfg.warp_scale_mm[0], cfg.warp_scale_mm[1], k)
    dirs = rng.normal(size=(k, 3))
    amplitude = rng.uniform(*cfg.warp_amplitude_mm)
    w = SmoothWarp(centres, dirs, scales)
    peak = float(np.linalg.norm(w(face_points), axis=1).max())
    return SmoothWarp(centres, dirs * (amplitude / max(peak, 1e-12)), scales)


def soft_weight(X: np.ndarray, centre, radii, outer: float = 1.8, p: float = 4.0) -> np.ndarray:
    """(N,) weights of a soft box-like region: 1 where the p-norm distance
    ``t = (sum_i |(x_i - c_i) / r_i|^p)^(1/p)`` is at most 1, ``0.5 (1 + cos(pi (t - 1) / (outer - 1)))``
    between 1 and ``outer``, 0 beyond (continuous with its first derivative)."""
    d = np.abs((np.asarray(X, float) - np.asarray(centre, float)) / np.asarray(radii, float))
    t = np.sum(d**p, axis=1) ** (1.0 / p)
    u = np.clip((t - 1.0) / (outer - 1.0), 0.0, 1.0)
    return 0.5 * (1.0 + np.cos(np.pi * u))


def _ramp(u: np.ndarray, delta: float = 3.0) -> np.ndarray:
    """0 for u <= 0, u^2 / (2 delta) up to delta, then u - delta / 2 (C1)."""
    u = np.asarray(u, float)
    return np.where(u <= 0.0, 0.0, np.where(u < delta, u * u / (2.0 * delta), u - delta / 2.0))


def _band(v: np.ndarray, full: float, zero: float) -> np.ndarray:
    """1 for |v| <= full, cosine falloff to 0 at |v| = zero."""
    u = np.clip((np.abs(v) - full) / (zero - full), 0.0, 1.0)
    return 0.5 * (1.0 + np.cos(np.pi * u))


def feature_displacement(X: np.ndarray, ibug: np.ndarray, factors: dict) -> np.ndarray:
    """(N, 3) displacement (mm) that scales the named features of the neutral face ``X``.

    Parameters
    ----------
    X : (N, 3) the subject's neutral head, mm, model frame (ICT vertex order).
    ibug : (68, 3) its iBUG-68 points, mm.
    factors : {feature name: factor}; a missing feature is left as it is (factor 1). Names from
        :data:`FEATURES`:

        - ``eye_width``: each eye's x extent about its centre (mean of its 6 iBUG points);
        - ``eye_spacing``: the x distance of the two eye centres (each eye region shifted);
        - ``nose_length``: the height of the nose from the nasion (27) down (27-35 move);
        - ``nose_width``: the x extent of the lower nose about the midline (alar width 31-35);
        - ``brow_height``: the brows' height above the eyes (mean y of brow minus eye points);
        - ``brow_projection``: how far the brows stand in front of the eyes (mean z difference);
        - ``lip_thickness``: the lips' height about the mouth line (mean y of the inner lips);
        - ``chin_slope``: dz/dy of the profile below the lower lip (57 -> 8);
        - ``forehead_slope``: dz/dy of the profile above the brows.

    Returns
    -------
    (N, 3) float64 displacement, the sum of each feature's field.
    """
    X = np.asarray(X, dtype=np.float64)
    p = np.asarray(ibug, dtype=np.float64)
    D = np.zeros_like(X)
    f = {k: float(v) - 1.0 for k, v in factors.items() if float(v) != 1.0}
    bad = set(f) - set(FEATURES)
    if bad:
        raise ValueError(f"unknown feature(s): {', '.join(sorted(bad))}")
    mid_x = 0.5 * (p[_R_EYE, 0].mean() + p[_L_EYE, 0].mean())
    for eye, brow in ((_R_EYE, _R_BROW), (_L_EYE, _L_BROW)):
        c = p[list(eye)].mean(0)
        hw = 0.5 * abs(p[eye[3], 0] - p[eye[0], 0])
        hh = max(np.abs(p[list(eye), 1] - c[1]).max(), 0.3 * hw)
        if "eye_width" in f:
            w = soft_weight(X, c, (1.1 * hw, 1.2 * hh, 25.0), outer=1.7)
            D[:, 0] += f["eye_width"] * (X[:, 0] - c[0]) * w
        if "eye_spacing" in f:
            w = soft_weight(X, c, (1.2 * hw, 1.3 * hh, 30.0), outer=1.8)
            D[:, 0] += f["eye_spacing"] * (c[0] - mid_x) * w
        if "brow_height" in f or "brow_projection" in f:
            b = p[list(brow)].mean(0)
            lo, hi = p[list(brow)].min(0), p[list(brow)].max(0)
            mid, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
            # a box around the brow points (x: 3 mm margin, 8 mm falloff, so the two brows' regions
            # do not meet between them; y: 2 mm margin, 10 mm falloff, clear of the eyes)
            w = _band(X[:, 0] - mid[0], half[0] + 3.0, half[0] + 11.0) \
                * _band(X[:, 1] - mid[1], half[1] + 2.0, half[1] + 12.0) \
                * _band(X[:, 2] - mid[2], half[2] + 10.0, half[2] + 25.0)
            if "brow_height" in f:
                D[:, 1] += f["brow_height"] * (b[1] - c[1]) * w
            if "brow_projection" in f:
                D[:, 2] += f["brow_projection"] * (b[2] - c[2]) * w
    alar_hw = 0.5 * abs(p[35, 0] - p[31, 0])
    nose_z = p[list(_NOSE), 2].mean()
    xz = X[:, [0, 2]]
    if "nose_length" in f:
        # the nose below the nasion (27) stretches along y; the upper lip takes up the change
        # below the subnasal over a falloff of 1.6x (at least 10 mm) the subnasal's displacement
        w = soft_weight(xz, (p[30, 0], nose_z), (1.3 * alar_hw, 30.0), outer=1.8)
        shift = abs(f["nose_length"] * (p[33, 1] - p[27, 1]))
        w = w * _band(np.minimum(X[:, 1] - p[33, 1], 0.0), 0.0, max(10.0, 1.6 * shift))
        w = w * _band(np.maximum(X[:, 1] - p[27, 1], 0.0), 0.0, 15.0)
        D[:, 1] += f["nose_length"] * (X[:, 1] - p[27, 1]) * w
    if "nose_width" in f:
        w = soft_weight(xz, (p[30, 0], nose_z), (1.3 * alar_hw, 30.0), outer=1.8) * \
            _band(X[:, 1] - 0.5 * (p[30, 1] + p[33, 1]), 0.5 * abs(p[30, 1] - p[33, 1]) + 2.0,
                  0.5 * abs(p[30, 1] - p[33, 1]) + 12.0)
        D[:, 0] += f["nose_width"] * (X[:, 0] - p[30, 0]) * w
    if "lip_thickness" in f:
        y_st = p[list(_INNER_LIPS), 1].mean()
        hw = 0.5 * abs(p[54, 0] - p[48, 0])
        top, bottom = p[list(_OUTER_LIPS), 1].max(), p[list(_OUTER_LIPS), 1].min()
        ctr, half = 0.5 * (top + bottom), 0.5 * (top - bottom)
        shift = abs(f["lip_thickness"]) * max(top - y_st, y_st - bottom)
        w = soft_weight(xz, (p[list(_OUTER_LIPS), 0].mean(), p[list(_OUTER_LIPS), 2].mean()), (1.25 * hw, 30.0), outer=1.5)
        # falloff over 3x the largest shift, but within 80 % of the gap to the subnasal / menton
        gap = max(min(p[33, 1] - top, bottom - p[8, 1]), 2.0)
        w = w * _band(X[:, 1] - ctr, half + 1.0, half + 1.0 + float(np.clip(3.0 * shift, 2.0, 0.8 * gap)))
        D[:, 1] += f["lip_thickness"] * (X[:, 1] - y_st) * w
    face_hw = 0.5 * abs(p[16, 0] - p[0, 0])
    if "chin_slope" in f:
        dy = p[8, 1] - p[57, 1]
        slope = (p[8, 2] - p[57, 2]) / dy if abs(dy) > 1e-6 else 0.0
        w = _band(X[:, 0] - p[8, 0], 0.5 * face_hw, face_hw) * _band(np.minimum(X[:, 1] - p[8, 1], 0.0), 10.0, 40.0)
        D[:, 2] += f["chin_slope"] * slope * -_ramp(p[57, 1] - X[:, 1]) * w
    if "forehead_slope" in f:
        y_g = p[list(_R_BROW + _L_BROW), 1].max() + 3.0
        front = (np.abs(X[:, 0] - p[27, 0]) < 4.0) & (X[:, 2] > p[27, 2] - 30.0)
        ys, zs = X[front, 1], X[front, 2]
        sel = (ys > y_g + 10.0) & (ys < y_g + 50.0)
        slope = float(np.polyfit(ys[sel], zs[sel], 1)[0]) if sel.sum() >= 3 else 0.0
        w = _band(X[:, 0] - p[27, 0], 0.6 * face_hw, 1.1 * face_hw) * _band(np.maximum(X[:, 1] - y_g, 0.0), 80.0, 130.0)
        D[:, 2] += f["forehead_slope"] * slope * _ramp(X[:, 1] - y_g) * w
    return D


@dataclass(frozen=True)
class OODSubject:
    """One subject of the preset.

    Attributes
    ----------
    identity : (100,) ICT identity weights. factors : {feature: factor}. warp : SmoothWarp.
    neutral : (N, 3) mm, the final neutral head (identity, features, warp).
    warp_peak_mm : the warp's largest displacement over the face part, mm.
    """

    identity: np.ndarray
    factors: dict
    warp: SmoothWarp
    neutral: np.ndarray
    warp_peak_mm: float

    def info(self) -> dict:
        """JSON-ready description (the ground truth's ``"ood"`` field)."""
        return {"identity_leading_sd": np.abs(self.identity[:10]).round(3).tolist(),
                "features": {k: round(v, 4) for k, v in self.factors.items()},
                "warp": {"bumps": len(self.warp.scales), "scales_mm": self.warp.scales.round(2).tolist(),
                         "max_mm_on_face": round(self.warp_peak_mm, 4)}}


def ood_subject(model: ICTModel, rng: np.random.Generator, cfg: OODConfig = OODConfig()) -> OODSubject:
    """Draw one out-of-model subject (identity, feature factors, warp) from ``rng``."""
    w = ood_identity(rng, model.identity.shape[0], cfg.identity_sigma, cfg.extreme_modes)
    factors = {k: float(1.0 + rng.uniform(-cfg.feature_change, cfg.feature_change)) for k in FEATURES}
    X = deform(model, w, np.zeros(model.expression.shape[0]))
    Dfeat = feature_displacement(X, X[model.landmarks68], factors)
    Xf = X + Dfeat
    face = Xf[model.part_id == model.part_names.index("face")]
    warp = smooth_warp(rng, face, cfg)
    dw = warp(Xf)
    peak = float(np.linalg.norm(dw[model.part_id == model.part_names.index("face")], axis=1).max())
    return OODSubject(w, factors, warp, Xf + dw, peak)


def ood_head(model: ICTModel, subject: OODSubject, expression_weights: np.ndarray) -> np.ndarray:
    """(N, 3) mm: the subject's head showing an expression (the expression on the ICT identity,
    plus the subject's feature and warp displacements, which ride on the skin)."""
    V = deform(model, subject.identity, expression_weights)
    X = deform(model, subject.identity, np.zeros_like(expression_weights))
    return V + (subject.neutral - X)
