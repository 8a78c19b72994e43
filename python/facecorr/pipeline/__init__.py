"""One scan end to end (:mod:`.correspond`: landmarks -> registration -> :class:`Result`; the
landmarks refined by it, :mod:`.landmarks`) and many
scans (:mod:`.batch`: a resumable folder run that survives bad scans)."""

from .correspond import CorrespondOptions, Result, correspond
from .landmarks import locate_landmarks

__all__ = ["CorrespondOptions", "Result", "correspond", "locate_landmarks"]
