"""FACS-style recipes of the BU-3DFE expressions as ICT (ARKit) expression-shape weights.

Each prototypic expression is written as its usual FACS action units (Ekman & Friesen's EMFACS
prototypes) mapped to ARKit shapes; ``_L``/``_R`` shapes are given once as ``name_LR``. The
intensity level l in 1..4 scales the whole recipe by :data:`LEVEL_SCALE` ``[l]`` (BU-3DFE's four
levels, from barely visible to the apex). Per scan, :func:`expression_weights` adds a small random
variation: each weight is multiplied by ``1 + N(0, 0.1^2)``, left and right differ by
``N(0, 0.06^2)``, and a little idle motion (blinks, gaze, lip press) is added at any level, so
no two scans of the same class are identical. Weights are clipped to [0, 1].

AU mapping used (ARKit names):

- NE: nothing (idle motion only).
- AN (AU4 brow lowerer, AU5 upper lid raiser, AU7 lid tightener, AU23/24 lip tightener/pressor,
  AU17 chin raiser): browDown, eyeSquint, eyeWide (small), noseSneer (small), mouthPress,
  mouthShrugLower, mouthFrown.
- DI (AU9 nose wrinkler, AU10 upper lip raiser, AU15 lip corner depressor, AU17, AU4, AU6/7):
  noseSneer, mouthUpperUp, mouthFrown, mouthShrugLower, browDown, cheekSquint, eyeSquint,
  jawOpen (small: the raised upper lip shows the teeth).
- FE (AU1+2+4 brows, AU5 wide eyes, AU20 lip stretcher, AU26 jaw drop): browInnerUp,
  browOuterUp, browDown (small), eyeWide, mouthStretch, jawOpen, mouthLowerDown.
- HA (AU6 cheek raiser, AU12 lip corner puller, AU25 lips part): cheekSquint, mouthSmile,
  eyeSquint, mouthUpperUp + mouthLowerDown + jawOpen (teeth show at high levels), mouthDimple.
- SA (AU1 inner brow raiser, AU4, AU15, AU17): browInnerUp, browDown (small), mouthFrown,
  mouthShrugLower, mouthPress (small), eyeBlink (small: lids droop), eyeLookDown.
- SU (AU1+2 brows, AU5, AU26 jaw drop / AU27 mouth stretch): browInnerUp, browOuterUp,
  eyeWide, jawOpen, mouthFunnel (small), mouthLowerDown.
"""

from __future__ import annotations

import numpy as np

#: Expression codes in BU-3DFE order; index used in per-scan seeds.
EXPRESSION_CODES = ("NE", "AN", "DI", "FE", "HA", "SA", "SU")

#: Scale of the recipe at intensity level 1..4 (index 0 = neutral).
LEVEL_SCALE = (0.0, 0.35, 0.6, 0.8, 1.0)

RECIPES: dict[str, dict[str, float]] = {
    "NE": {},
    "AN": {
        "browDown_LR": 1.0, "eyeSquint_LR": 0.6, "eyeWide_LR": 0.15, "noseSneer_LR": 0.35,
        "mouthPress_LR": 0.8, "mouthShrugLower": 0.5, "mouthFrown_LR": 0.5, "mouthRollUpper": 0.15,
    },
    "DI": {
        "noseSneer_LR": 1.0, "mouthUpperUp_LR": 0.9, "mouthFrown_LR": 0.5, "mouthShrugLower": 0.6,
        "browDown_LR": 0.6, "cheekSquint_LR": 0.7, "eyeSquint_LR": 0.6, "jawOpen": 0.08,
    },
    "FE": {
        "browInnerUp_LR": 1.0, "browOuterUp_LR": 0.5, "browDown_LR": 0.25, "eyeWide_LR": 1.0,
        "mouthStretch_LR": 0.9, "jawOpen": 0.3, "mouthLowerDown_LR": 0.6, "mouthUpperUp_LR": 0.2,
    },
    "HA": {
        "mouthSmile_LR": 1.0, "cheekSquint_LR": 0.8, "eyeSquint_LR": 0.5, "mouthUpperUp_LR": 0.35,
        "mouthLowerDown_LR": 0.35, "jawOpen": 0.15, "mouthDimple_LR": 0.3,
    },
    "SA": {
        "browInnerUp_LR": 0.9, "browDown_LR": 0.3, "mouthFrown_LR": 1.0, "mouthShrugLower": 0.6,
        "mouthPress_LR": 0.25, "eyeBlink_LR": 0.25, "eyeLookDown_LR": 0.3, "mouthRollLower": 0.15,
    },
    "SU": {
        "browInnerUp_LR": 1.0, "browOuterUp_LR": 1.0, "eyeWide_LR": 0.9, "jawOpen": 0.55,
        "mouthFunnel": 0.2, "mouthLowerDown_LR": 0.3,
    },
}

#: Idle motion added to every scan: shape -> upper bound of a uniform weight.
IDLE = {"eyeBlink_LR": 0.08, "eyeLookUp_LR": 0.1, "eyeLookDown_LR": 0.1, "mouthPress_LR": 0.05,
        "browInnerUp_LR": 0.05}


def _expand(recipe: dict[str, float]) -> dict[str, float]:
    out: dict[str, float] = {}
    for name, w in recipe.items():
        if name.endswith("_LR"):
            out[name[:-3] + "_L"] = out.get(name[:-3] + "_L", 0.0) + w
            out[name[:-3] + "_R"] = out.get(name[:-3] + "_R", 0.0) + w
        else:
            out[name] = out.get(name, 0.0) + w
    return out


def expression_weights(names: tuple, code: str, level: int, rng: np.random.Generator | None = None) -> np.ndarray:
    """Weights (len(names),) in [0, 1] of expression ``code`` at intensity ``level``.

    ``level`` is 0 for "NE" and 1..4 otherwise. With ``rng`` None the nominal recipe is returned
    (no variation, no idle motion).
    """
    if code not in RECIPES:
        raise ValueError(f"unknown expression {code!r}; expected one of {', '.join(EXPRESSION_CODES)}")
    if (code == "NE") != (level == 0) or not 0 <= level <= 4:
        raise ValueError(f"level {level} is invalid for {code} (NE has level 0, others 1..4)")
    w = np.zeros(len(names))
    index = {n: i for i, n in enumerate(names)}
    scale = LEVEL_SCALE[level]
    for name, v in _expand(RECIPES[code]).items():
        w[index[name]] = v * scale
    if rng is not None:
        w *= 1.0 + rng.normal(0.0, 0.1, len(w))
        for i, n in enumerate(names):  # left/right asymmetry
            if n.endswith("_L") and n[:-2] + "_R" in index:
                a = rng.normal(0.0, 0.06)
                w[i] *= 1.0 + a
                w[index[n[:-2] + "_R"]] *= 1.0 - a
        for name, hi in _expand(IDLE).items():
            w[index[name]] += rng.uniform(0.0, hi)
    return np.clip(w, 0.0, 1.0)
