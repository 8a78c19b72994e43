"""One scan end to end (:mod:`.correspond`: landmarks -> registration -> :class:`Result`) and many
scans (:mod:`.batch`: a resumable folder run that survives bad scans)."""

from .correspond import CorrespondOptions, Result, correspond

__all__ = ["CorrespondOptions", "Result", "correspond"]
