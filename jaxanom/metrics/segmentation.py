"""Semantic segmentation metrics: a confusion matrix with ignored pixels, and what it gives.

``confusion_matrix`` counts on the device (jit); the rest are float64 NumPy functions of the
(small) matrix, so matrices summed over a dataset (as int64) give the dataset's numbers. A
class that never occurs and is never predicted has NaN IoU / recall / precision and is left
out of the means, as Cityscapes' evaluation does.
"""
from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from jaxanom.metrics.placement import on_one_device


def confusion_matrix(prediction, label, num_classes: int, ignore: int = 255) -> jax.Array:
    """(num_classes, num_classes) int32 counts, rows = true class, columns = predicted class.

    prediction, label: integer arrays of one shape (...): one image or a stacked batch, all
    pixels pooled. Pixels whose label is ``ignore`` are skipped. Raises ValueError on a shape
    mismatch or a class index outside [0, num_classes) (other than ``ignore`` in ``label``).
    int32 counts: split datasets above 2**31 pixels and sum the matrices as int64.
    """
    prediction, label = on_one_device(jnp.asarray(prediction)), on_one_device(jnp.asarray(label))
    if int(num_classes) < 1:
        raise ValueError(f"num_classes: expected a positive integer, got {num_classes}")
    for name, array in (("prediction", prediction), ("label", label)):
        if not jnp.issubdtype(array.dtype, jnp.integer):
            raise ValueError(f"{name}: expected an integer dtype, got {array.dtype}")
    if prediction.shape != label.shape:
        raise ValueError(f"label: expected the shape of prediction {prediction.shape}, got {label.shape}")
    bad_prediction, bad_label = (int(x) for x in _out_of_range(prediction, label, num_classes, ignore))
    if bad_prediction or bad_label:
        name, count = ("prediction", bad_prediction) if bad_prediction else ("label", bad_label)
        raise ValueError(f"{name}: expected class indices in [0, {num_classes}), got {count} pixels outside")
    return confusion_counts(prediction, label, int(num_classes), int(ignore))


@partial(jax.jit, static_argnums=(2, 3))
def _out_of_range(prediction, label, num_classes, ignore):
    kept = label != ignore
    outside = lambda x: (x < 0) | (x >= num_classes)  # noqa: E731
    return jnp.sum(outside(prediction) & kept), jnp.sum(outside(label) & kept)


@partial(jax.jit, static_argnums=(2, 3))
def confusion_counts(prediction, label, num_classes: int, ignore: int = 255) -> jax.Array:
    """``confusion_matrix`` without input checks, for use inside ``jit`` (e.g. an eval step).

    Pixels whose label is ``ignore`` or outside [0, num_classes) are skipped; predictions must
    lie in [0, num_classes).
    """
    label = label.astype(jnp.int32)
    skipped = (label == ignore) | (label < 0) | (label >= num_classes)
    cell = jnp.where(skipped, num_classes * num_classes, label * num_classes + prediction.astype(jnp.int32))
    return jnp.bincount(cell.ravel(), length=num_classes**2 + 1)[:-1].reshape(num_classes, num_classes)


def _parts(matrix):
    matrix = np.asarray(matrix, np.float64)
    if matrix.ndim != 2 or matrix.shape[0] != matrix.shape[1]:
        raise ValueError(f"matrix must be a square (C, C) confusion matrix (rows: label, columns: prediction), "
                         f"got shape {matrix.shape}")
    true_positive = np.diag(matrix)
    return true_positive, matrix.sum(axis=1), matrix.sum(axis=0), matrix.sum()


def _ratio(numerator, denominator):
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(denominator > 0, numerator / np.where(denominator > 0, denominator, 1), np.nan)


def _mean_present(values) -> float:
    present = values[~np.isnan(values)]
    return float(present.mean()) if present.size else float("nan")


def per_class_iou(matrix) -> np.ndarray:
    """(C,) TP / (TP + FP + FN) per class; NaN where the class neither occurs nor is predicted."""
    tp, actual, predicted, _ = _parts(matrix)
    return _ratio(tp, actual + predicted - tp)


def miou(matrix) -> float:
    """Mean IoU over classes that occur or are predicted."""
    return _mean_present(per_class_iou(matrix))


def pixel_accuracy(matrix) -> float:
    """Correct pixels / all counted pixels."""
    tp, _, _, total = _parts(matrix)
    return float(tp.sum() / total) if total > 0 else float("nan")


def recall(matrix) -> np.ndarray:
    """(C,) TP / (TP + FN) per class (per-class accuracy); NaN for classes that never occur."""
    tp, actual, _, _ = _parts(matrix)
    return _ratio(tp, actual)


def class_accuracy(matrix) -> float:
    """Mean per-class recall over classes that occur."""
    return _mean_present(recall(matrix))


def precision(matrix) -> np.ndarray:
    """(C,) TP / (TP + FP) per class; NaN for classes never predicted."""
    tp, _, predicted, _ = _parts(matrix)
    return _ratio(tp, predicted)


def false_positive_rate(matrix) -> np.ndarray:
    """(C,) FP / (FP + TN) per class: pixels of other classes predicted as this one."""
    tp, actual, predicted, total = _parts(matrix)
    return _ratio(predicted - tp, total - actual)
