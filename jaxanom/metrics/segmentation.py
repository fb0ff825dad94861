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
    prediction, label = _checked(prediction, label, num_classes, ignore)
    return confusion_counts(prediction, label, int(num_classes), int(ignore))


def frame_confusion_matrices(prediction, label, num_classes: int, ignore: int = 255) -> jax.Array:
    """(B, num_classes, num_classes) int32: ``confusion_matrix`` of each frame of a batch (B, ...)."""
    prediction, label = _checked(prediction, label, num_classes, ignore)
    if prediction.ndim < 1:
        raise ValueError(f"prediction: expected a batch (B, ...), got shape {prediction.shape}")
    return _frame_counts(prediction, label, int(num_classes), int(ignore))


def _checked(prediction, label, num_classes: int, ignore: int) -> tuple[jax.Array, jax.Array]:
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
    return prediction, label


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


@partial(jax.jit, static_argnums=(2, 3))
def _frame_counts(prediction, label, num_classes: int, ignore: int) -> jax.Array:
    return jax.vmap(lambda p, l: confusion_counts(p, l, num_classes, ignore))(prediction, label)


def confusion_scores(matrix, num_classes: int | None = None) -> dict:
    """Every score of confusion matrices (..., K, K) (rows: label, columns: prediction), float64.

    ``num_classes`` C (default K): the classes scored are the first C; outputs C..K-1 (a void or
    "unknown" output) are always wrong predictions. Returns per class (..., C): ``iou`` TP / (TP +
    FP + FN), ``recall`` TP / (TP + FN), ``precision`` TP / (TP + FP), ``fpr`` FP / (FP + TN), NaN
    where the denominator is 0; their means over the classes where defined (...): ``miou``,
    ``class_accuracy`` (mean recall), ``mean_precision``, ``mean_fpr``, NaN where none is; and
    ``pixel_accuracy`` (...): correct pixels / counted pixels. Leading axes score many matrices
    at once (e.g. bootstrap replicates); a single (K, K) matrix gives floats.
    """
    matrix = np.asarray(matrix, np.float64)
    if matrix.ndim < 2 or matrix.shape[-1] != matrix.shape[-2]:
        raise ValueError(f"matrix: expected square (..., K, K) confusion matrices (rows: label, columns: "
                         f"prediction), got shape {matrix.shape}")
    size = matrix.shape[-1]
    num_classes = size if num_classes is None else int(num_classes)
    if not 1 <= num_classes <= size:
        raise ValueError(f"num_classes: expected 1 to {size} (the matrix's size), got {num_classes}")
    tp = np.diagonal(matrix, axis1=-2, axis2=-1)
    actual, predicted, total = matrix.sum(-1), matrix.sum(-2), matrix.sum((-2, -1))
    classes = slice(0, num_classes)
    per_class = {"iou": _ratio(tp, actual + predicted - tp), "recall": _ratio(tp, actual),
                 "precision": _ratio(tp, predicted), "fpr": _ratio(predicted - tp, total[..., None] - actual)}
    per_class = {name: value[..., classes] for name, value in per_class.items()}
    means = {"miou": "iou", "class_accuracy": "recall", "mean_precision": "precision", "mean_fpr": "fpr"}
    scores = {"pixel_accuracy": _ratio(tp.sum(-1), total), **per_class,
              **{name: _mean_present(per_class[of]) for name, of in means.items()}}
    return {name: float(value) if np.ndim(value) == 0 else value for name, value in scores.items()}


def _ratio(numerator, denominator):
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(denominator > 0, numerator / np.where(denominator > 0, denominator, 1), np.nan)


def _mean_present(values: np.ndarray) -> np.ndarray:
    """(..., C) -> (...): the mean of each row's non-NaN values (NaN if none), row by row so that
    each mean sums exactly the values a one-matrix mean sums, in the same order (same rounding)."""
    rows = values.reshape(-1, values.shape[-1])
    means = [row[~np.isnan(row)].mean() if not np.isnan(row).all() else np.nan for row in rows]
    return np.asarray(means, np.float64).reshape(values.shape[:-1])


def _square(matrix) -> np.ndarray:
    matrix = np.asarray(matrix)
    if matrix.ndim != 2 or matrix.shape[0] != matrix.shape[1]:
        raise ValueError(f"matrix must be a square (C, C) confusion matrix (rows: label, columns: prediction), "
                         f"got shape {matrix.shape}")
    return matrix


def per_class_iou(matrix) -> np.ndarray:
    """(C,) TP / (TP + FP + FN) per class; NaN where the class neither occurs nor is predicted."""
    return confusion_scores(_square(matrix))["iou"]


def miou(matrix) -> float:
    """Mean IoU over classes that occur or are predicted."""
    return confusion_scores(_square(matrix))["miou"]


def pixel_accuracy(matrix) -> float:
    """Correct pixels / all counted pixels."""
    return confusion_scores(_square(matrix))["pixel_accuracy"]


def recall(matrix) -> np.ndarray:
    """(C,) TP / (TP + FN) per class (per-class accuracy); NaN for classes that never occur."""
    return confusion_scores(_square(matrix))["recall"]


def class_accuracy(matrix) -> float:
    """Mean per-class recall over classes that occur."""
    return confusion_scores(_square(matrix))["class_accuracy"]


def precision(matrix) -> np.ndarray:
    """(C,) TP / (TP + FP) per class; NaN for classes never predicted."""
    return confusion_scores(_square(matrix))["precision"]


def false_positive_rate(matrix) -> np.ndarray:
    """(C,) FP / (FP + TN) per class: pixels of other classes predicted as this one."""
    return confusion_scores(_square(matrix))["fpr"]
