"""MMF's post-processor (Eq. 6): one anomaly score per superpixel, focused on the road.

With Omega_j the pixels of superpixel j of an (H, W) image (as read in docs/papers/mmf.md#superpixel-scores):

- n_j = ``|Omega_j| / (H W)``, alpha_j = mean anomaly a over Omega_j, p_j = mean road probability
  over Omega_j, c_j = centroid (y, x), r_ij = ``|c_i - c_j|``;
- omega = median of r_ij over the pairs i < j of non-empty superpixels (NumPy's median: the
  mean of the two middle values for an even count; found by radix selection, not a sort);
- S_i = alpha_i sum_{j != i} p_j n_j exp(-r_ij^2 / (2 omega^2))  (j = i too with ``include_self``);
- S_i is min-max normalised over the non-empty superpixels (all 0 when they are equal), and
  each pixel takes the score of its superpixel.

Label ids with no pixel are ignored; ``num_segments`` K is static (``superpixels.num_superpixels``).
Memory is O(K) plus one block of ``block_rows`` x K pair distances at a time (by default about
4M pairs, 16 MB a float32 array): the K x K pairs are visited block by block (``lax.scan``), three
times (two radix-selection passes for omega, one for the sums), and the result is exact (the
same value as summing the full K x K matrix, up to float32 summation order).
"""
from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from jaxanom._batching import over_images
from jaxanom._validate import check_finite, check_integer, check_rank, values_checked


def _segment_means(values: jax.Array, labels: jax.Array, counts: jax.Array, k: int) -> jax.Array:
    """(K, ...) mean of ``values`` (N, ...) per label (0 for an empty label)."""
    sums = jax.ops.segment_sum(values, labels, k)
    return sums / jnp.maximum(counts, 1.0).reshape((k,) + (1,) * (values.ndim - 1))


_PAIRS_PER_BLOCK = 1 << 22  # entries of one (rows, K) block of pair distances: 16 MB in float32
_UNUSED = np.iinfo(np.int32).max  # above every float32's bits


def _block_rows(k: int, block_rows: int | None) -> int:
    """Rows of superpixels per block: ``block_rows``, else as many as fit ``_PAIRS_PER_BLOCK`` pairs."""
    return max(1, min(k, block_rows or _PAIRS_PER_BLOCK // k))


def _scan_rows(fn, carry, centres: jax.Array, valid: jax.Array, rows: int):
    """Fold ``fn(carry, index (R,), valid (R,), r2 (R, K)) -> (carry, out (R,))`` over blocks of R
    superpixels (the last block padded with invalid rows); returns ``(carry, out (K,))``.

    Only one (R, K) block of squared centroid distances exists at a time, so memory is O(R K),
    and every block computes r2 with the same expression (identical values in every pass).
    """
    k = centres.shape[0]
    blocks = -(-k // rows)
    padded_centres = jnp.pad(centres, ((0, blocks * rows - k), (0, 0)))
    padded_valid = jnp.pad(valid, (0, blocks * rows - k))

    def step(carry, block):
        start = block * rows
        mine = jax.lax.dynamic_slice_in_dim(padded_centres, start, rows)
        r2 = (mine[:, None, 0] - centres[None, :, 0]) ** 2 + (mine[:, None, 1] - centres[None, :, 1]) ** 2
        return fn(carry, start + jnp.arange(rows), jax.lax.dynamic_slice_in_dim(padded_valid, start, rows), r2)

    carry, out = jax.lax.scan(step, carry, jnp.arange(blocks))
    return carry, out.reshape(-1)[:k]


def _median_distance(centres: jax.Array, valid: jax.Array, rows: int) -> jax.Array:
    """omega: median of r_ij = |c_i - c_j| over the pairs i < j of valid superpixels (NaN without pairs).

    Exact radix selection over the int32 bits of r_ij (non-negative floats order as their bits),
    in two blockwise passes: a histogram of the high 16 bits finds the bucket of the lower middle
    value; a histogram of the low 16 bits inside that bucket (and the least value above it)
    finds the lower and the upper middle values. NumPy's median is their mean.
    """
    k = valid.shape[0]
    columns = jnp.arange(k)

    def pair_bits(index, mine, r2):
        keep = (index[:, None] < columns[None, :]) & mine[:, None] & valid[None, :]
        return keep, jax.lax.bitcast_convert_type(jnp.sqrt(r2), jnp.int32)

    def count_high(hist, index, mine, r2):
        keep, bits = pair_bits(index, mine, r2)
        return hist.at[(bits >> 16).ravel()].add(keep.ravel().astype(jnp.int32)), jnp.zeros(index.shape)

    high, _ = _scan_rows(count_high, jnp.zeros(1 << 15, jnp.int32), centres, valid, rows)
    count = jnp.sum(high)
    rank = (count - 1) // 2
    below = jnp.cumsum(high)
    bucket = jnp.sum(below <= rank)  # the first bucket whose running count passes rank
    before = jnp.where(bucket > 0, below[jnp.maximum(bucket - 1, 0)], 0)

    def count_low(carry, index, mine, r2):
        low, above = carry
        keep, bits = pair_bits(index, mine, r2)
        in_bucket = keep & ((bits >> 16) == bucket)
        low = low.at[(bits & 0xFFFF).ravel()].add(in_bucket.ravel().astype(jnp.int32))
        above = jnp.minimum(above, jnp.min(jnp.where(keep & ((bits >> 16) > bucket), bits, _UNUSED)))
        return (low, above), jnp.zeros(index.shape)

    (low, above), _ = _scan_rows(count_low, (jnp.zeros(1 << 16, jnp.int32), jnp.int32(_UNUSED)), centres, valid, rows)
    running = jnp.cumsum(low)
    lower_low = jnp.sum(running <= rank - before)
    lower = (bucket << 16) | lower_low
    # the next order statistic: lower again if it repeats, else the next filled low bin, else the least above
    later = (jnp.arange(1 << 16) > lower_low) & (low > 0)
    next_in_bucket = (bucket << 16) | jnp.argmax(later)
    upper = jnp.where(before + running[lower_low] > count // 2, lower,
                      jnp.where(jnp.any(later), next_in_bucket, above))
    middle = jax.lax.bitcast_convert_type(jnp.stack([lower, upper]), jnp.float32)
    return jnp.where(count > 0, (middle[0] + middle[1]) / 2, jnp.nan)


def _superpixel_scores(anomaly, road, labels, num_segments: int, include_self: bool = False,
                       block_rows: int | None = None):
    k = num_segments
    rows = _block_rows(k, block_rows)
    height, width = labels.shape
    flat = labels.ravel()
    counts = jax.ops.segment_sum(jnp.ones(flat.shape, jnp.float32), flat, k)
    valid = counts > 0
    ys, xs = jnp.meshgrid(jnp.arange(height, dtype=jnp.float32), jnp.arange(width, dtype=jnp.float32), indexing="ij")
    alpha = _segment_means(anomaly.ravel().astype(jnp.float32), flat, counts, k)
    p = _segment_means(road.ravel().astype(jnp.float32), flat, counts, k)
    centres = _segment_means(jnp.stack([ys.ravel(), xs.ravel()], -1), flat, counts, k)
    mass = jnp.where(valid, p * counts / (height * width), 0.0)  # p_j n_j; 0 for empty ids
    omega = _median_distance(centres, valid, rows)
    columns = jnp.arange(k)

    def neighbourhood(carry, index, mine, r2):  # sum_j p_j n_j w_ij for one block of rows i
        weight = jnp.where(r2 == 0, 1.0, jnp.exp(-r2 / (2.0 * omega**2)))  # r = 0: weight 1 even if omega = 0
        pair = True if include_self else index[:, None] != columns[None, :]
        return carry, jnp.sum(jnp.where(pair, mass * weight, 0.0), axis=1)

    _, total = _scan_rows(neighbourhood, None, centres, valid, rows)
    score = alpha * total
    low = jnp.min(jnp.where(valid, score, jnp.inf))
    high = jnp.max(jnp.where(valid, score, -jnp.inf))
    normalised = jnp.where(valid & (high > low), (score - low) / jnp.where(high > low, high - low, 1.0), 0.0)
    return normalised, valid


def _superpixel_score(anomaly, road, labels, num_segments: int, include_self: bool = False,
                      block_rows: int | None = None):
    scores, _ = _superpixel_scores(anomaly, road, labels, num_segments, include_self, block_rows)
    return scores[labels]


_STATIC = ("num_segments", "include_self", "block_rows")
_superpixel_scores_jit = jax.jit(_superpixel_scores, static_argnames=_STATIC)
_superpixel_score_jit = jax.jit(_superpixel_score, static_argnames=_STATIC)


@functools.partial(jax.jit, static_argnames=_STATIC)
def _superpixel_score_batch(anomaly, road, labels, num_segments: int, include_self: bool = False,
                            block_rows: int | None = None):
    one = functools.partial(_superpixel_score, num_segments=num_segments, include_self=include_self,
                            block_rows=block_rows)
    return over_images(one, anomaly, road, labels)


def _check(anomaly, road_probability, labels, num_segments, block_rows, batched: bool):
    rank, layout = (3, "(B, H, W)") if batched else (2, "(H, W)")
    check_rank("anomaly", anomaly, rank, layout)
    for name, x in (("road_probability", road_probability), ("labels", labels)):
        if np.shape(x) != np.shape(anomaly):
            raise ValueError(f"{name} must have the shape of anomaly {np.shape(anomaly)}, got {np.shape(x)}")
    check_integer("labels", labels)
    if not isinstance(num_segments, (int, np.integer)) or num_segments < 1:
        raise ValueError(f"num_segments must be an integer >= 1, got {num_segments!r}")
    if block_rows is not None and (not isinstance(block_rows, (int, np.integer)) or block_rows < 1):
        raise ValueError(f"block_rows must be None or an integer >= 1, got {block_rows!r}")
    check_finite("anomaly", anomaly)
    check_finite("road_probability", road_probability)
    if values_checked(labels) and np.size(labels):
        low, high = int(np.min(labels)), int(np.max(labels))
        if low < 0 or high >= num_segments:
            raise ValueError(f"labels must lie in [0, num_segments) = [0, {num_segments}), got values in [{low}, {high}]")
    return jnp.asarray(anomaly), jnp.asarray(road_probability), jnp.asarray(labels, jnp.int32), int(num_segments)


def superpixel_scores(anomaly, road_probability, labels, num_segments: int, *, include_self: bool = False,
                      block_rows: int | None = None):
    """Eq. 6 per superpixel: ``(scores (K,) float32 in [0, 1], valid (K,) bool)``.

    anomaly a, road_probability (H, W) float; labels (H, W) int in [0, K) (from ``slic``).
    ``valid`` marks the ids that have pixels; the others score 0. ``block_rows``: superpixels per
    block of pair distances (None: as many as fit 4M pairs); it changes memory, not the result.
    """
    args = _check(anomaly, road_probability, labels, num_segments, block_rows, batched=False)
    return _superpixel_scores_jit(*args[:3], num_segments=args[3], include_self=include_self,
                                  block_rows=block_rows)


def superpixel_score(anomaly, road_probability, labels, num_segments: int, *, include_self: bool = False,
                     block_rows: int | None = None):
    """Eq. 6 as a map: each pixel gets its superpixel's normalised score, ``(H, W)`` float32 in [0, 1].

    Inputs as ``superpixel_scores``. MMF detects anomalies where this exceeds 0.5 (§IV-A).
    """
    args = _check(anomaly, road_probability, labels, num_segments, block_rows, batched=False)
    return _superpixel_score_jit(*args[:3], num_segments=args[3], include_self=include_self,
                                 block_rows=block_rows)


def superpixel_score_batch(anomaly, road_probability, labels, num_segments: int, *, include_self: bool = False,
                           block_rows: int | None = None):
    """``superpixel_score`` over a batch: ``(B, H, W)`` inputs -> ``(B, H, W)`` float32."""
    args = _check(anomaly, road_probability, labels, num_segments, block_rows, batched=True)
    return _superpixel_score_batch(*args[:3], num_segments=args[3], include_self=include_self,
                                   block_rows=block_rows)
