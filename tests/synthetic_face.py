"""A quick ICT-model scan for registration tests (independent of facecorr.synth).

Random identity and expression from the vendored ICT model, the face, mouth socket, gums, tongue
and teeth (so an open mouth shows the interior), cropped to a sphere around the nose, each
triangle split in 4 and the vertices jittered (so the scan's vertices are not the template's),
posed by a random rotation + translation. Ground truth: the posed model at the template's ICT
vertices (the template is cut from the same model).
"""

import numpy as np

from facecorr.geometry.mesh import Mesh
from facecorr.names import LANDMARK_IBUG68, LANDMARK_NAMES
from facecorr.template import ICT_MODEL_PATH, load_template

_MODEL = None


def subdivide(v, f):
    """(vertices, faces) with every triangle split in 4 at its edge midpoints (appended after ``v``)."""
    e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    ue, inv = np.unique(e, axis=0, return_inverse=True)
    mid = len(v) + np.arange(len(ue))
    vv = np.vstack([v, 0.5 * (v[ue[:, 0]] + v[ue[:, 1]])])
    m01, m12, m20 = (mid[inv[i * len(f):(i + 1) * len(f)]] for i in range(3))
    a, b, c = f.T
    return vv, np.concatenate([np.stack(x, 1) for x in ((a, m01, m20), (m01, b, m12), (m20, m12, c), (m01, m12, m20))])


def _model():
    global _MODEL
    if _MODEL is None:
        d = np.load(ICT_MODEL_PATH)
        _MODEL = {k: d[k] for k in d.files}
    return _MODEL


def make_scan(seed=0, expression=None, identity_sigma=1.0, noise=0.1, rotate=True, warp=None, eyeballs=False):
    """Returns (scan Mesh, landmarks dict, gt (N_template, 3), expression dict). ``warp``: optional
    function (N, 3) -> (N, 3) of the model's vertices (model frame, mm: y up, z forward), applied
    after identity and expression (a face outside the model's span). ``eyeballs``: the scan also
    has the model's eyeballs (as a range scan sees them through the eye fissures)."""
    m = _model()
    rng = np.random.default_rng(seed)
    names = list(m["expression_names"])
    if expression is None:
        expression = {"jawOpen": 0.5, "mouthSmile_L": 0.6, "mouthSmile_R": 0.6, "browInnerUp_L": 0.5, "browInnerUp_R": 0.5, "cheekSquint_L": 0.4}
    v = m["neutral"].astype(np.float64)
    v = v + np.tensordot(rng.normal(0, identity_sigma, 100), m["identity"].astype(np.float64), axes=1)
    for k, w in expression.items():
        v = v + w * m["expression"][names.index(k)].astype(np.float64)
    if warp is not None:
        v = np.asarray(warp(v), dtype=np.float64)
    parts = list(m["part_names"])
    kept = ("face", "head_neck", "mouth_socket", "gums_tongue", "teeth") + (("eyeball_left", "eyeball_right") if eyeballs else ())
    use = np.isin(m["part_id"], [parts.index(p) for p in kept])
    nose = v[m["landmarks68"][30]]
    use &= np.linalg.norm(v - nose, axis=1) < 125.0
    tri = m["triangles"].astype(np.int64)
    tri = tri[use[tri].all(axis=1)]
    # split every triangle in 4 (edge midpoints) and jitter: new, denser connectivity
    vv, faces = subdivide(v, tri)
    used = np.unique(faces)
    remap = -np.ones(len(vv), np.int64)
    remap[used] = np.arange(len(used))
    sv = vv[used] + rng.normal(0, noise, (len(used), 3))
    faces = remap[faces]
    tpl = load_template()
    gt = v[tpl.ict_vertex]
    lms = v[m["landmarks68"][list(LANDMARK_IBUG68)]]
    if rotate:
        q, _ = np.linalg.qr(rng.standard_normal((3, 3)))
        r = q * np.sign(np.linalg.det(q))
        t = rng.uniform(-300, 300, 3)
    else:
        r, t = np.eye(3), np.zeros(3)
    pose = lambda p: p @ r.T + t
    mesh = Mesh(pose(sv), faces)
    return mesh, dict(zip(LANDMARK_NAMES, pose(lms))), pose(gt), expression
