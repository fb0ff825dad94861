"""MMF's post-processor (Eq. 6): one anomaly score per superpixel, focused on the road.

With Omega_j the pixels of superpixel j of an (H, W) image (MMF.md A2.8, decisions D1, D2, D5):

- n_j = |Omega_j| / (H W), alpha_j = mean anomaly a over Omega_j, p_j = mean road probability
  over Omega_j, c_j = centroid (y, x), r_ij = |c_i - c_j|;
- omega = median of r_ij over the pairs i < j of non-empty superpixels (NumPy's median: the
  mean of the two middle values for an even count; found by bisection, not a sort);
- S_i = alpha_i sum_{j != i} p_j n_j exp(-r_ij^2 / (2 omega^2))  (j = i too with ``include_self``);
- S_i is min-max normalised over the non-empty superpixels (all 0 when they are equal), and
  each pixel takes the score of its superpixel.

Label ids with no pixel are ignored; ``num_segments`` K is static (``superpixels.num_superpixels``).
"""
from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from jaxanom._validate import check_finite, check_integer, check_rank, is_concrete


def _segment_means(values: jax.Array, labels: jax.Array, counts: jax.Array, k: int) -> jax.Array:
    """(K, ...) mean of ``values`` (N, ...) per label (0 for an empty label)."""
    sums = jax.ops.segment_sum(values, labels, k)
    return sums / jnp.maximum(counts, 1.0).reshape((k,) + (1,) * (values.ndim - 1))


def _order_statistics(values: jax.Array, keep: jax.Array, ranks: jax.Array) -> jax.Array:
    """The ``ranks``-th smallest (0-based) of the kept non-negative float32 ``values``.

    Bisection over the float bit patterns (whose integer order is the order of non-negative
    floats): 32 counting passes, exact, and far faster on XLA:CPU than a float sort.
    """
    bits = jnp.where(keep, jax.lax.bitcast_convert_type(values, jnp.int32), jnp.iinfo(jnp.int32).max)

    def halve(_, bounds):
        low, high = bounds
        middle = low + (high - low) // 2
        enough = jnp.sum(bits[None, :] <= middle[:, None], axis=1) > ranks
        return jnp.where(enough, low, middle + 1), jnp.where(enough, middle, high)

    start = (jnp.zeros_like(ranks), jnp.full_like(ranks, 0x7F800000))  # [0.0, inf]
    low, _ = jax.lax.fori_loop(0, 32, halve, start)
    return jax.lax.bitcast_convert_type(low, jnp.float32)


def _median_distance(centres: jax.Array, valid: jax.Array) -> jax.Array:
    """omega: median of |c_i - c_j| over pairs i < j of valid superpixels (NaN without pairs)."""
    i, j = np.triu_indices(centres.shape[0], 1)
    distance = jnp.sqrt(jnp.sum((centres[i] - centres[j]) ** 2, axis=-1))
    keep = valid[i] & valid[j]
    count = jnp.sum(keep, dtype=jnp.int32)
    middle = _order_statistics(distance, keep, jnp.stack([(count - 1) // 2, count // 2]))
    return jnp.where(count > 0, (middle[0] + middle[1]) / 2, jnp.nan)


def _superpixel_scores(anomaly, road, labels, num_segments: int, include_self: bool = False):
    k = num_segments
    height, width = labels.shape
    flat = labels.ravel()
    counts = jax.ops.segment_sum(jnp.ones(flat.shape, jnp.float32), flat, k)
    valid = counts > 0
    ys, xs = jnp.meshgrid(jnp.arange(height, dtype=jnp.float32), jnp.arange(width, dtype=jnp.float32), indexing="ij")
    alpha = _segment_means(anomaly.ravel().astype(jnp.float32), flat, counts, k)
    p = _segment_means(road.ravel().astype(jnp.float32), flat, counts, k)
    centres = _segment_means(jnp.stack([ys.ravel(), xs.ravel()], -1), flat, counts, k)
    n = counts / (height * width)
    omega = _median_distance(centres, valid)
    r2 = jnp.sum((centres[:, None] - centres[None]) ** 2, axis=-1)
    weight = jnp.where(r2 == 0, 1.0, jnp.exp(-r2 / (2.0 * omega**2)))  # r = 0: weight 1 even if omega = 0
    pair = valid[None, :] & (True if include_self else ~jnp.eye(k, dtype=bool))
    score = alpha * jnp.sum(jnp.where(pair, p * n * weight, 0.0), axis=1)
    low = jnp.min(jnp.where(valid, score, jnp.inf))
    high = jnp.max(jnp.where(valid, score, -jnp.inf))
    normalised = jnp.where(valid & (high > low), (score - low) / jnp.where(high > low, high - low, 1.0), 0.0)
    return normalised, valid


def _superpixel_score(anomaly, road, labels, num_segments: int, include_self: bool = False):
    scores, _ = _superpixel_scores(anomaly, road, labels, num_segments, include_self)
    return scores[labels]


_STATIC = ("num_segments", "include_self")
_superpixel_scores_jit = jax.jit(_superpixel_scores, static_argnames=_STATIC)
_superpixel_score_jit = jax.jit(_superpixel_score, static_argnames=_STATIC)


@functools.partial(jax.jit, static_argnames=_STATIC)
def _superpixel_score_batch(anomaly, road, labels, num_segments: int, include_self: bool = False):
    one = functools.partial(_superpixel_score, num_segments=num_segments, include_self=include_self)
    return jax.vmap(one)(anomaly, road, labels)


def _check(anomaly, road_probability, labels, num_segments, batched: bool):
    rank, layout = (3, "(B, H, W)") if batched else (2, "(H, W)")
    check_rank("anomaly", anomaly, rank, layout)
    for name, x in (("road_probability", road_probability), ("labels", labels)):
        if np.shape(x) != np.shape(anomaly):
            raise ValueError(f"{name} must have the shape of anomaly {np.shape(anomaly)}, got {np.shape(x)}")
    check_integer("labels", labels)
    if not isinstance(num_segments, (int, np.integer)) or num_segments < 1:
        raise ValueError(f"num_segments must be an integer >= 1, got {num_segments!r}")
    check_finite("anomaly", anomaly)
    check_finite("road_probability", road_probability)
    if is_concrete(labels) and np.size(labels):
        low, high = int(np.min(labels)), int(np.max(labels))
        if low < 0 or high >= num_segments:
            raise ValueError(f"labels must lie in [0, num_segments) = [0, {num_segments}), got values in [{low}, {high}]")
    return jnp.asarray(anomaly), jnp.asarray(road_probability), jnp.asarray(labels, jnp.int32), int(num_segments)


def superpixel_scores(anomaly, road_probability, labels, num_segments: int, *, include_self: bool = False):
    """Eq. 6 per superpixel: ``(scores (K,) float32 in [0, 1], valid (K,) bool)``.

    anomaly a, road_probability (H, W) float; labels (H, W) int in [0, K) (from ``slic``).
    ``valid`` marks the ids that have pixels; the others score 0.
    """
    args = _check(anomaly, road_probability, labels, num_segments, batched=False)
    return _superpixel_scores_jit(*args[:3], num_segments=args[3], include_self=include_self)


def superpixel_score(anomaly, road_probability, labels, num_segments: int, *, include_self: bool = False):
    """Eq. 6 as a map: each pixel gets its superpixel's normalised score, ``(H, W)`` float32 in [0, 1].

    Inputs as ``superpixel_scores``. MMF detects anomalies where this exceeds 0.5 (§IV-A).
    """
    args = _check(anomaly, road_probability, labels, num_segments, batched=False)
    return _superpixel_score_jit(*args[:3], num_segments=args[3], include_self=include_self)


def superpixel_score_batch(anomaly, road_probability, labels, num_segments: int, *, include_self: bool = False):
    """``superpixel_score`` over a batch: ``(B, H, W)`` inputs -> ``(B, H, W)`` float32."""
    args = _check(anomaly, road_probability, labels, num_segments, batched=True)
    return _superpixel_score_batch(*args[:3], num_segments=args[3], include_self=include_self)
