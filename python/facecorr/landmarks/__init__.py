"""Fully automatic landmark prediction (paper §3): a module per stage.

mvee (decision ellipsoids), classify (FP -> PCA -> M-cluster labels), mds (canonical forms),
bp (loopy belief propagation), alignment (landmark-graph flip), model (the trained model file),
train / predict (the two pipelines), commands (CLI).
"""
