"""Exact benchmark metrics: pixel AP / AUROC / FPR@TPR, SMIYC components, confusion / mIoU; the
official SegmentMeIfYouCan kit's binned convention (``smiyc``); all of them as evaluators fed the
same batches (``evaluator``: init / update / merge / finalize), which also fold the datasets
given as lists of frames (``pooled``); AP / AUROC / FPR as pure JAX for use inside ``jax.jit`` /
``vmap``, binned or by a sort, with error bounds (``binned``)."""
from jaxanom.metrics.accumulator import AnomalyMetricAccumulator
from jaxanom.metrics.anomaly import anomaly_metrics, pr_curve, roc_curve, threshold_at_tpr
from jaxanom.metrics.binned import (binned_anomaly_metrics, binned_error_bounds, score_histogram,
                                    sorted_anomaly_metrics)
from jaxanom.metrics.pooled import component_metrics, smiyc_component_metrics, smiyc_pixel_metrics
from jaxanom.metrics.roi import restrict_to_roi
from jaxanom.metrics.segmentation import (class_accuracy, confusion_matrix, confusion_scores, false_positive_rate,
                                          frame_confusion_matrices, miou, per_class_iou, pixel_accuracy, precision,
                                          recall)
from jaxanom.metrics.smiyc import to_unit_interval

__all__ = [
    "AnomalyMetricAccumulator", "anomaly_metrics", "binned_anomaly_metrics", "binned_error_bounds", "class_accuracy",
    "component_metrics", "confusion_matrix", "confusion_scores", "false_positive_rate", "frame_confusion_matrices", "miou",
    "per_class_iou", "pixel_accuracy", "pr_curve", "precision", "recall", "restrict_to_roi", "roc_curve",
    "score_histogram", "smiyc_component_metrics", "smiyc_pixel_metrics", "sorted_anomaly_metrics", "threshold_at_tpr",
    "to_unit_interval",
]
