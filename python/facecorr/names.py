"""Names and index conventions shared by every stage (README, "Architecture")."""

#: The 8 landmarks of the method, in this order everywhere ("right" = the subject's right, -x).
LANDMARK_NAMES = (
    "right_outer_eye_corner",
    "right_inner_eye_corner",
    "left_inner_eye_corner",
    "left_outer_eye_corner",
    "right_subalare",
    "left_subalare",
    "nose_tip",
    "subnasal",
)

#: iBUG-68 index (0-based) of each of the 8 landmarks, in LANDMARK_NAMES order.
LANDMARK_IBUG68 = (36, 39, 42, 45, 31, 35, 30, 33)

#: iBUG-68 points of the evaluation regions (paper Table 3), 0-based. Points 17-21 and 36-41
#: are on the subject's right (image left in the usual annotation).
IBUG68_REGIONS = {
    "right_eyebrow": tuple(range(17, 22)),
    "left_eyebrow": tuple(range(22, 27)),
    "right_eye": tuple(range(36, 42)),
    "left_eye": tuple(range(42, 48)),
    "nose": tuple(range(27, 36)),
    "mouth": tuple(range(48, 60)),
}

#: BU-3DFE expression codes (file names) and full names.
EXPRESSIONS = {
    "NE": "neutral",
    "AN": "anger",
    "DI": "disgust",
    "FE": "fear",
    "HA": "happiness",
    "SA": "sadness",
    "SU": "surprise",
}

#: Indices into LANDMARK_NAMES of the nose points (the nose-first search and the patch radii).
R_SUBALARE, L_SUBALARE, NOSE_TIP, SUBNASAL = 4, 5, 6, 7
