"""The official SegmentMeIfYouCan kit's binned pixel metrics and its component threshold.

jaxanom's own metrics are exact (one curve point per distinct score). The benchmark's code
(github SegmentMeIfYouCan/road-anomaly-benchmark, ``metrics/pixel_classification.py``
configuration ``PixBinaryClass``, ``metrics/pixel_classification_curves.py``,
``metrics/instance_segmentation.py``) bins instead; this module computes what it computes, from
the same inputs (docs/decisions/smiyc-convention.md):

1. scores are float16 (the kit reads the float16 maps of
   ``anomaly_p/<method>/<dataset>/<frame>.hdf5``); only non-void pixels (label < 255) count;
2. per frame, the bin edges are the score range widened by eps = max(0.01 (max - min), 0.01) on
   each side, plus ``np.quantile`` (linear) of the anomaly pixels at min(384, count) evenly
   spaced levels and of the normal pixels likewise, sorted without repeats; each bin [e_i, e_i+1)
   counts its anomaly and normal pixels and stands at its lower edge e_i;
3. the bins of all frames are merged by sorting their lower edges (high to low) and summing
   counts: one curve point per distinct edge, preceded by the origin;
4. AP = sum_k (R_k - R_k-1) Prec_k on that curve (a step sum), AUROC by trapezoids, FPR95 the FPR
   of the first point with TPR >= 0.95, best F1 the first point of highest 2 TP / (2 TP + FP + FN);
5. components: the mask is ``score > t`` with t the best-F1 point's edge; the kit compares the
   float16 map with a float64 threshold under NumPy 1.x, which rounds the threshold to float16
   first. The component rules are ``jaxanom.metrics.components``'.

Facts of the kit reproduced on purpose: the quantile interpolation subtracts the two float16
neighbours in float16 before interpolating in float64; the range's half-width eps is float64
from a float16 difference (which overflows to inf past 65504: the outer edges become +-inf); the
kit keeps the first sorted entry as a curve point even when the next frame shares its edge
(with several frames sharing the top edge, the kit's order among them follows its unstable sort
and its worker order: here the later frame comes first, as the kit does on small inputs). Where
the kit fails (a frame with no non-void pixel: ``np.min`` of nothing), that frame is skipped here.

``to_unit_interval`` maps any score into [0, 1] (logistic) for users who want the benchmark's
documented range.
"""
from __future__ import annotations

import dataclasses
from typing import Iterable

import numpy as np

from jaxanom.metrics.components import TRACKS, check_track, image_components

NUM_BINS = 768  # the kit's PixBinaryClass: 384 quantiles per class and frame
FLOAT16_MAX = float(np.finfo(np.float16).max)


@dataclasses.dataclass(frozen=True)
class FrameBins:
    """One frame's histogram: (K,) float64 lower edges (ascending) and int64 counts of anomaly
    (``positives``) and normal (``negatives``) pixels in [edge_i, edge_i+1)."""

    lower_edges: np.ndarray
    positives: np.ndarray
    negatives: np.ndarray


def frame_bins(scores, labels) -> FrameBins:
    """The kit's percentile histogram of one frame (module docstring, step 2).

    scores: float (H, W) (rounded to float16 here, as the kit stores them); labels: integer
    (H, W) in {0, 1, 255}. ValueError on bad input.
    """
    values, truth = _frame_pixels(scores, labels)
    if values.size == 0:
        empty = np.zeros(0, np.int64)
        return FrameBins(np.zeros(0), empty, empty)
    # sorted as float32 (exact): NumPy 2.x's float16 sort (AVX-512) can leave ~1M values unsorted
    classes = [np.sort(values[truth].astype(np.float32)).astype(np.float16),
               np.sort(values[~truth].astype(np.float32)).astype(np.float16)]
    low, high = values.min(), values.max()
    with np.errstate(over="ignore"):
        width = high - low  # float16, as the kit computes it: inf past 65504
    eps = max(float(width) * 1e-2, 1e-2)
    parts = [[float(low) - eps, float(high) + eps]]
    parts += [_numpy_quantiles(part, min(NUM_BINS // 2, part.size)) for part in classes if part.size]
    edges = np.unique(np.concatenate(parts))
    if np.isnan(edges).any():
        raise ValueError("scores: two consecutive scores of one class differ by more than float16 can hold "
                         f"({FLOAT16_MAX:g}); the kit's quantiles are NaN there")
    # np.histogram's counts in [e_i, e_i+1): every value lies below the top edge max + eps
    positives, negatives = (np.diff(np.searchsorted(part.astype(np.float64), edges)).astype(np.int64)
                            for part in classes)
    return FrameBins(edges[:-1], positives, negatives)


def _frame_pixels(scores, labels) -> tuple[np.ndarray, np.ndarray]:
    """The non-void pixels of a frame: (float16 scores, bool anomaly), validated."""
    scores, labels = np.asarray(scores), np.asarray(labels)
    if not np.issubdtype(scores.dtype, np.floating):
        raise ValueError(f"scores: expected a floating dtype, got {scores.dtype}")
    if not np.issubdtype(labels.dtype, np.integer):
        raise ValueError(f"labels: expected an integer dtype (uint8 0/1/255), got {labels.dtype}")
    if scores.ndim != 2 or labels.shape != scores.shape:
        raise ValueError(f"labels: expected (H, W) maps of one shape, got scores {scores.shape}, "
                         f"labels {labels.shape}")
    if not np.isin(labels, (0, 1, 255)).all():
        bad = np.setdiff1d(labels, (0, 1, 255))[:5].tolist()
        raise ValueError(f"labels: expected values in {{0, 1, 255}}, got {bad}")
    keep = labels != 255
    values = scores[keep]
    if not (np.isfinite(values).all() and np.abs(values).max(initial=0.0) <= FLOAT16_MAX):
        raise ValueError(f"scores: expected finite values within float16's range (|score| <= {FLOAT16_MAX:g}) "
                         "on non-void pixels: the kit stores float16")
    return values.astype(np.float16), labels[keep] == 1


def _numpy_quantiles(ascending: np.ndarray, count: int) -> np.ndarray:
    """``np.quantile(values, np.linspace(0, 1, count))`` as NumPy 1.22-1.26 computes it on float16
    ``values`` (the kit pins 1.23): index (n - 1) q, the neighbours' difference in float16, then
    a + d g below g = 0.5 and b - d (1 - g) from it, in float64. float64 (count,)."""
    n = ascending.size
    index = (n - 1) * np.linspace(0.0, 1.0, count)
    below = np.floor(index)
    gamma = index - below
    below = below.astype(np.intp)
    above = np.minimum(below + 1, n - 1)
    below = np.where(index >= n - 1, n - 1, below)
    a, b = ascending[below], ascending[above]
    with np.errstate(over="ignore", invalid="ignore"):
        step = (b - a).astype(np.float64)  # float16 difference: inf past 65504, as in the kit
        a, b = a.astype(np.float64), b.astype(np.float64)
        return np.where(gamma >= 0.5, b - step * (1 - gamma), a + step * gamma)


def binned_metrics(frames: Iterable[FrameBins]) -> dict:
    """AP, AUROC, FPR at TPR 0.95 and the best-F1 threshold of the merged bins (steps 3-4).

    Returns a dict of Python numbers: ``ap``, ``auroc``, ``fpr_at_tpr``, ``threshold_at_tpr``
    (the edge of that point), ``best_f1``, ``best_f1_threshold`` (the kit's component threshold),
    ``num_thresholds`` (curve points after the origin), ``num_positives``, ``num_negatives``.
    ValueError when no anomaly or no normal pixel is left.
    """
    frames = list(frames)
    if not frames:
        raise ValueError("frames: expected at least one frame's bins, got none")
    edges = np.concatenate([f.lower_edges for f in frames])
    order = np.argsort(edges, kind="stable")[::-1]  # high to low; the later frame first on a tie
    thresholds = edges[order]
    tp = np.cumsum(np.concatenate([f.positives for f in frames])[order].astype(np.float64))
    fp = np.cumsum(np.concatenate([f.negatives for f in frames])[order].astype(np.float64))
    positives, negatives = (tp[-1], fp[-1]) if tp.size else (0.0, 0.0)
    for count, cls in ((positives, "anomaly (1)"), (negatives, "normal (0)")):
        if count == 0:
            raise ValueError(f"labels: no {cls} pixel left after removing void (255); AP, AUROC and FPR are "
                             "undefined")
    # one point per edge, where all of its frames are summed; the kit also keeps the first entry
    last = np.flatnonzero(thresholds[:-1] != thresholds[1:])
    points = np.unique(np.concatenate([[0], last, [tp.size - 1]]))
    tp = np.concatenate([[0.0], tp[points]])  # the origin: the first entry always holds a pixel
    fp = np.concatenate([[0.0], fp[points]])
    thresholds = np.concatenate([[np.inf], thresholds[points]])  # the origin's is never reported
    tpr_k, fpr_k = tp / positives, fp / negatives
    predicted = tp + fp
    precision = np.where(predicted > 0, tp / np.maximum(predicted, 1.0), 1.0)
    f1 = 2 * tp / (2 * tp + fp + (positives - tp))
    first = int(np.searchsorted(tpr_k, 0.95))  # TPR reaches 1 at the last point
    best = int(np.argmax(f1))
    return {
        "ap": float(np.sum(np.diff(tpr_k) * precision[1:])),
        "auroc": float((np.diff(fpr_k) * (tpr_k[1:] + tpr_k[:-1]) / 2.0).sum()),  # np.trapz's order
        "fpr_at_tpr": float(fpr_k[first]), "threshold_at_tpr": float(thresholds[first]),
        "best_f1": float(f1[best]), "best_f1_threshold": float(thresholds[best]),
        "num_thresholds": int(points.size), "num_positives": int(positives), "num_negatives": int(negatives),
        "tpr": 0.95, "convention": "smiyc",
    }


def above_threshold(scores, threshold: float) -> np.ndarray:
    """The kit's anomaly mask: bool ``float16(scores) > float16(threshold)`` (step 5)."""
    return np.asarray(scores).astype(np.float16) > np.float16(threshold)


def smiyc_frame_components(scores, labels, threshold: float, *,
                           track: str = "anomaly") -> tuple[np.ndarray, np.ndarray]:
    """One frame's (sIoU per ground-truth component, PPV per predicted component) of the kit's
    mask ``above_threshold(scores, threshold)`` under the track's size rules."""
    check_track(track)
    _frame_pixels(scores, labels)  # validates
    return image_components(above_threshold(scores, threshold), np.asarray(labels), *TRACKS[track])


def to_unit_interval(scores, center: float = 0.0, scale: float = 1.0):
    """The logistic 1 / (1 + exp(-(scores - center) / scale)) of a score map: a strictly increasing
    map into [0, 1] (the range the benchmark documents), jit-safe, same shape and dtype.

    Exact AP, AUROC and FPR depend on the order and ties of the scores only, so they do not change
    while the map keeps distinct scores distinct (in float32 it saturates about 17 ``scale`` from
    ``center``). The kit's numbers do change, because its float16 rounding and interpolated bin
    edges act on the mapped values: float16 keeps 11 significant bits, so mapped scores tie where
    the map is flat (from about 8.3 ``scale`` above ``center`` they all round to 1).
    """
    import jax
    import jax.numpy as jnp

    return jax.nn.sigmoid((jnp.asarray(scores) - center) / scale)
