"""Fully connected CRF mean-field inference (Kraehenbuehl & Koltun 2011) in JAX.

Energy: unary ``U = -log clip(P, 1e-8)``; pairwise Potts ``mu(l, l') = [l != l']`` times
``w_b k_b + w_g k_g`` with

- appearance (bilateral) ``k_b = exp(-|dp|^2 / 2 sxy_b^2 - |dI|^2 / 2 srgb^2)``,
- smoothness ``k_g = exp(-|dp|^2 / 2 sxy_g^2)``,

(p in pixels, I in 8-bit units, i.e. ``255 * image``). Mean field, with the Potts constant
dropped from the softmax: ``Q <- softmax(-U + sum_m w_m K~_m Q)``, where ``K~`` leaves out
j = i, and ``normalization="symmetric"`` (pydensecrf's default) uses
``D^-1/2 K~ D^-1/2`` with ``D = K 1`` (self included).

Two filters compute ``K Q``:

- ``method="exact"``: the O(N^2) sum in row blocks (the oracle; up to ~10^4 pixels);
- ``method="permutohedral"``: the permutohedral lattice of Adams, Baek & Davis (2010): features
  are lifted onto the (d+1)-dimensional lattice, splatted with barycentric weights, blurred
  with [1 2 1]/2 along each of the d+1 lattice directions and sliced back, for the bilateral
  kernel. Its keys are packed into int64 codes and sorted once, alone (``lattice_keys``, which
  also counts the vertices; on CPU by NumPy through a callback); the tables get that many slots
  rounded up to a quarter octave (``lattice_tables``): each point's vertex 0 is found by binary
  search, the others by neighbour steps along its simplex. ``K~`` subtracts the lattice's own
  diagonal (``Lattice.self_weight``, 0.4-0.8, not 1; from per-vertex tables of the blur walks) and
  divides by ``mass_scale`` (the lattice's off-diagonal mass over the exact kernel's, ~0.4-0.6).
  The smoothness kernel depends only on positions and separates: it is computed to float32
  rounding (``positional_filter``: two banded 1-D filters, taps beyond 6 sigma dropped), with no lattice.

The public ``dense_crf`` computes in float32 (the lattice keys in int64 under a local
``jax.enable_x64``) and returns Q ``(H, W, L)``.
"""
from __future__ import annotations

import functools
import math
from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxanom._batching import over_images
from jaxanom._validate import check_finite, check_range, check_rank
from jaxanom.shapes import padded_size

_BLOCK = 512  # rows of the exact kernel computed at once
_TILE = 64  # outputs per block of the banded positional filter


# ---- features ----------------------------------------------------------------------------------


def crf_features(image: jax.Array, sxy_b, srgb, sxy_g) -> tuple[jax.Array, jax.Array]:
    """Scaled features ``(N, 5)`` (bilateral) and ``(N, 2)`` (smoothness); ``image (H, W, 3)`` in [0, 1]."""
    h, w = image.shape[:2]
    yy, xx = jnp.meshgrid(jnp.arange(h, dtype=jnp.float32), jnp.arange(w, dtype=jnp.float32), indexing="ij")
    pos = jnp.stack([yy, xx], axis=-1).reshape(-1, 2)
    rgb = 255.0 * image.reshape(-1, image.shape[-1]).astype(jnp.float32)
    return jnp.concatenate([pos / sxy_b, rgb / srgb], axis=-1), pos / sxy_g


# ---- exact filter ------------------------------------------------------------------------------


@jax.jit
def exact_filter(features: jax.Array, values: jax.Array) -> jax.Array:
    """``sum_j exp(-|f_i - f_j|^2 / 2) v_j`` (self included), ``(N, d), (N, L) -> (N, L)``, in row blocks."""
    n = features.shape[0]
    pad = (-n) % _BLOCK
    rows = jnp.pad(features, ((0, pad), (0, 0))).reshape(-1, _BLOCK, features.shape[-1])

    def block(f_rows):
        d2 = jnp.sum((f_rows[:, None, :] - features[None, :, :]) ** 2, axis=-1)
        return jnp.exp(-0.5 * d2) @ values

    return jax.lax.map(block, rows).reshape(-1, values.shape[-1])[:n]


# ---- permutohedral lattice ---------------------------------------------------------------------


class Lattice(NamedTuple):
    """A built lattice: per point and vertex the vertex id ``(N, d+1)`` and weight ``(N, d+1)``;
    per lattice direction the two neighbours of every vertex ``(d+1, 2, S)`` (S = empty slot);
    ``self_weight (N,)``: the filter's weight of each point on itself (``lattice_filter``'s
    diagonal); ``fits``: whether every key fitted the int64 packing (else the lattice is wrong)."""

    vertex: jax.Array
    weight: jax.Array
    neighbours: jax.Array
    self_weight: jax.Array
    fits: jax.Array


class LatticeKeys(NamedTuple):
    """The first half of a build: every point's vertex codes and their sorted copy (no table size yet)."""

    codes: jax.Array  # (N (d+1),) int64, point-major
    ordered: jax.Array  # (N (d+1),) the codes sorted
    count: jax.Array  # int32 scalar: the number of distinct vertices
    weight: jax.Array  # (N, d+1) barycentric weights
    rank: jax.Array  # (N, d+1) the simplex ordering of the coordinates
    fits: jax.Array


def _elevate(features: jax.Array) -> jax.Array:
    """Project ``(N, d)`` onto the plane ``sum = 0`` of R^{d+1}, scaled for a unit-std Gaussian."""
    d = features.shape[-1]
    inv_std = math.sqrt(2.0 / 3.0) * (d + 1)
    scale = jnp.asarray([inv_std / math.sqrt((i + 1) * (i + 2)) for i in range(d)], features.dtype)
    cf = features * scale
    suffix = jnp.cumsum(cf[:, ::-1], axis=-1)[:, ::-1]  # suffix[j] = sum_{i >= j} cf_i
    tail = jnp.concatenate([suffix[:, 1:], jnp.zeros_like(suffix[:, :1])], axis=-1)  # sum_{i > j} cf_i
    j = jnp.arange(1, d + 1, dtype=features.dtype)
    return jnp.concatenate([suffix[:, :1], tail - j * cf], axis=-1)  # e_0 = sum cf, e_j = sum_{i>=j} cf_i - j cf_{j-1}


def _packing(d: int):
    bits = 62 // d
    return jnp.int64(1) << jnp.arange(d, dtype=jnp.int64) * bits, jnp.int64(1) << (bits - 1)


def _sort(codes: jax.Array) -> jax.Array:
    """``jnp.sort(codes)`` (int64) along the last axis; on CPU NumPy's, through a callback
    (XLA:CPU sorts 3M int64 in 264 ms, NumPy in 31 ms, measured). The callback sees int32 pairs:
    it runs on a thread where ``jax.enable_x64`` may be off, and an int64 result would not pass."""
    if jax.default_backend() != "cpu":
        return jnp.sort(codes)
    pairs = jax.lax.bitcast_convert_type(codes, jnp.int32)  # (..., M, 2)

    def host(p):
        return np.sort(np.ascontiguousarray(p).view(np.int64)[..., 0], axis=-1)[..., None].view(np.int32)

    ordered = jax.pure_callback(host, jax.ShapeDtypeStruct(pairs.shape, jnp.int32), pairs, vmap_method="expand_dims")
    return jax.lax.bitcast_convert_type(ordered, jnp.int64)


@jax.jit
def lattice_keys(features: jax.Array) -> LatticeKeys:
    """Simplex vertices and barycentric weights of ``features (N, d)`` (already divided by their
    std devs), their codes sorted once; ``.count`` sizes the tables of ``lattice_tables``."""
    d = features.shape[1]
    elevated = _elevate(features)
    rem0 = jnp.round(elevated / (d + 1)) * (d + 1)
    total = jnp.sum(rem0, axis=-1) / (d + 1)
    diff = elevated - rem0
    # rank[i] = position of coordinate i in descending order of diff (ties: the lower index first)
    greater = (diff[:, None, :] > diff[:, :, None]) | ((diff[:, None, :] == diff[:, :, None])
                                                     & (jnp.arange(d + 1)[None, :] < jnp.arange(d + 1)[:, None]))
    rank = jnp.sum(greater, axis=-1, dtype=jnp.int32) + total[:, None].astype(jnp.int32)
    low, high = rank < 0, rank > d
    rank = jnp.where(low, rank + d + 1, jnp.where(high, rank - d - 1, rank))
    rem0 = jnp.where(low, rem0 + d + 1, jnp.where(high, rem0 - d - 1, rem0))
    v = (elevated - rem0) / (d + 1)
    # barycentric weights: b[p] = v[the coordinate of rank d - p] - v[the one of rank d - p + 1], b[0] += 1 + b[d+1]
    # (summed coordinate by coordinate: 2x faster on CPU than an (N, d+1, d+1) select and reduce)
    by_rank = sum(jnp.where(rank[:, i:i + 1] == d - np.arange(d + 1), v[:, i:i + 1], 0.0) for i in range(d + 1))
    bary = by_rank - jnp.concatenate([by_rank[:, d:] - 1.0, by_rank[:, :d]], axis=-1)  # b[0] = by_rank[0] + 1 - by_rank[d]

    # vertex r of the simplex: rem0 + canonical[r][rank], with canonical[r][j] = r - (d+1) [j > d - r]
    r = np.arange(d + 1, dtype=np.int32)[:, None]
    keys = rem0[:, None, :d] + (r - (d + 1) * (rank[:, None, :d] > d - r)).astype(features.dtype)  # (N, d+1, d), integers
    base, half = _packing(d)
    # digits (also neighbours') in their field: over r, canonical[r][k] takes every value in [-k, d - k]
    fits = jnp.max(jnp.maximum(jnp.abs(rem0[:, :d] - rank[:, :d]), jnp.abs(rem0[:, :d] + d - rank[:, :d]))) < half - (d + 2)
    codes = jnp.sum((keys.astype(jnp.int64) + half) * base, axis=-1).reshape(-1)
    ordered = _sort(codes)
    count = 1 + jnp.sum(ordered[1:] != ordered[:-1], dtype=jnp.int32)
    return LatticeKeys(codes, ordered, count, bary, rank.astype(jnp.int32), fits)


@functools.partial(jax.jit, static_argnames="size")
def lattice_tables(keys: LatticeKeys, size: int) -> Lattice:
    """The vertex tables of ``keys`` with room for ``size`` (static) distinct vertices: blur and
    neighbour search cost O(size); with fewer than ``keys.count``, ``fits`` is false."""
    n, dp1 = keys.weight.shape
    d = dp1 - 1
    base, _ = _packing(d)
    empty = jnp.iinfo(jnp.int64).max
    new = jnp.concatenate([jnp.zeros((1,), jnp.int32), (keys.ordered[1:] != keys.ordered[:-1]).astype(jnp.int32)])
    slot = jax.lax.associative_scan(jnp.add, new)  # a cumsum, 3x faster than jnp.cumsum's on CPU
    unique = jnp.full((size,), empty, jnp.int64).at[slot].set(keys.ordered, mode="drop")  # sorted

    def find(codes):  # the slot of each code, `size` if absent (or dropped: then fits is false)
        at = jnp.clip(jnp.searchsorted(unique, codes), 0, size - 1)
        return jnp.where((unique[at] == codes) & (codes != empty), at, size).astype(jnp.int32)

    # the step along direction j: key - 1 everywhere and + d at j (j < d); the opposite one: its negative
    step = -jnp.sum(base) + (d + 1) * jnp.concatenate([base, jnp.zeros((1,), jnp.int64)])
    ahead = find((unique[None, :] + step[:, None]).reshape(-1)).reshape(dp1, size)
    back = jnp.full((dp1, size + 1), size, jnp.int32).at[jnp.arange(dp1)[:, None], ahead].set(jnp.arange(size, dtype=jnp.int32))
    back = back.at[:, size].set(size)  # from a missing vertex: missing
    neighbours = jnp.stack([ahead, back[:, :size]], axis=1)  # (d+1, 2, size)
    # the simplex: vertex 0 is the point's remainder-0 key, vertex r+1 is one step back from vertex r
    # along the direction of rank d - r (its key: +1 everywhere, -d there)
    vertex = [find(keys.codes.reshape(n, dp1)[:, 0])]
    for r in range(d):
        direction = sum(jnp.where(keys.rank[:, i] == d - r, i, 0) for i in range(dp1))  # of rank d - r
        vertex.append(back.reshape(-1)[direction * (size + 1) + vertex[-1]])
    inverse = jnp.stack(vertex, axis=-1)
    self_weight = _self_weights(inverse, keys.weight, keys.rank, neighbours)
    return Lattice(inverse, keys.weight, neighbours, self_weight, keys.fits & (keys.count <= size))


def _walks(neighbours: jax.Array) -> jax.Array:
    """Which blur walks exist, bit-packed ``(size + 1, 2, K)`` int64 (K = 2^(d+1) / 64 rounded up):
    bit m % 64 of word m // 64 is ``P[y, m]`` in ``[:, 0]``, ``N[y, m]`` in ``[:, 1]``. ``P[y, m]``:
    the walk from vertex y that moves +1 along the directions in bit mask m and stays on the others,
    ``N[y, m]`` the one that moves -1 on m; it exists if every vertex on the way does (row
    ``size``: a missing start, none). Built as binary trees over the directions in blur order:
    2^(d+1) - 1 gathers per vertex each."""
    dp1, _, size = neighbours.shape
    moves = jnp.concatenate([neighbours, jnp.full((dp1, 2, 1), size, jnp.int32)], axis=-1)
    exists = []
    for sense in (0, 1):  # +1 moves, -1 moves
        at = [jnp.arange(size + 1, dtype=jnp.int32)]  # at[m]: where the walk of mask m is so far
        for j in range(dp1):
            at = at + [moves[j, sense][column] for column in at]  # masks with bit j set moved along j
        # compared before stacking: XLA fuses the gathers into the stack (3x faster than stacking int32 columns)
        exists.append(jnp.stack([column < size for column in at], axis=1))
    # 16-bit pieces by a matmul (exact in float32), which XLA does not fuse into the per-point
    # gather of the rows (fused, the packing ran per point: 5x slower than 36 float look-ups), then words
    exists = jnp.pad(jnp.stack(exists, axis=1), ((0, 0), (0, 0), (0, -(2**dp1) % 64))).reshape(size + 1, 2, -1, 4, 16)
    pieces = (exists.astype(jnp.float32) @ (2.0 ** np.arange(16, dtype=np.float32))).astype(jnp.int64)
    return jnp.sum(pieces << np.arange(0, 64, 16), axis=-1)


def _self_weights(vertex, weight, rank, neighbours):
    """Diagonal of the splat-blur-slice operator: ``alpha sum_{a,b} w_a w_b B[v_a, v_b]`` per point.

    ``B[v_a, v_b]`` (what a unit splatted at vertex b holds at vertex a after the d+1 blurs) sums
    over the walks b -> a that move by s_j in {-1, 0, 1} lattice steps along direction j, in blur
    order, with weight 1/2 per move. The simplex's v_a - v_b is a sum of steps over the directions
    m whose rank lies in (d - max(a,b), d - min(a,b)] (sign: + if a < b); since the d+1 steps sum
    to 0, the walks are: a < b, +1 on m or -1 off m (``P[m] + N[~m]``); a > b, -1 on m or +1 off
    m (``N[m] + P[~m]``); a = b, staying or +1 / -1 on all (``P[0] + P[~0] + N[~0]``). A walk
    counts only if every vertex it passes exists in this lattice (a missing one holds nothing):
    one bit of ``_walks``' row of v_b, gathered once per point and vertex.
    """
    dp1 = weight.shape[1]
    full = 2**dp1 - 1
    # below[:, k]: the mask of the directions of rank < k, k = 0..d+1
    below = sum(jnp.where(rank[:, j:j + 1] < np.arange(dp1 + 1), np.int64(1) << j, 0) for j in range(dp1))
    words = _walks(neighbours)[vertex]  # (N, d+1, 2, K): the rows of the vertices

    def walk(b, sense, mask):  # 0 / 1: whether the walk `sense` of `mask` from v_b exists
        word = sum(jnp.where(mask >> 6 == k, words[:, b, sense, k], 0) for k in range(words.shape[-1]))
        return ((word >> (mask & 63)) & 1).astype(weight.dtype)

    terms = []
    for a in range(dp1):
        for b in range(dp1):
            if a == b:
                gains = walk(b, 0, 0) + 0.5**dp1 * (walk(b, 0, full) + walk(b, 1, full))
            else:  # m: the ranks in (d - max(a,b), d - min(a,b)]; |m| moves of 1/2 each
                ranks = below[:, dp1 - min(a, b)] - below[:, dp1 - max(a, b)]
                m, moved = (ranks, b - a) if a < b else (full - ranks, dp1 - (a - b))
                gains = 0.5**moved * walk(b, 0, m) + 0.5 ** (dp1 - moved) * walk(b, 1, full - m)
            terms.append(weight[:, a] * weight[:, b] * gains)
    # one reduction: its result is stored once (XLA would copy a sum of terms into every consumer)
    return _alpha(dp1) * jnp.sum(jnp.stack(terms, axis=-1), axis=-1)


def _alpha(dp1: int) -> float:
    """The slice's scale ``1 / (1 + 2^-d)``: a point on a vertex of a full lattice weighs itself 1."""
    return 1.0 / (1.0 + 2.0 ** (-(dp1 - 1)))


@functools.partial(jax.jit, static_argnames="size")
def build_lattice(features: jax.Array, size: int | None = None) -> Lattice:
    """The permutohedral lattice of ``features (N, d)`` (already divided by their std devs), with
    room for ``size`` (static) vertices (default ``N (d+1)``, always enough)."""
    keys = lattice_keys(features)
    return lattice_tables(keys, keys.codes.shape[0] if size is None else size)


@jax.jit
def vertex_count(features: jax.Array) -> jax.Array:
    """The number of distinct lattice vertices of ``features (N, d)`` (int32 scalar)."""
    return lattice_keys(features).count


@jax.jit
def lattice_filter(lattice: Lattice, values: jax.Array) -> jax.Array:
    """Approximate ``sum_j exp(-|f_i - f_j|^2 / 2) v_j``: splat, blur along d+1 directions, slice."""
    n, dp1 = lattice.vertex.shape
    size = lattice.neighbours.shape[-1]
    splat = jax.ops.segment_sum((lattice.weight[..., None] * values[:, None, :]).reshape(n * dp1, -1),
                                lattice.vertex.reshape(-1), num_segments=size + 1)  # slot `size` stays 0

    def blur(grid, pair):
        return grid.at[:size].add(0.5 * (grid[pair[0]] + grid[pair[1]])), None

    grid, _ = jax.lax.scan(blur, splat, lattice.neighbours, unroll=True)
    # the slice as a sum of d+1 gathered rows: one fused loop, 5x faster on CPU than an einsum
    # over the gathered (N, d+1, L) block (a batch of N tiny matrix products)
    return _alpha(dp1) * sum(lattice.weight[:, r:r + 1] * grid[lattice.vertex[:, r]] for r in range(dp1))


# ---- mean field --------------------------------------------------------------------------------


def positional_filter(height: int, width: int, sigma: float) -> Callable[[jax.Array], jax.Array]:
    """The smoothness filter ``sum_j exp(-|p_i - p_j|^2 / 2 sigma^2) v_j`` (self included),
    ``(H W, L) -> (H W, L)``: the Gaussian separates over rows and columns, ``K v = K_y V K_x``,
    each factor a banded 1-D filter (``_gaussian_rows``; ``sigma`` static)."""
    def apply(v):
        x = _gaussian_rows(v.reshape(height, -1), sigma).reshape(height, width, -1)
        x = _gaussian_rows(x.transpose(1, 0, 2).reshape(width, -1), sigma).reshape(width, height, -1)
        return x.transpose(1, 0, 2).reshape(height * width, -1)

    return apply


def _gaussian_rows(x: jax.Array, sigma: float) -> jax.Array:
    """``y_i = sum_j exp(-(i - j)^2 / 2 sigma^2) x_j`` along axis 0 of ``x (n, M)``, keeping the taps
    ``|i - j| <= r = ceil(6 sigma)``: those dropped sum to at most ``int_r^inf exp(-t^2 / 2 sigma^2) dt
    <= sigma sqrt(pi / 2) erfc(6 / sqrt 2) < 2.5e-9 sigma`` on each side, so ``|y - y_exact| <= 5e-9
    sigma max|x|`` (the centre tap alone is 1). Blocks of ``_TILE`` outputs read ``_TILE + 2r`` inputs:
    O(n (_TILE + 2r) M) instead of the dense O(n^2 M); where the band covers the image
    (``r >= n - 1``), one dense n x n matrix with every tap."""
    n = x.shape[0]
    reach = math.ceil(6 * sigma)
    tile, pad = (n, 0) if reach >= n - 1 else (_TILE, reach)
    count = -(-n // tile)
    padded = jnp.pad(x, ((pad, count * tile - n + pad), (0, 0)))
    window = padded[np.arange(count)[:, None] * tile + np.arange(tile + 2 * pad)]  # (count, tile + 2 pad, M)
    offset = np.arange(tile)[:, None] + pad - np.arange(tile + 2 * pad)  # output - input
    band = np.where(np.abs(offset) <= reach, np.exp(-0.5 * (offset / sigma) ** 2), 0.0).astype(np.float32)
    return jnp.einsum("ab,tbm->tam", band, window).reshape(count * tile, -1)[:n]


@functools.partial(jax.jit, static_argnames="rows")
def mass_scale(lattice: Lattice, features: jax.Array, rows: int = 64) -> jax.Array:
    """``c`` with ``K~_lattice ~ c K~``: the lattice's off-diagonal mass over the exact kernel's,
    both summed over ``rows`` (static) evenly strided points (O(rows N)); 1 if the exact is 0."""
    n = features.shape[0]
    picked = jnp.arange(0, n, max(1, n // rows))
    # |f_i - f_j|^2 summed feature by feature over (rows, N) planes: 5x faster on CPU than a (rows, N, d) sum over d
    d2 = sum((column[picked][:, None] - column[None]) ** 2 for column in features.T)
    exact = jnp.sum(jnp.exp(-0.5 * d2)) - picked.size
    approx = jnp.sum(lattice_filter(lattice, jnp.ones((n, 1), features.dtype))[picked, 0] - lattice.self_weight[picked])
    return jnp.where(exact > 0, approx / jnp.where(exact > 0, exact, 1.0), 1.0)


def _mean_field(unary, terms, iters, symmetric: bool):
    """``terms``: (``v -> K~ v``, w_m) with ``K~`` the kernel without its diagonal; symmetric:
    ``D = K~ 1 + 1`` (the exact kernel's row sums, self weight 1). ``iters`` may be traced: every
    iteration count of one shape shares a compile."""
    ones = jnp.ones((unary.shape[0], 1), unary.dtype)
    norms = [jax.lax.rsqrt(k(ones) + 1.0) if symmetric else ones for k, _ in terms]

    def step(_, q):
        message = sum(w * nm * k(nm * q) for (k, w), nm in zip(terms, norms))
        return _softmax(-unary + message)

    return jax.lax.fori_loop(0, iters, step, _softmax(-unary))


def _softmax(x: jax.Array) -> jax.Array:
    """``jax.nn.softmax(x, axis=-1)`` for ``x (N, L)`` with few labels, written label by label: XLA:CPU
    reduces a short minor axis slowly (5x slower at 512x1024x5)."""
    labels = [x[:, k:k + 1] for k in range(x.shape[-1])]
    top = labels[0]
    for label in labels[1:]:
        top = jnp.maximum(top, label)
    e = jnp.exp(x - top)
    return e / sum(e[:, k:k + 1] for k in range(x.shape[-1]))


def _bilateral_keys(image, sxy_b, srgb):
    return lattice_keys(crf_features(image, sxy_b, srgb, 1.0)[0])


def _dense_crf(probs, image, keys, sxy_b, srgb, w_b, sxy_g, w_g, iters, symmetric: bool, size: int | None):
    """One frame; ``keys``: the bilateral lattice's (permutohedral, each fitting the packing) or None (exact)."""
    h, w, num_labels = probs.shape
    unary = -jnp.log(jnp.clip(probs.reshape(-1, num_labels).astype(jnp.float32), 1e-8, None))
    f_b, f_g = crf_features(image, sxy_b, srgb, sxy_g)
    if keys is None:
        terms = [(lambda v: exact_filter(f_b, v) - v, w_b), (lambda v: exact_filter(f_g, v) - v, w_g)]
    else:
        lat = lattice_tables(keys, size)
        scale = mass_scale(lat, f_b)
        positional = positional_filter(h, w, sxy_g)
        terms = [(lambda v: (lattice_filter(lat, v) - lat.self_weight[:, None] * v) / scale, w_b),
                 (lambda v: positional(v) - v, w_g)]
    return _mean_field(unary, terms, iters, symmetric).reshape(h, w, num_labels)


def _dense_crf_frames(probs, image, keys, sxy_b, srgb, w_b, sxy_g, w_g, iters, symmetric: bool, size: int | None):
    return over_images(lambda p, i, k: _dense_crf(p, i, k, sxy_b, srgb, w_b, sxy_g, w_g, iters, symmetric, size),
                       probs, image, keys)


_keys_jit = jax.jit(_bilateral_keys)
_keys_batch = jax.jit(lambda images, sxy_b, srgb: over_images(lambda i: _bilateral_keys(i, sxy_b, srgb), images))
_dense_crf_jit = jax.jit(_dense_crf, static_argnums=(6, 9, 10))
_dense_crf_batch = jax.jit(_dense_crf_frames, static_argnums=(6, 9, 10))


def dense_crf(probs, image, *, sxy_b: float = 80.0, srgb: float = 13.0, w_b: float = 10.0, sxy_g: float = 3.0,
              w_g: float = 3.0, iters: int = 5, normalization: str = "symmetric", method: str = "permutohedral",
              reference_width: int | None = None) -> jax.Array:
    """Mean-field marginals Q ``(H, W, L)`` float32 of the dense CRF.

    ``probs (H, W, L)`` class probabilities (the unary is ``-log clip(P, 1e-8)``), ``image
    (H, W, C)`` in [0, 1] (colour differences are taken in 8-bit units, as pydensecrf's).
    Defaults are pydensecrf's common settings. ``reference_width``: if given, ``sxy_b`` and
    ``sxy_g`` are meant for an image that wide and are scaled by ``W / reference_width``.
    """
    return _run(_dense_crf_jit, probs, image, False, sxy_b, srgb, w_b, sxy_g, w_g, iters, normalization, method,
                reference_width)


def dense_crf_batch(probs, image, *, sxy_b: float = 80.0, srgb: float = 13.0, w_b: float = 10.0, sxy_g: float = 3.0,
                    w_g: float = 3.0, iters: int = 5, normalization: str = "symmetric", method: str = "permutohedral",
                    reference_width: int | None = None) -> jax.Array:
    """``dense_crf`` over a batch: ``probs (B, H, W, L)``, ``image (B, H, W, C)`` -> ``(B, H, W, L)``."""
    return _run(_dense_crf_batch, probs, image, True, sxy_b, srgb, w_b, sxy_g, w_g, iters, normalization, method,
                reference_width)


def _run(fn, probs, image, batched, sxy_b, srgb, w_b, sxy_g, w_g, iters, normalization, method, reference_width):
    lead = "B, " if batched else ""
    check_rank("probs", probs, 3 + batched, f"({lead}H, W, L)")
    check_rank("image", image, 3 + batched, f"({lead}H, W, C)")
    if np.shape(image)[:-1] != np.shape(probs)[:-1]:
        raise ValueError(f"image must have the {lead}height and width of probs {np.shape(probs)[:-1]}, got {np.shape(image)}")
    if min(np.shape(probs)) < 1:
        raise ValueError(f"probs must hold at least one pixel and one label, got shape {np.shape(probs)}")
    check_finite("probs", probs)
    check_finite("image", image)
    check_range("image", image, 0.0, 1.0, " (divide 8-bit images by 255)")
    for name, value in (("sxy_b", sxy_b), ("srgb", srgb), ("sxy_g", sxy_g)):
        if not value > 0:
            raise ValueError(f"{name} must be > 0, got {value}")
    if int(iters) < 0:
        raise ValueError(f"iters must be >= 0, got {iters}")
    if normalization not in ("symmetric", "none"):
        raise ValueError(f"normalization must be 'symmetric' or 'none', got {normalization!r}")
    if method not in ("permutohedral", "exact"):
        raise ValueError(f"method must be 'permutohedral' or 'exact', got {method!r}")
    scale = 1.0 if reference_width is None else np.shape(probs)[-2] / float(reference_width)
    with jax.enable_x64(True):
        image = jnp.asarray(image, jnp.float32)
        sigmas = jnp.float32(sxy_b * scale), jnp.float32(srgb), float(np.float32(sxy_g * scale))  # static: sizes the smoothness band
        keys, size = None, None
        if method == "permutohedral":  # the bilateral lattice is built once: sorted keys, then tables of its size
            keys = (_keys_batch if batched else _keys_jit)(image, sigmas[0], sigmas[1])
            count, fits = jax.device_get((keys.count, keys.fits))  # one read, before the CRF's work
            if not np.all(fits):
                raise ValueError("features too far apart for the lattice's key packing: increase sxy_b / srgb or use "
                                 "method='exact'")
            # 4 compiled lattice sizes per doubling; the blur, walks and searches cost O(size), at most 1.25x the count
            size = padded_size(int(np.max(count)))
        q = fn(jnp.asarray(probs, jnp.float32), image, keys, sigmas[0], sigmas[1], jnp.float32(w_b), sigmas[2],
               jnp.float32(w_g), jnp.int32(iters), normalization == "symmetric", size)
        return jnp.asarray(np.asarray(q))
