"""Evaluation inside a region of interest: pixels outside it become void (255).

MMF evaluates in the road ROI (Lost & Found: free space and obstacles; Obstacle Track: the road),
so off-road false positives do not count. Works on one image or a batch (any shape).
"""
from __future__ import annotations

import numpy as np

from jaxanom._validate import dtype_of

VOID = 255


def restrict_to_roi(labels, roi) -> np.ndarray:
    """labels (...) in {0, 1, 255}, roi (...) bool (or 0/1) -> uint8 labels, 255 where ``roi`` is False."""
    labels, roi = np.asarray(labels), np.asarray(roi)
    if roi.shape != labels.shape:
        raise ValueError(f"roi must have the shape of labels {labels.shape}, got {roi.shape}")
    if not np.issubdtype(dtype_of(labels), np.integer):
        raise ValueError(f"labels must hold integers 0/1/255, got dtype {labels.dtype}")
    if roi.dtype != bool:
        if not (np.issubdtype(roi.dtype, np.integer) and np.isin(roi, (0, 1)).all()):
            raise ValueError(f"roi must be a bool mask (or 0/1 integers), got dtype {roi.dtype} "
                             f"with values {np.unique(roi)[:5].tolist()}")
        roi = roi.astype(bool)
    if not np.isin(labels, (0, 1, VOID)).all():
        raise ValueError(f"labels must hold 0, 1 or 255, got {np.setdiff1d(labels, (0, 1, VOID))[:5].tolist()}")
    return np.where(roi, labels, VOID).astype(np.uint8)
