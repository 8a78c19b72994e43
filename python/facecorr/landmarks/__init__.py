"""Fully automatic landmark prediction (paper §3, floor 4: a stage; never imports ``registration``).

:mod:`.predict` (the driver: :class:`PredictOptions`, :func:`predict_landmarks`, checks and
flags), :mod:`.start` (the default protrusion start), :mod:`.patches` (the default patch
localisation), :mod:`.pose` (trimmed ICP), :mod:`.protrusion`, :mod:`.gaussian`, :mod:`.model`
(the trained model file), :mod:`.train`, and :mod:`.paper` (the paper's start and BP).
"""

from .model import LandmarkModel, load_model
from .predict import LandmarkResult, PredictOptions, predict_landmarks
from .train import train

__all__ = ["LandmarkModel", "LandmarkResult", "PredictOptions", "load_model", "predict_landmarks", "train"]
