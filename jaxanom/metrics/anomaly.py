"""Pixel-level anomaly metrics pooled over all non-void pixels (docs/papers/anomaly-metrics.md#pooling).

``anomaly_metrics`` gives AP, AUROC and FPR at a TPR in the convention of each benchmark, exact
(one curve point per distinct score, ties as scikit-learn) and in float64 whether or not JAX's
64-bit mode is on: pixels are sorted once on the device, counted with exact integers (int32
below 2**31 pixels, int64 above) and summed in float64 inside a local ``jax.enable_x64``.
Labels: 0 normal, 1 anomaly, 255 void (ignored). Higher score = more anomalous.
"""
from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from jaxanom.metrics.curve import curve_points, curve_summary
from jaxanom.metrics.placement import on_one_device
from jaxanom.metrics.ranking import NEGATIVE, POSITIVE, keys_to_scores, sort_pixels
from jaxanom.shapes import padded_size

FPR_CONVENTIONS = ("first", "interp", "nearest", "strict")
AP_CONVENTIONS = ("step", "trapz", "envelope")


def check_scores_labels(scores, labels) -> tuple[jnp.ndarray, jnp.ndarray, dict]:
    """Validate one pair of score / label arrays; returns them flat with their class counts.

    The flat arrays are padded with void pixels to one of a few sizes (at most 1/16 more
    pixels, at least 1024), so that images of many sizes share a few compiled programs.

    Raises ValueError on: non-float scores, non-integer labels, shape mismatch, labels outside
    {0, 1, 255}, NaN scores on non-void pixels. Call inside ``jax.enable_x64(True)``.
    """
    scores, labels = _one_device_or_host(scores), _one_device_or_host(labels)
    if not jnp.issubdtype(scores.dtype, jnp.floating):
        raise ValueError(f"scores: expected a floating dtype, got {scores.dtype}")
    if not jnp.issubdtype(labels.dtype, jnp.integer):
        raise ValueError(f"labels: expected an integer dtype (uint8 0/1/255), got {labels.dtype}")
    if scores.shape != labels.shape:
        raise ValueError(f"labels: expected the shape of scores {scores.shape}, got {labels.shape}")
    if jnp.iinfo(labels.dtype).max < 255:  # int8: 255 would wrap to -1, so -1 would pass as void
        labels = labels.astype(jnp.int16)
    bad_labels, nan_scores, positives, negatives = (int(x) for x in _audit(scores, labels))
    if bad_labels:
        raise ValueError(f"labels: expected values in {{0, 1, 255}}, got {bad_labels} other pixels")
    if nan_scores:
        raise ValueError(f"scores: {nan_scores} NaN values on non-void pixels")
    size = int(scores.size)
    counts = {"num_positives": positives, "num_negatives": negatives, "num_void": size - positives - negatives}
    # float32 is exact for float16 / bfloat16 and gives one compiled version for them all.
    work = jnp.float64 if jax.dtypes.canonicalize_dtype(scores.dtype) == jnp.float64 else jnp.float32
    return (*_flat_padded(scores, labels, padded_size(max(size, 1024), per_doubling=8, min_step=1), work), counts)


def _one_device_or_host(array):
    """A JAX array on one device (``on_one_device``), anything else as a NumPy array: host data
    goes to the compiled checks as it is (``jnp.asarray`` would compile a copy per shape)."""
    return on_one_device(array) if isinstance(array, jax.Array) else np.asarray(array)


@partial(jax.jit, static_argnums=(2, 3))
def _flat_padded(scores, labels, size: int, dtype):
    """Scores as ``dtype`` and labels as uint8 (values already checked), flat, padded with void
    pixels to ``size``."""
    scores, labels = scores.astype(dtype).ravel(), labels.astype(jnp.uint8).ravel()
    padding = size - scores.shape[0]
    return jnp.pad(scores, (0, padding)), jnp.pad(labels, (0, padding), constant_values=255)


@jax.jit
def _audit(scores, labels):
    count = lambda mask: jnp.sum(mask, dtype=jnp.int64)  # noqa: E731
    void = labels == 255
    return (count((labels != 0) & (labels != 1) & ~void), count(jnp.isnan(scores) & ~void),
            count(labels == 1), count(labels == 0))


def require_both_classes(counts: dict) -> None:
    """ValueError when no positive or no negative pixel is left after removing void."""
    for name, cls in (("num_positives", "positive (1)"), ("num_negatives", "negative (0)")):
        if counts[name] == 0:
            raise ValueError(f"labels: no {cls} pixel left after removing void (255); "
                             "AP, AUROC and FPR are undefined")


def check_conventions(fpr_convention: str, ap_convention: str, tpr: float) -> None:
    """ValueError on an unknown convention name or a TPR outside (0, 1]."""
    if fpr_convention not in FPR_CONVENTIONS:
        raise ValueError(f"fpr_convention: expected one of {FPR_CONVENTIONS}, got {fpr_convention!r}")
    if ap_convention not in AP_CONVENTIONS:
        raise ValueError(f"ap_convention: expected one of {AP_CONVENTIONS}, got {ap_convention!r}")
    if not 0.0 < float(tpr) <= 1.0:
        raise ValueError(f"tpr: expected a value in (0, 1], got {tpr}")


def _pixel_weights(codes, size):
    count = jnp.int32 if size < 2**31 else jnp.int64
    return (codes == POSITIVE).astype(count), (codes == NEGATIVE).astype(count)


@jax.jit
def _pixel_summary(scores, labels, tpr):
    keys, codes = sort_pixels(scores, labels)
    return curve_summary(keys, *_pixel_weights(codes, keys.shape[0]), tpr)


@jax.jit
def _pixel_points(scores, labels):
    keys, codes = sort_pixels(scores, labels)
    tp, fp, end, _, _ = curve_points(keys, *_pixel_weights(codes, keys.shape[0]))
    return keys, tp, fp, end


def summary_to_metrics(summary: dict, counts: dict, fpr_convention: str, ap_convention: str,
                       tpr: float, float64_keys: bool, conventions: bool) -> dict:
    """The ``curve_summary`` of the chosen conventions as a dict of Python numbers; with
    ``conventions``, also ``ap_conventions`` / ``fpr_conventions``: every convention's value."""
    to_score = lambda key: float(keys_to_scores(np.asarray([key]), float64_keys)[0])  # noqa: E731
    extra = {}
    if conventions:
        extra = {"ap_conventions": {name: float(summary[f"ap_{name}"]) for name in AP_CONVENTIONS},
                 "fpr_conventions": {name: float(summary[f"fpr_{name}"]) for name in FPR_CONVENTIONS}}
    return {**extra,
        "ap": float(summary[f"ap_{ap_convention}"]),
        "auroc": float(summary["auroc"]),
        "fpr_at_tpr": float(summary[f"fpr_{fpr_convention}"]),
        "threshold_at_tpr": to_score(summary["first_key"]),
        "best_f1": float(summary["best_f1"]),
        "best_f1_threshold": to_score(summary["best_f1_key"]),
        "num_thresholds": int(summary["num_thresholds"]),
        **counts,
        "tpr": float(tpr), "fpr_convention": fpr_convention, "ap_convention": ap_convention,
    }


def anomaly_metrics(scores, labels, *, fpr_convention: str = "first", ap_convention: str = "step",
                    tpr: float = 0.95, conventions: bool = False) -> dict:
    """AP, AUROC and FPR at ``tpr`` over all non-void pixels of ``scores`` / ``labels``.

    scores: float (...), any leading shape (one image or a stacked dataset); labels: integer
    (...) in {0, 1, 255}. Returns a dict: ``ap``, ``auroc``, ``fpr_at_tpr`` (float64),
    ``threshold_at_tpr`` (the score of the first point with TPR >= tpr), ``best_f1`` and
    ``best_f1_threshold`` (pixel F1 maximised over thresholds; predict score >= threshold),
    ``num_positives``, ``num_negatives``, ``num_void``, ``num_thresholds`` and the settings.
    Conventions as in ``jaxanom.metrics.curve``; ``conventions=True`` adds ``ap_conventions``
    and ``fpr_conventions``, dicts of every AP / FPR convention's value (one computation).
    Raises ValueError on bad input and when no positive or no negative pixel is left after
    removing void.
    """
    check_conventions(fpr_convention, ap_convention, tpr)
    with jax.enable_x64(True):
        scores, labels, counts = check_scores_labels(scores, labels)
        require_both_classes(counts)
        summary = _pixel_summary(scores, labels, jnp.float64(tpr))
        return summary_to_metrics(summary, counts, fpr_convention, ap_convention, tpr,
                                  scores.dtype == jnp.float64, conventions)


def _points(scores, labels):
    """Per-threshold (TP, FP, score) from high to low on the host, with the class totals."""
    with jax.enable_x64(True):
        scores, labels, counts = check_scores_labels(scores, labels)
        require_both_classes(counts)
        keys, tp, fp, end = (np.asarray(x) for x in _pixel_points(scores, labels))
        float64 = scores.dtype == jnp.float64
    tp, fp = tp[end].astype(np.float64), fp[end].astype(np.float64)
    return tp, fp, keys_to_scores(keys[end], float64), counts


def roc_curve(scores, labels) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """ROC curve (fpr, tpr, thresholds), float64 (K+1,): the origin (threshold +inf), then one
    point per distinct non-void score from high to low (scikit-learn's ``roc_curve`` with
    ``drop_intermediate=False``). Predict anomaly where score >= threshold."""
    tp, fp, thresholds, counts = _points(scores, labels)
    fpr = np.concatenate([[0.0], fp / counts["num_negatives"]])
    tpr = np.concatenate([[0.0], tp / counts["num_positives"]])
    return fpr, tpr, np.concatenate([[np.inf], thresholds])


def pr_curve(scores, labels) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Precision-recall curve (precision, recall, thresholds), float64 (K,): one point per
    distinct non-void score from high to low; unlike scikit-learn, no (recall 0, precision 1)
    point is appended and the order is by decreasing threshold."""
    tp, fp, thresholds, counts = _points(scores, labels)
    return tp / (tp + fp), tp / counts["num_positives"], thresholds


def threshold_at_tpr(scores, labels, tpr: float = 0.95) -> float:
    """The highest score threshold whose TPR (predicting score >= threshold) is >= ``tpr``."""
    return anomaly_metrics(scores, labels, tpr=tpr)["threshold_at_tpr"]
