"""Registration of the blendshape template onto a scan (paper §4, floor 4: a stage).

:func:`register` (:mod:`.register`) runs landmark alignment (:mod:`.alignment`), expression +
identity fitting (:mod:`.expression`, :mod:`.identity`), the mouth, eye and nose searches
(:mod:`.mouth`, :mod:`.eyes`, :mod:`.nose` with :mod:`.feature_search`: lips, lids and alae moved
where the scan's are) and shape fitting (:mod:`.shape`, Rust); :mod:`.beard` finds a beard's rough
layer and redoes the shape fit without it;
:mod:`.identity_training` learns the identity basis. Imports only the floors below (never
``landmarks``).
"""

from .alignment import align_landmarks
from .expression import ExpressionOptions, fit_expression
from .register import RegisterOptions, RegistrationResult, refit_shape, register
from .shape import ShapeFitOptions, fit_shape

__all__ = ["ExpressionOptions", "RegisterOptions", "RegistrationResult", "ShapeFitOptions", "align_landmarks",
           "fit_expression", "fit_shape", "refit_shape", "register"]
