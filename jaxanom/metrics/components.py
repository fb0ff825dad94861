"""SMIYC component-level metrics: sIoU, PPV and F1 over connected components (docs/papers/anomaly-metrics.md#component-metrics).

Follows the SegmentMeIfYouCan definitions (Chan et al., 2021) and their benchmark code:

- anomaly mask = score >= threshold (default: the pixel threshold of best F1 over all images,
  the point of the exact PR curve: ``metrics.pooled.component_metrics``), minus void pixels;
  8-connected components (OpenCV);
- predicted components under ``min_predicted`` pixels are dropped and ground-truth components
  (label 1) under ``min_ground_truth`` pixels become void: 500 / 100 ("anomaly" track),
  50 / 10 ("obstacle" track); then only non-void pixels count;
- sIoU(k) of ground-truth component k, with K(k) the predicted components meeting k:
  ``|k ∩ K(k)| / |(k ∪ K(k)) \\ A(k)|``, A(k) the pixels of other ground-truth components, i.e.
  ``|k ∩ K(k)| / (|k| + pixels of K(k) on no ground-truth component)``;
- PPV(p) of predicted component p: ``|p ∩ ground truth| / |p|``;
- at t in linspace(0.25, 0.75, 11), pooled over images: TP = #{sIoU >= t}, FN = #{sIoU < t},
  FP = #{PPV < t}, F1 = 2 TP / (2 TP + FN + FP); ``f1_mean`` is their mean.

Checked against the benchmark's code (github SegmentMeIfYouCan/road-anomaly-benchmark,
``road_anomaly_benchmark/metrics/instance_segmentation.py``: ``default_instancer``,
``segment_metrics``, ``MetricSegment`` configs ``SegEval-AnomalyTrack`` 500 / 100 and
``SegEval-ObstacleTrack`` 50 / 10): the same rules, including that a predicted component's size
is counted before small ground-truth components become void, that ``FP`` counts predicted
components by PPV (``prec_pred``; early versions used their sIoU), and that mean sIoU / PPV and
F1 pool the components of all frames. Two deliberate differences (docs/decisions/predict.md):
the benchmark predicts score > threshold with a threshold taken from a binned PR curve; here the
threshold is an exact score and pixels at it are predicted (the mask whose pixel F1 is the best).
And its size rule also loops over the background "component" 0, which makes every non-anomaly
pixel void in an image with fewer than 100 / 10 of them; here only label-1 components are tested.
"""
from __future__ import annotations

import cv2
import numpy as np

TRACKS = {"anomaly": (500, 100), "obstacle": (50, 10)}  # (min_predicted, min_ground_truth) pixels
SIOU_THRESHOLDS = np.linspace(0.25, 0.75, 11)


def frame_components(scores, labels, threshold: float, *, track: str = "anomaly") -> tuple[np.ndarray, np.ndarray]:
    """One image: ``(sIoU per ground-truth component, PPV per predicted component)``, float64,
    of the mask ``scores >= threshold`` under the track's size rules (module docstring).

    scores: float (H, W); labels: (H, W) in {0, 1, 255}; threshold: a finite score (use the
    dataset's, e.g. the pooled best-F1 pixel threshold of ``metrics.pooled.component_metrics``).
    """
    check_track(track)
    scores, labels = np.asarray(scores), np.asarray(labels)
    if scores.ndim != 2 or labels.shape != scores.shape:
        raise ValueError(f"labels: expected (H, W) maps of one shape, got scores {scores.shape}, labels {labels.shape}")
    if not np.isin(labels, (0, 1, 255)).all():
        raise ValueError(f"labels: expected values in {{0, 1, 255}}, got {np.setdiff1d(labels, (0, 1, 255))[:5].tolist()}")
    if not np.isfinite(threshold):
        raise ValueError(f"threshold: expected a finite score, got {threshold}")
    if nan := int(np.isnan(scores[labels != 255]).sum()):
        raise ValueError(f"scores: {nan} NaN values on non-void pixels")
    return image_components(scores >= threshold, labels, *TRACKS[track])


def component_summary(siou, ppv) -> dict:
    """The benchmark's numbers from the sIoU of ground-truth components and the PPV of predicted
    ones (of one image or pooled over many): at t in ``SIOU_THRESHOLDS`` TP = #{sIoU >= t},
    FN = #{sIoU < t}, FP = #{PPV < t}, F1 = 2 TP / (2 TP + FN + FP) (NaN where that is 0/0);
    ``f1_mean`` their mean, ``mean_siou`` / ``mean_ppv`` the means over components (NaN if none)."""
    siou, ppv = np.asarray(siou, np.float64), np.asarray(ppv, np.float64)
    tp = np.array([np.sum(siou >= t) for t in SIOU_THRESHOLDS])
    fn = np.array([np.sum(siou < t) for t in SIOU_THRESHOLDS])
    fp = np.array([np.sum(ppv < t) for t in SIOU_THRESHOLDS])
    denominator = 2 * tp + fn + fp
    f1 = np.where(denominator > 0, 2 * tp / np.maximum(denominator, 1), np.nan)
    mean = lambda x: float(x.mean()) if x.size and not np.isnan(x).all() else float("nan")  # noqa: E731
    return {"siou": siou, "ppv": ppv, "mean_siou": mean(siou), "mean_ppv": mean(ppv),
            "siou_thresholds": SIOU_THRESHOLDS, "tp": tp, "fn": fn, "fp": fp, "f1": f1, "f1_mean": mean(f1),
            "num_truth": int(siou.size), "num_predicted": int(ppv.size)}


def check_track(track: str) -> None:
    """ValueError naming ``track`` unless it is a key of ``TRACKS``."""
    if track not in TRACKS:
        raise ValueError(f"track: expected one of {tuple(TRACKS)}, got {track!r}")


def _components(mask: np.ndarray, min_size: int) -> tuple[np.ndarray, np.ndarray]:
    """8-connected components of a bool (H, W) mask: (ids (H, W), 0 = none, numbered 1.. among
    components of >= min_size pixels; small (H, W) bool, the pixels of smaller components)."""
    _, ids, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    large = stats[:, cv2.CC_STAT_AREA] >= min_size
    large[0] = False
    renumber = np.where(large, np.cumsum(large), 0)
    small = ~large
    small[0] = False
    return renumber[ids], small[ids]


def image_components(prediction: np.ndarray, labels: np.ndarray, min_predicted: int,
                     min_ground_truth: int) -> tuple[np.ndarray, np.ndarray]:
    """One image: bool (H, W) predicted mask and (H, W) labels -> (sIoU per ground-truth
    component, PPV per predicted component), float64, in OpenCV's component order."""
    void = labels == 255
    predicted, _ = _components(prediction & ~void, min_predicted)
    truth, small_truth = _components(labels == 1, min_ground_truth)
    region = ~void & ~small_truth
    num_truth, num_predicted = truth.max(initial=0), predicted.max(initial=0)
    joint = np.bincount(truth[region].astype(np.int64) * (num_predicted + 1) + predicted[region],
                        minlength=(num_truth + 1) * (num_predicted + 1)).reshape(num_truth + 1, num_predicted + 1)
    truth_size = joint[1:].sum(axis=1)
    covered = joint[1:, 1:].sum(axis=1)
    meets = joint[1:, 1:] > 0
    siou = covered / (truth_size + meets.astype(np.int64) @ joint[0, 1:])
    predicted_size = joint[:, 1:].sum(axis=0)
    in_region = predicted_size > 0
    ppv = joint[1:, 1:].sum(axis=0)[in_region] / predicted_size[in_region]
    return siou.astype(np.float64), ppv.astype(np.float64)
