"""Evaluation on a synthetic database with exact ground truth (floor 6, above the pipeline):
:mod:`.metrics` (region and landmark errors, MHD, dense error, tables), :mod:`.landmarks` (the
paper's Tables 1/2) and :mod:`.registration` (Table 3, Fig. 10), both run by :mod:`.runner`."""

from . import metrics
from .metrics import dense_error, landmark_errors, load_ground_truth, mhd, region_errors, summarize_regions

__all__ = ["metrics", "dense_error", "landmark_errors", "load_ground_truth", "mhd", "region_errors",
           "summarize_regions"]
