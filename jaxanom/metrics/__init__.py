"""Exact benchmark metrics: pixel AP / AUROC / FPR@TPR, SMIYC components, confusion / mIoU."""
from jaxanom.metrics.anomaly import anomaly_metrics, pr_curve, roc_curve, threshold_at_tpr

__all__ = ["anomaly_metrics", "pr_curve", "roc_curve", "threshold_at_tpr"]
