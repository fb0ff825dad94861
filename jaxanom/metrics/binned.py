"""Binned pixel metrics as pure JAX: AP, AUROC and FPR at a TPR inside ``jax.jit`` / ``vmap``.

The scores are counted in ``num_bins`` uniform bins over a score range (two histograms, positive
and negative pixels; void pixels weigh 0), and ``curve_summary`` gives the exact metrics of the
binned scores: pixels of one bin tie. Binning is a non-decreasing map of the scores (scores out
of the range fall in the end bins), so each bin's pixels form one stretch of the exact curve and
the bin edges are exact curve points. ``binned_error_bounds`` bounds ``|binned - exact|`` from the
histograms alone (docs/decisions/jit-metrics.md derives it):

- AUROC: half the fraction of positive-negative pairs that share a bin, sum_b n+_b n-_b / (2 P N);
- AP: sum_b (n+_b / P) (U_b - L_b), the recall a bin spans times the precision range of its box;
- FPR at TPR t: the negatives' share of the bin in which the TPR crosses t.

A bin whose pixels all have one score is a single point of the exact curve too and adds nothing
(``binned_anomaly_metrics`` finds those bins with a per-bin min and max of the scores).

``binned_anomaly_metrics`` adds to each bound the float rounding of its working precision (float32
unless JAX's 64-bit mode is on: 2 (K' + 16) u for AP and AUROC, K' the non-empty bins, u the
unit roundoff), so ``|returned - exact| <= returned bound``, and returns NaN where a metric is
undefined (no positive or no negative pixel, or a NaN score on a non-void pixel).
``AnomalyMetricAccumulator``'s binned mode uses the same histogram and bounds on the host.

``sorted_anomaly_metrics`` is the exact counterpart for static sizes: a sort of the map (every
distinct score a tied bin), the same ``curve_summary`` and the same reporting; its bounds hold
the float32 rounding alone (none in 64-bit mode, where it gives ``anomaly_metrics``' numbers).
"""
from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from jaxanom._validate import check_count, dtype_of, is_concrete
from jaxanom.errors import InputError
from jaxanom.metrics.curve import curve_points, curve_summary
from jaxanom.metrics.ranking import descending_keys

BOUNDED_FPR_CONVENTIONS = ("first", "interp", "strict")  # "nearest" has no bin bound
AP_CONVENTIONS = ("step", "trapz", "envelope")


def score_histogram(scores, labels, low, high, num_bins: int) -> jax.Array:
    """(num_bins, 2) counts of negative / positive pixels per uniform bin of [low, high).

    Bin i holds the scores s with floor((s - low) num_bins / (high - low)) = i, clipped to
    [0, num_bins - 1]; labels 0 / 1 count, any other label (void, 255) weighs 0. The scale is
    computed on halves, so that ranges up to float's largest span do not overflow, in float64 on
    the host when ``low`` and ``high`` are Python numbers. Pure JAX: ``low`` / ``high`` may be
    traced; ``num_bins`` is static. Counts are int32 (int64 in 64-bit mode).
    """
    bins = _bin_index(scores, low, high, num_bins)
    counted = (labels == 0) | (labels == 1)
    index = jnp.where(counted, 2 * bins + (labels == 1).astype(jnp.int32), 2 * num_bins)
    return jnp.bincount(index.ravel(), length=2 * num_bins + 1)[:-1].reshape(num_bins, 2)


def _bin_index(scores, low, high, num_bins: int) -> jax.Array:
    """The uniform bin of each score, int32 in [0, num_bins) (``score_histogram``'s binning)."""
    work = scores.dtype if scores.dtype == jnp.float64 else jnp.float32
    half = lambda x: jnp.asarray(x, work) / 2  # noqa: E731
    if isinstance(low, (int, float, np.number)) and isinstance(high, (int, float, np.number)):
        scale = jnp.asarray(num_bins / (float(high) / 2 - float(low) / 2), work)  # float64 on the host
    else:
        scale = jnp.asarray(num_bins, work) / (half(high) - half(low))
    return jnp.clip(jnp.floor((half(scores) - half(low)) * scale), 0, num_bins - 1).astype(jnp.int32)


def _tied_bins(scores, counted, low, high, num_bins: int) -> jax.Array:
    """(num_bins,) bool: the bins whose counted pixels all have one score (empty bins: False)."""
    bins = jnp.where(counted, _bin_index(scores, low, high, num_bins), num_bins).ravel()
    values = scores.ravel()
    smallest = jax.ops.segment_min(values, bins, num_segments=num_bins + 1)[:-1]
    largest = jax.ops.segment_max(values, bins, num_segments=num_bins + 1)[:-1]
    return smallest == largest


def binned_error_bounds(positives, negatives, tpr, fpr_convention: str = "first", ap_convention: str = "step",
                        margin: float = 0.0, tied=None) -> dict:
    """Bounds on ``|binned - exact|`` from per-bin counts (K,) ordered from the highest bin down.

    Bin edges are exact curve points; inside bin b (n+_b positives, n-_b negatives, counts
    TP_s, FP_s before it and TP_e, FP_e after it) the exact curve stays in the box the bin
    spans, whose precision lies in [L_b, U_b] = [TP_s / (TP_s + FP_e), TP_e / (TP_e + FP_s)]
    ([0, 1] for the first non-empty bin). Hence

    - AP (step or trapz): sum_b (n+_b / P) (U_b - L_b);
    - AP envelope: sum_b (n+_b / P) (M_b - E_b), with E_b the largest bin-end precision at or
      after b (the binned envelope, a lower bound of the exact one there) and M_b the largest
      U_b' at or after b (an upper bound);
    - AUROC: sum_b (n-_b / N) (n+_b / P) / 2 (a staircase against the box's diagonal);
    - FPR ("first", "interp", "strict"): n-_b / N of the bin in which the TPR crosses tpr; with
      ``margin`` > 0, the negatives of every bin from the first whose end TPR reaches
      tpr - margin to the first that reaches tpr + margin (a crossing decided in another
      precision lies among them).

    ``tied`` (K,) bool, optional: bins whose pixels all share one score. The exact curve has a
    single point there, the bin's end, so such a bin adds nothing (its box shrinks to that point;
    its FPR term vanishes when the crossing is decided, ``margin`` apart, in it alone).
    Empty bins add nothing. Pure JAX (jit / vmap); float64 in 64-bit mode, else float32.
    Returns ``ap_error_bound``, ``auroc_error_bound``, ``fpr_error_bound`` (NaN without both classes).
    """
    real = jax.dtypes.canonicalize_dtype(jnp.float64)
    pos, neg = jnp.asarray(positives).astype(real), jnp.asarray(negatives).astype(real)
    tp_end, fp_end = jnp.cumsum(pos), jnp.cumsum(neg)
    tp_start, fp_start = tp_end - pos, fp_end - neg
    p, n = tp_end[-1], fp_end[-1]
    tied = jnp.zeros(pos.shape, bool) if tied is None else jnp.asarray(tied)
    first = tp_start + fp_start == 0  # no pixel above: the box spans precisions [0, 1]
    end_precision = tp_end / jnp.maximum(tp_end + fp_end, 1.0)
    upper = jnp.where(tied, end_precision, jnp.where(first, 1.0, tp_end / jnp.maximum(tp_end + fp_start, 1.0)))
    lower = jnp.where(tied, end_precision, jnp.where(first, 0.0, tp_start / jnp.maximum(tp_start + fp_end, 1.0)))
    if ap_convention == "envelope":
        ends = jax.lax.cummax(end_precision, reverse=True)
        ap_bound = jnp.sum(pos / p * (jax.lax.cummax(upper, reverse=True) - ends))
    else:
        ap_bound = jnp.sum(pos / p * (upper - lower))
    tpr_end = tp_end / p
    crossing = (lambda t: tpr_end > t) if fpr_convention == "strict" else (lambda t: tpr_end >= t)
    early, late = crossing(tpr - margin), crossing(tpr + margin)
    index = jnp.arange(pos.shape[0])
    last = jnp.max(jnp.where(pos + neg > 0, index, 0))  # a crossing past tpr + margin may not exist
    start = jnp.argmax(early)
    stop = jnp.where(late.any(), jnp.argmax(late), last)
    window = (index >= start) & (index <= stop)
    decided = early.any() & ~((start == stop) & tied[start])
    fpr_bound = jnp.where(decided, jnp.sum(jnp.where(window, neg, 0.0)) / n, 0.0)
    auroc_bound = jnp.sum(jnp.where(tied, 0.0, neg / n * pos / p)) / 2
    return {"ap_error_bound": ap_bound, "auroc_error_bound": auroc_bound,
            "fpr_error_bound": fpr_bound}


def _check_arguments(scores, labels, tpr, fpr_convention: str, ap_convention: str) -> None:
    """One-line InputErrors for what is known without the data (dtypes, shapes, static options)."""
    if fpr_convention not in BOUNDED_FPR_CONVENTIONS:
        raise InputError("fpr_convention", f"expected one of {BOUNDED_FPR_CONVENTIONS} (\"nearest\" has no bound), "
                         f"got {fpr_convention!r}")
    if ap_convention not in AP_CONVENTIONS:
        raise InputError("ap_convention", f"expected one of {AP_CONVENTIONS}, got {ap_convention!r}")
    if not jnp.issubdtype(dtype_of(scores), jnp.floating):
        raise InputError("scores", f"expected a floating dtype, got {dtype_of(scores)}")
    if not jnp.issubdtype(dtype_of(labels), jnp.integer):
        raise InputError("labels", f"expected an integer dtype (0 / 1 / void), got {dtype_of(labels)}")
    if np.shape(scores) != np.shape(labels):
        raise InputError("labels", f"expected the shape of scores {np.shape(scores)}, got {np.shape(labels)}")
    if is_concrete(tpr) and not isinstance(tpr, jax.Array) and not 0.0 < float(tpr) <= 1.0:
        raise InputError("tpr", f"expected a value in (0, 1], got {tpr}")


def _reported(summary, bounds, threshold, defined, fpr_convention: str, ap_convention: str) -> dict:
    """The metrics of ``curve_summary`` with their bounds plus the float rounding, NaN where not ``defined``.

    Float rounding (docs/decisions/jit-metrics.md): the metric and its bound are each a sum of K'
    non-zero terms (K' curve points) within 16 roundings of their values, so each errs by at most
    (K' + 16) u; the FPR is a ratio of two rounded counts, its bound a ratio of two sums.
    """
    real = jax.dtypes.canonicalize_dtype(jnp.float64)
    unit = float(np.finfo(real).eps) / 2
    rounding = 2 * unit * (summary["num_thresholds"].astype(real) + 16)
    metrics = {"ap": summary[f"ap_{ap_convention}"], "auroc": summary["auroc"],
               "fpr_at_tpr": summary[f"fpr_{fpr_convention}"], "threshold_at_tpr": threshold,
               "ap_error_bound": bounds["ap_error_bound"] + rounding,
               "auroc_error_bound": bounds["auroc_error_bound"] + rounding,
               "fpr_error_bound": bounds["fpr_error_bound"] * (1 + 4 * unit) + 4 * unit}
    metrics = {k: jnp.where(defined, v.astype(real), jnp.nan) for k, v in metrics.items()}
    return {**metrics, "num_positives": summary["num_positives"], "num_negatives": summary["num_negatives"]}


def binned_anomaly_metrics(scores, labels, *, num_bins: int = 4096, score_range=None, tpr=0.95,
                           fpr_convention: str = "first", ap_convention: str = "step") -> dict:
    """AP, AUROC and FPR at ``tpr`` of the binned scores, with bounds on their distance to the exact ones.

    scores: float (...), labels: integer (...) of the same shape, 0 normal, 1 anomaly, anything
    else void (weight 0); higher score = more anomalous. Pure JAX: runs under ``jax.jit`` and
    ``jax.vmap`` (for example over a stack of score maps), with no host read.
    ``num_bins`` (static): uniform bins over ``score_range`` = (low, high), which may be traced;
    default: the non-void scores' own minimum and maximum. Scores outside the range count in the
    end bins (still bounded, just coarser). ``tpr`` may be traced; ``fpr_convention`` in
    ("first", "interp", "strict") and ``ap_convention`` in ("step", "trapz", "envelope") are
    static, as in ``anomaly_metrics``.

    Returns a dict of scalars: ``ap``, ``auroc``, ``fpr_at_tpr``, ``threshold_at_tpr`` (the lower
    edge of the bin where the TPR reaches ``tpr``), ``ap_error_bound``, ``auroc_error_bound``,
    ``fpr_error_bound`` (``|metric - exact metric| <= bound``, exact = ``anomaly_metrics`` of the
    same pixels), ``num_positives``, ``num_negatives``. Every metric and bound is NaN where the
    exact metric is undefined: no positive or no negative pixel (an all-void map) or a NaN score
    on a non-void pixel. Works in float32 (float64 in 64-bit mode), counts in int32: up to 2**31
    non-void pixels per call.
    """
    _check_arguments(scores, labels, tpr, fpr_convention, ap_convention)
    num_bins = check_count("num_bins", num_bins, 1, 2**30)
    if score_range is not None:
        score_range = tuple(score_range)
    return _binned_metrics(scores, labels, score_range, tpr, num_bins, fpr_convention, ap_convention)


@partial(jax.jit, static_argnums=(4, 5, 6))
def _binned_metrics(scores, labels, score_range, tpr, num_bins, fpr_convention, ap_convention):
    real = jax.dtypes.canonicalize_dtype(jnp.float64)
    counted = (labels == 0) | (labels == 1)
    if score_range is None:
        low = jnp.min(jnp.where(counted, scores, jnp.inf))
        high = jnp.max(jnp.where(counted, scores, -jnp.inf))
    else:
        low, high = (jnp.asarray(x, real) for x in score_range)
    # one bin when every score is equal (or none is counted): any positive width does
    high = jnp.where(jnp.isfinite(high) & jnp.isfinite(low) & (high > low), high, low + 1)
    low = jnp.where(jnp.isfinite(low), low, 0.0)
    high = jnp.where(jnp.isfinite(high), high, 1.0)
    histogram = score_histogram(scores, labels, low, high, num_bins)[::-1]  # highest bin first
    positives, negatives = histogram[:, 1], histogram[:, 0]
    tied = _tied_bins(scores, counted, low, high, num_bins)[::-1]
    tpr = jnp.asarray(tpr, real)
    summary = curve_summary(jnp.arange(num_bins, dtype=jnp.uint32), positives, negatives, tpr)
    bounds = binned_error_bounds(positives, negatives, tpr, fpr_convention, ap_convention,
                                 margin=float(np.finfo(real).eps) * 8, tied=tied)
    width = (high.astype(real) - low.astype(real)) / num_bins
    edge = low.astype(real) + (num_bins - 1 - summary["first_key"].astype(real)) * width
    defined = (summary["num_positives"] > 0) & (summary["num_negatives"] > 0) & ~jnp.any(jnp.isnan(scores) & counted)
    return _reported(summary, bounds, edge, defined, fpr_convention, ap_convention)


def sorted_anomaly_metrics(scores, labels, *, tpr=0.95, fpr_convention: str = "first",
                           ap_convention: str = "step") -> dict:
    """The exact metrics (one curve point per distinct score, ties as scikit-learn) as pure JAX:
    a sort of the static-size map inside ``jax.jit`` / ``vmap``.

    Arguments, conventions and the returned dict as ``binned_anomaly_metrics``, but
    ``threshold_at_tpr`` is the score of the first point with TPR >= ``tpr``. In 64-bit mode the
    numbers are ``anomaly_metrics``' (the same sort keys and ``curve_summary``, in float64); in
    float32 the sums are float32, and the bounds hold that rounding, 2 (K' + 16) u with K' the
    distinct scores, plus, for the FPR, the negatives of the points whose TPR lies within 8 eps of
    ``tpr`` (where a float32 and a float64 crossing may differ). A sort of every map costs more
    than a histogram (docs/decisions/jit-metrics.md).
    """
    _check_arguments(scores, labels, tpr, fpr_convention, ap_convention)
    return _sorted_metrics(scores, labels, tpr, fpr_convention, ap_convention)


@partial(jax.jit, static_argnums=(3, 4))
def _sorted_metrics(scores, labels, tpr, fpr_convention, ap_convention):
    real = jax.dtypes.canonicalize_dtype(jnp.float64)
    scores, labels = scores.ravel(), labels.ravel()
    counted = (labels == 0) | (labels == 1)
    keys = descending_keys(scores)
    keys = jnp.where(counted, keys, ~jnp.zeros_like(keys))  # uncounted pixels last, on a key of their own
    pos, neg = (labels == 1).astype(jnp.int32), (labels == 0).astype(jnp.int32)
    keys, pos, neg, ordered = jax.lax.sort((keys, pos, neg, scores), num_keys=1)
    tpr = jnp.asarray(tpr, real)
    summary = curve_summary(keys, pos, neg, tpr)
    tp, fp, end, tp_prev, fp_prev = curve_points(keys, pos, neg)
    # each distinct score is a tied bin whose counts sit at its last entry: only the FPR's
    # crossing (decided in the working precision) bounds anything
    bounds = binned_error_bounds(jnp.where(end, tp - tp_prev, 0), jnp.where(end, fp - fp_prev, 0), tpr,
                                 fpr_convention, ap_convention, margin=float(np.finfo(real).eps) * 8,
                                 tied=jnp.ones(keys.shape, bool))
    threshold = ordered[jnp.argmax(keys == summary["first_key"])].astype(real)
    defined = (summary["num_positives"] > 0) & (summary["num_negatives"] > 0) & ~jnp.any(jnp.isnan(scores) & counted)
    return _reported(summary, bounds, threshold, defined, fpr_convention, ap_convention)
