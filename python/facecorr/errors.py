"""Exception types raised by facecorr.

Every error a user can cause is a :class:`FacecorrError` subclass with a one-line message; the
CLI prints that line and exits 2. Anything else (including a Rust panic, which surfaces as
``RuntimeError("facecorr internal error in ...")``) is a bug of ours and exits 1.
"""


class FacecorrError(Exception):
    """Base class of all errors caused by the input or the call."""


class MeshError(FacecorrError, ValueError):
    """The mesh is unusable: empty, NaN/inf coordinates, no faces, bad indices, ..."""


class MeshFileError(FacecorrError, OSError):
    """The file is missing, unreadable, of an unknown format or broken."""


class UnitsError(FacecorrError, ValueError):
    """The units are unknown or cannot be inferred from the face's size."""


class ModelError(FacecorrError, ValueError):
    """A trained landmark model file is missing, broken or of another version."""


class LandmarkError(FacecorrError):
    """Landmarks could not be predicted (no face, hopeless input)."""


class RegistrationError(FacecorrError):
    """The template could not be fitted to the scan."""


class OutputError(FacecorrError, OSError):
    """An output cannot be written there: a folder, a parent that is a file, no permission, two
    outputs (or an output and an input) naming the same file, a failed write."""


class ShapeModelError(FacecorrError, ValueError):
    """A statistical shape model cannot be built or read: no usable results, results that do not
    match, a missing or broken model file."""
