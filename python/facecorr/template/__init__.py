"""The blendshape template P(alpha) = A0 + sum_k alpha_k A_k that the registration fits.

Everything is cut from the vendored ICT face model (``data/ict/ict_face_model.npz``, MIT) by the
deterministic :func:`build_template`; ``python -m facecorr.template.build`` writes the result to
``data/template.npz`` (committed, float32) and :func:`load_template` reads it (cached).

Frame and units
    The ICT model's own frame, unchanged: millimetres, +y up, +z out of the face, the subject's
    right at -x (iBUG-68 point 36, the right outer eye corner, is at x = -44.6 mm). Keeping the
    model frame means a scan generated from the model and the template share coordinates up to
    the scan's rigid pose.

Rest pose A0 (5325 vertices, 10287 triangles)
    The ICT generic neutral over the model's ``narrow_face`` area (forehead to chin, cheek to
    cheek; no ears, neck, mouth socket, teeth, tongue or eyeballs) minus its PEEL_RINGS = 8
    outermost vertex rings and minus the nostril tubes -- the extent of a BU-3DFE cropped face.

    - The crop: the narrow face's edge loops are concentric (138 vertices each), so peeling
      whole rings keeps a smooth outer boundary (largest turn between consecutive boundary
      edges: 6 degrees). Why peel: on 14 synthetic BU-3DFE-like scans (``facecorr.synth``, tiny
      preset, seed 1, level 4, a perfect registration) the share of scans with data within 2 mm
      of a vertex averages 0.03-0.56 on rings 0-7 (forehead top, temples, under the chin:
      outside the scans' crop), 0.65 on ring 8 and >= 0.8 from ring 10 on; a template reaching
      far beyond the scans only inflates MHD and leaves vertices without data. The eyebrow
      points (iBUG 17-26, ring 12) stay 4 rings inside; the upper jaw line (iBUG 0-4, 12-16) is
      cut (``ibug68`` = -1 there).
    - The nostril tubes (2 x 138 vertices) go deep into the nose where no scanner looks: a
      vertex near the nose is dropped when no horizontal-ish view (yaw -60..60, pitch 0 / 15 deg
      from below) sees it unoccluded and at a non-grazing angle (``build._nostril_interiors``).
      Their cut edges are two small boundary loops inside the nostrils, out of sight.

    Faces are the ICT triangles with all three corners kept, in ICT order and with ICT corner
    order, so a point given by (ICT triangle, barycentric coords) is the same point on the
    template (:attr:`Template.ict_face_to_template_face`): dense ground truth stays exact. The
    cut is one connected, edge-manifold piece with six boundary loops (BOUNDARY_LOOP_NAMES): the
    outer crop line, the two eye openings, the mouth slit (open between the lips, as in the
    model) and the two nostrils. No decimation: 5325 vertices is already inside the 5-10k
    budget.

Blendshapes A_k (K = 14 displacement fields, mm, weights meant in [0, 1])
    Chosen from the 53 ICT (ARKit-named) expression shapes, mostly jaw, lips and mouth corners
    plus brows, as the paper asks (expression fitting: "no two blendshapes add the same kind of
    displacement"). Redundancy is measured by the cosine similarity of the flattened
    displacement fields over the template (``blendshape_cosine`` in the npz); the rule is that no
    two kept fields have cosine >= MAX_BLENDSHAPE_COSINE = 0.65 (the same motion twice) or
    <= MIN_BLENDSHAPE_COSINE = -0.95 (a motion and its exact undoing, which could only cancel).
    Numbers from the build (benches/template_coverage.py measures what the set reproduces):

    Candidates dropped or merged (cosine to the kept shape, over the template):

    - mouthLowerDown_L+R: 0.85 with jawOpen (the lower lip goes down with the jaw) -> dropped.
    - mouthClose -0.86 and mouthPress_L+R -0.84 with jawOpen, 0.85 and 0.84 with mouthShrugLower
      (they close the lips, mostly what the chin raiser does) -> dropped.
    - mouthShrugLower (chin raiser, FACS AU17, in sadness, anger, disgust) is kept although its
      cosine with jawOpen is -0.92: it is the only way to move the chin and lower lip *up*
      (weights are >= 0), and without it 73% of its displacement over mouth + chin is left
      unexplained by the other 13 shapes (bounded least squares). The pair's Gram matrix has
      eigenvalues 1.92 and 0.08: jointly fittable, not degenerate.
    - mouthFunnel: 0.88 with mouthPucker (the same lip protrusion) -> merged, A = (pucker +
      funnel) / 2, cosine 0.97 / 0.97 to the two.
    - mouthDimple_L/_R: 0.79 with mouthSmile, same side -> dropped.
    - noseSneer_L+R 0.89 and mouthShrugUpper 0.75 with mouthUpperUp -> dropped.
    - browInnerUp/browOuterUp of one side: 0.654 -> kept only as left+right sums (0.63).

    Kept, with each one's largest and smallest cosine to the other kept fields
    (``python -m facecorr.template.build`` stores the matrix as ``blendshape_cosine``):

    ==============  ==========================  ==========================
    blendshape      max cosine (with)           min cosine (with)
    ==============  ==========================  ==========================
    jawOpen         +0.21 (mouthFrown_L/_R)     -0.92 (mouthShrugLower)
    mouthSmile_L    +0.57 (mouthStretch_L)      -0.39 (mouthPucker)
    mouthSmile_R    +0.57 (mouthStretch_R)      -0.39 (mouthPucker)
    mouthFrown_L    +0.58 (mouthStretch_L)      -0.41 (mouthUpperUp)
    mouthFrown_R    +0.58 (mouthStretch_R)      -0.41 (mouthUpperUp)
    mouthStretch_L  +0.58 (mouthFrown_L)        -0.57 (mouthPucker)
    mouthStretch_R  +0.58 (mouthFrown_R)        -0.57 (mouthPucker)
    mouthPucker     +0.25 (mouthShrugLower)     -0.57 (mouthStretch_L/_R)
    mouthUpperUp    +0.40 (mouthSmile_L/_R)     -0.41 (mouthFrown_L/_R)
    mouthShrugLower +0.25 (mouthPucker)         -0.92 (jawOpen)
    browInnerUp     +0.63 (browOuterUp)         -0.32 (browDown_L/_R)
    browOuterUp     +0.63 (browInnerUp)         -0.51 (browDown_L/_R)
    browDown_L      +0.02 (browDown_R)          -0.51 (browOuterUp)
    browDown_R      +0.02 (browDown_L)          -0.51 (browOuterUp)
    ==============  ==========================  ==========================

    Recipes: mouthPucker = (ICT mouthPucker + mouthFunnel) / 2; mouthUpperUp, browInnerUp and
    browOuterUp = the ICT _L + _R shapes; the others are the ICT shape of that name. Symmetric
    actions are summed to keep K small; the lip-corner actions and browDown stay split because
    real expressions are often asymmetric there and their left/right cosines are below 0.1.
    Negative cosines are opposite motions (brows down vs up, lips stretched vs puckered, jaw
    down vs chin up), which the weights in [0, 1] keep apart.

Regions (paper Fig. 7: upper face, chin, mouth), per vertex, ``REGION_NAMES`` order
    mouth
        the lips and mouth corners: the vertices whose (x, y) lie in the ellipse around the lip
        contour (iBUG 48-59) with semi-axes half the mouth width + 10 mm and half the lip height
        + 7 mm (its top stays below the subnasal point).
    chin
        the jaw below the lower lip: vertices below the lowest lip point (iBUG 57), outside the
        mouth, that jawOpen moves by at least 35% of its largest displacement (the chin and the
        front of the mandible, not the cheeks near the jaw hinge), and whose rest-pose normal is
        within 60 deg of +z. The last condition leaves out the under-chin surface, which a
        frontal scanner does not see: the paper's expression fit waits until 80% of the chin
        vertices have a valid nearest neighbour on the scan, which an unseen half of the region
        would never allow.
    upper
        the rest (forehead, eyes, nose, cheeks, and the under-chin surface).
    Each region is one edge-connected piece (small islands are given to the neighbouring region).

Landmarks
    ``ibug68``: the ICT ``landmarks68`` vertices mapped to template ids (-1 where outside: the
    upper jaw line 0-4 and 12-16; every evaluation point 17-59 is inside). The 8 landmarks of the method are iBUG 36, 39, 42, 45, 31,
    35, 30, 33 (``facecorr.names.LANDMARK_IBUG68``).

Landmark graph Pa (the paper's Fig. 2 structure; its picture is not in the text we have)
    The 8 landmark positions on A0 with GRAPH_EDGES (indices in LANDMARK_NAMES order): the eye
    corners in a chain (outer-inner-inner-outer), each inner eye corner to the nose tip and to
    its subalare, each outer eye corner to its subalare, and the nose points to each other (both
    subalare to the tip and to the subnasal, tip to subnasal): 14 edges, a planar triangulated
    graph that fixes left/right and up/down once the nose points are labelled.

Modules
    :mod:`.model`: the :class:`Template` data model, the npz reader (:func:`template_from_arrays`,
    :func:`load_template`), paths and naming constants. :mod:`.build`: the builder from the ICT
    model (:func:`build_template`, :func:`save_template`; ``python -m facecorr.template.build``),
    imported on first use of one of its names, so loading the template needs neither scipy nor
    the builder.
"""

from __future__ import annotations

from .model import (
    BOUNDARY_LOOP_NAMES, CHIN, DATA_DIR, GRAPH_EDGES, ICT_MODEL_PATH, MOUTH, REGION_NAMES,
    TEMPLATE_PATH, UPPER, Template, eye_caps, load_template, template_from_arrays,
)

#: Names served from :mod:`.build`, imported on first access (PEP 562): ``python -m
#: facecorr.template.build`` then runs a module the package has not imported yet.
_BUILD_NAMES = (
    "BLENDSHAPE_RECIPES", "MAX_BLENDSHAPE_COSINE", "MIN_BLENDSHAPE_COSINE", "PEEL_RINGS",
    "MOUTH_MARGIN_X", "MOUTH_MARGIN_Y", "CHIN_JAW_FRACTION", "CHIN_MIN_NORMAL_Z",
    "REGION_SMOOTHING_PASSES", "blendshape_cosine", "build_template", "save_template",
    "visible_points",
)

__all__ = [
    "BOUNDARY_LOOP_NAMES", "CHIN", "DATA_DIR", "GRAPH_EDGES", "ICT_MODEL_PATH", "MOUTH",
    "REGION_NAMES", "TEMPLATE_PATH", "UPPER", "Template", "eye_caps", "load_template", "template_from_arrays",
    *_BUILD_NAMES,
]


def __getattr__(name: str):
    if name in _BUILD_NAMES:
        from . import build

        return getattr(build, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_BUILD_NAMES))
