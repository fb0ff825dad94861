"""Exact summaries of the ROC and precision-recall curves from score-sorted counts (docs/papers/anomaly-metrics.md).

Input: entries sorted by ``keys`` ascending (= score descending), each carrying a number of
positive and negative pixels (one pixel per entry, or run-length / histogram counts). Entries
with equal keys are one threshold (ties as scikit-learn); entries with no pixel are skipped.
Counts are exact integers; every rate and sum is in the float dtype of ``tpr``: float64 for the
exact metrics (call inside ``jax.enable_x64(True)``), float32 for ``binned``'s metrics inside a
caller's jit without 64-bit mode.

With thresholds k = 1..K from high to low, TP_k / FP_k the pixels at or above threshold k,
R_k = TP_k / P, Prec_k = TP_k / (TP_k + FP_k), TPR_k = R_k, FPR_k = FP_k / N and point 0 the
origin (TP_0 = FP_0 = 0):

- AP "step"  = sum_k (R_k - R_{k-1}) Prec_k                      (scikit-learn, Fishyscapes)
- AP "trapz" = sum_{k>=2} (R_k - R_{k-1}) (Prec_k + Prec_{k-1}) / 2   (np.trapz over the
  curve's points, no artificial (0, 1) start: SMIYC before Aug 2023)
- AP "envelope" = sum_k (R_k - R_{k-1}) max_{j>=k} Prec_j   (VOC all-point interpolation,
  MMF Eq. 7 with r_0 = 0: precision replaced by its upper envelope from the right)
- AUROC      = sum_k (FPR_k - FPR_{k-1}) (TPR_k + TPR_{k-1}) / 2
- FPR at TPR t, four conventions (docs/papers/anomaly-metrics.md#fpr-at-95-tpr), see ``curve_summary``.
"""
from __future__ import annotations

import jax
import jax.numpy as jnp
from jax import lax


def entry_index(size: int) -> jnp.ndarray:
    """0..size-1 as int32 (half the memory traffic of int64) unless size needs int64."""
    return jnp.arange(size, dtype=jnp.int32 if size < 2**31 else jnp.int64)


def curve_points(keys, pos, neg):
    """Cumulative counts at every entry and where a threshold ends.

    keys (M,) uint sorted ascending; pos, neg (M,) int. An entry with no pixel (void, empty
    bin) must not share its key with an entry that has one. Returns tp, fp (M,) cumulative
    counts; end (M,) bool, the last entry of each threshold; tp_prev, fp_prev (M,), the counts
    at the previous threshold (0 before the first).
    """
    index = entry_index(keys.shape[0])
    tp, fp = jnp.cumsum(pos), jnp.cumsum(neg)
    next_keys = jnp.concatenate([keys[1:], keys[-1:]])
    end = ((keys != next_keys) | (index == keys.shape[0] - 1)) & (pos + neg > 0)
    prev = jnp.concatenate([jnp.full((1,), -1, index.dtype), lax.cummax(jnp.where(end, index, -1))[:-1]])
    safe = jnp.maximum(prev, 0)
    tp_prev = jnp.where(prev >= 0, tp[safe], 0)
    fp_prev = jnp.where(prev >= 0, fp[safe], 0)
    return tp, fp, end, tp_prev, fp_prev


@jax.jit
def curve_summary(keys, pos, neg, tpr):
    """AP, AUROC, FPR at TPR ``tpr`` (every convention) and best F1, as float64 / int scalars.

    keys, pos, neg as in ``curve_points``; tpr a float scalar in (0, 1], float64 for exact
    rates (its dtype is the one every rate and sum is computed in). FPR at TPR t:

    - "first":   FPR of the first point with TPR >= t (Fishyscapes, SMIYC);
    - "interp":  linear between the last point with TPR < t (the origin at worst) and the first
      with TPR >= t; a point with TPR == t exactly is taken as is (SML, Mask2Anomaly);
    - "nearest": the point whose ``|TPR - t|`` is least, ties to the largest FPR, candidates the
      origin and the points up to the first with TPR = 1 (PEBAL's fpr_and_fdr_at_recall);
    - "strict":  FPR of the first point with TPR > t (RbA); NaN when there is none (t = 1).

    ``first_key`` / ``best_f1_key`` are the keys of the "first" point and of the point of
    highest pixel F1 (the highest such threshold on ties).
    """
    tp, fp, end, tp_prev, fp_prev = curve_points(keys, pos, neg)
    size = keys.shape[0]
    index = entry_index(size)
    f64 = tpr.dtype
    p, n = tp[-1].astype(f64), fp[-1].astype(f64)
    tpf, fpf, tpp, fpp = (x.astype(f64) for x in (tp, fp, tp_prev, fp_prev))
    # differences of the integer counts (exact; float64 gives the same, float32 would cancel)
    d_tp, d_fp = (tp - tp_prev).astype(f64), (fp - fp_prev).astype(f64)
    precision = tpf / jnp.maximum(tpf + fpf, 1.0)
    precision_prev = tpp / jnp.maximum(tpp + fpp, 1.0)
    d_recall = d_tp / p
    tpr_k = tpf / p
    distance = jnp.abs(tpr_k - tpr)
    envelope = lax.cummax(jnp.where(end, precision, -jnp.inf), reverse=True)
    per_entry = (  # one term per point; all reduced in a single pass (see _combine)
        jnp.where(end, d_recall * precision, 0.0),
        jnp.where(end & (tpp + fpp > 0), d_recall * (precision + precision_prev) / 2, 0.0),
        jnp.where(end, d_fp * (tpf + tpp), 0.0),
        end.astype(index.dtype),
        jnp.where(end & (tpr_k >= tpr), index, size - 1),
        jnp.where(end & (tpr_k > tpr), index, size),
        jnp.where(end & (tpp < p), distance, jnp.inf),
        jnp.where(end & (tpp < p), index, -1),
        jnp.where(end, 2.0 * tpf / (tpf + fpf + p), -1.0),
        index,
        jnp.where(end, d_recall * envelope, 0.0),
    )
    start = (0.0, 0.0, 0.0, 0, size - 1, size, jnp.inf, -1, -jnp.inf, size, 0.0)
    start = tuple(jnp.asarray(v, x.dtype) for v, x in zip(start, per_entry))
    (ap_step, ap_trapz, auroc, num_thresholds, first, strict, nearest_distance, nearest, best_f1,
     best, ap_envelope) = lax.reduce(per_entry, start, _combine, (0,))

    fpr_at = lambda i: fp[i].astype(f64) / n  # noqa: E731
    fpr_strict = jnp.where(strict < size, fpr_at(jnp.minimum(strict, size - 1)), jnp.nan)
    t1, f1, t0, f0 = tpf[first] / p, fpr_at(first), tpp[first] / p, fpp[first] / n
    fpr_interp = jnp.where(t1 == tpr, f1, f0 + (tpr - t0) * (f1 - f0) / (t1 - t0))
    fpr_nearest = jnp.where(tpr < nearest_distance, 0.0, fpr_at(jnp.maximum(nearest, 0)))
    return {
        "ap_step": ap_step, "ap_trapz": ap_trapz, "ap_envelope": ap_envelope, "auroc": auroc / (2.0 * p * n),
        "fpr_first": f1, "fpr_interp": fpr_interp, "fpr_nearest": fpr_nearest, "fpr_strict": fpr_strict,
        "first_key": keys[first], "best_f1": best_f1, "best_f1_key": keys[best],
        "num_positives": tp[-1], "num_negatives": fp[-1], "num_thresholds": num_thresholds,
    }


def _combine(a, b):
    """Reducer of ``curve_summary``'s per-point terms: three sums, a count, the first index
    with TPR >= t and > t, the nearest TPR (ties to the later point: larger FPR), the best
    F1 (ties to the earlier point: higher threshold) and the envelope AP's sum."""
    sums = tuple(x + y for x, y in zip(a[:4], b[:4]))
    take_b_nearest = (b[6] < a[6]) | ((b[6] == a[6]) & (b[7] > a[7]))
    take_b_best = (b[8] > a[8]) | ((b[8] == a[8]) & (b[9] < a[9]))
    return (*sums, jnp.minimum(a[4], b[4]), jnp.minimum(a[5], b[5]),
            jnp.where(take_b_nearest, b[6], a[6]), jnp.where(take_b_nearest, b[7], a[7]),
            jnp.where(take_b_best, b[8], a[8]), jnp.where(take_b_best, b[9], a[9]), a[10] + b[10])
