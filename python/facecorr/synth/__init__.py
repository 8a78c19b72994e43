"""A BU-3DFE-like synthetic database of simulated face scans with exact ground truth.

See :mod:`facecorr.synth.generate` (layout, JSON contract, seeds), :mod:`.scanner` (the scan
simulation), :mod:`.expressions` (FACS recipes) and :mod:`.model` (identities).
"""

from .expressions import EXPRESSION_CODES, LEVEL_SCALE, RECIPES, expression_weights
from .generate import (PRESETS, SynthError, generate, generate_scan, load_index, make_scan, model_vertices, scan_list,
                       subject_identity, subject_name, subject_split)
from .model import IDENTITY_SIGMA, load_ict
from .scanner import Scan, ScannerConfig, scan_head

__all__ = [
    "EXPRESSION_CODES", "LEVEL_SCALE", "RECIPES", "expression_weights", "PRESETS", "SynthError", "generate", "generate_scan",
    "load_index", "make_scan", "model_vertices", "scan_list", "subject_identity", "subject_name",
    "subject_split", "IDENTITY_SIGMA", "load_ict", "Scan", "ScannerConfig", "scan_head",
]
