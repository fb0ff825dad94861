"""What to do with classes whose statistics rest on few pixels (a deviation from SML, see
``docs/decisions/sml.md``).

SML standardises every pixel by the mean and std of the max logit of its predicted class. A
class predicted on a few hundred pixels gets a std that is too small (and a mean that is noisy),
so anomalies predicted as that class look in-distribution. Three policies:

* ``"none"``: the original's per-class estimate, unchanged (degenerate classes follow
  ``missing``: an error, or the pooled statistics).
* ``"min_count"``: classes with fewer than ``min_count`` pixels take the pooled statistics (mean
  and unbiased std of the max logit over all counted pixels of all classes).
* ``"shrink"``: an empirical-Bayes estimate that treats the pooled statistics as a prior worth
  ``strength`` = k pixels. With the class's n pixels, mean m and sum of squared deviations
  M2, and the pooled mean m0 and unbiased variance s0^2::

      mean' = (n m + k m0) / (n + k)
      var'  = (M2 + k s0^2 + (n k / (n + k)) (m - m0)^2) / (max(n - 1, 0) + k)

  i.e. Chan's merge of the class's pixels with k pseudo-pixels drawn from the pooled
  distribution: the within term (M2 with n - 1 degrees of freedom, plus the prior's k s0^2
  with k), and the between term of the two means. n = 0 gives the pooled (m0, s0^2); n >> k
  gives the class's own estimate. The prior's weight is k / (n + k).
"""
from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxanom.errors import InputError

POLICIES = ("none", "min_count", "shrink")
# The default, chosen on real frames (experiments/real_sml.md, docs/decisions/sml.md): ESPNet's statistics
# from 8 Cityscapes frames at 1024x512 (4.2 M pixels), scored on RoadAnomaly21 and RoadObstacle21. Shrinkage
# with a 1e6-pixel prior was never clearly worse than another policy and clearly beat the original ("none").
# The strength is in pixels: statistics fitted on many more pixels may take a proportionally larger one.
DEFAULT_POLICY = "shrink"
DEFAULT_STRENGTH = 1e6
STATUSES = ("fitted", "pooled", "shrunk")


class FinalizedStats(NamedTuple):
    """Per-class result of ``stats_finalize_report``; every field has length C.

    ``mean``, ``std``: float32 ``(C,)`` to standardise with; ``count``: int64 ``(C,)`` predicted
    pixels behind each class; ``status``: per class ``"fitted"`` (its own estimate),
    ``"pooled"`` (the pooled statistics) or ``"shrunk"`` (the shrinkage estimate);
    ``prior_weight``: float64 ``(C,)`` weight of the pooled statistics in the result (0 fitted,
    1 pooled, k / (n + k) shrunk).
    """

    mean: jax.Array
    std: jax.Array
    count: np.ndarray
    status: tuple[str, ...]
    prior_weight: np.ndarray


def check_policy(policy: str, min_count, strength) -> None:
    if policy not in POLICIES:
        raise InputError("policy", f"must be one of {POLICIES}, got {policy!r}")
    if not (np.isscalar(min_count) and np.isfinite(min_count) and min_count >= 0):
        raise InputError("min_count", f"must be a finite number of pixels >= 0, got {min_count!r}")
    if not (np.isscalar(strength) and np.isfinite(strength) and strength > 0):
        raise InputError("strength", f"must be a finite number of pixels > 0, got {strength!r}")


def pooled_moments(count: np.ndarray, mean: np.ndarray, m2: np.ndarray) -> tuple[float, float, float]:
    """``(N, mean, M2)`` of all classes' pixels together (Chan's merge), float64."""
    n = float(count.sum())
    pooled_mean = float((count * mean).sum() / n) if n > 0 else 0.0
    return n, pooled_mean, float((m2 + count * np.square(mean - pooled_mean)).sum())


def finalize(count, mean, m2, *, policy: str, min_count: float, strength: float,
             missing: str) -> FinalizedStats:
    """The policy applied to float64 ``(C,)`` count, mean and M2; see the module docstring."""
    var = np.divide(m2, count - 1, out=np.zeros_like(m2), where=count > 1)
    degenerate = (count < 2) | ~(var > 0)
    n0, mean0, m2_0 = pooled_moments(count, mean, m2)
    pool_ok = n0 > 1 and m2_0 > 0
    var0 = m2_0 / (n0 - 1) if pool_ok else 0.0
    status = np.full(count.shape, "fitted", dtype=object)
    weight = np.zeros_like(count)
    if policy == "shrink":
        k = float(strength)
        weight = k / (count + k)
        with np.errstate(over="ignore", invalid="ignore"):  # a huge k overflows: refused below
            between = count * k / (count + k) * np.square(mean - mean0)
            mean = (count * mean + k * mean0) / (count + k)
            var = (m2 + k * var0 + between) / (np.maximum(count - 1, 0) + k)
        status[:] = "shrunk"
        degenerate = np.zeros_like(degenerate)
    elif policy == "min_count":
        degenerate = degenerate | (count < min_count)
    if degenerate.any():
        classes = np.flatnonzero(degenerate).tolist()
        if policy == "none" and missing == "error":
            raise InputError(
                "stats", f"has classes {classes} with counts {count[degenerate].astype(int).tolist()}: each class "
                "needs >= 2 predicted pixels with some spread; fit on more data, pass {missing} pooled, or {policy} "
                "min_count or shrink", mentions=("missing", "policy"))
        mean = np.where(degenerate, mean0, mean)
        var = np.where(degenerate, var0, var)
        status[degenerate] = "pooled"
        weight = np.where(degenerate, 1.0, weight)
    if not pool_ok and (policy == "shrink" or degenerate.any()):
        raise InputError("stats", f"has only {int(n0)} counted pixel(s) with no spread in all: cannot pool or "
                         "shrink toward the pooled statistics; fit on more data")
    with np.errstate(over="ignore", invalid="ignore"):
        mean32, std32 = np.float32(mean), np.float32(np.sqrt(var))  # what is saved and scored with
    if not (np.isfinite(mean32).all() and np.isfinite(std32).all() and (std32 > 0).all()):
        bad = np.flatnonzero(~(np.isfinite(mean32) & np.isfinite(std32) & (std32 > 0))).tolist()
        raise InputError("stats", f": the {policy} policy gives classes {bad} a mean / std that is not a finite "
                         f"float32 with std > 0 (mean {mean32[bad][:5].tolist()}, std {std32[bad][:5].tolist()})"
                         + ("; use a smaller {strength}" if policy == "shrink" else ""), mentions=("strength",))
    return FinalizedStats(jnp.asarray(mean32), jnp.asarray(std32),
                          np.rint(count).astype(np.int64), tuple(status.tolist()), np.asarray(weight, np.float64))
