"""Fully automatic landmark prediction (paper §3): a module per stage.

mvee (decision ellipsoids), classify (FP -> PCA -> M-cluster labels), mds (canonical forms),
bp (loopy belief propagation), alignment (landmark-graph flip), model (the trained model file),
train / predict (the two pipelines), commands (CLI).
"""

from .model import LandmarkModel, load_model
from .predict import LandmarkResult, predict_landmarks
from .train import train

__all__ = ["LandmarkModel", "LandmarkResult", "load_model", "predict_landmarks", "train"]
