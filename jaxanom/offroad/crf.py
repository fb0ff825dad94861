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
  with [1 2 1]/2 along each of the d+1 lattice directions and sliced back. The lattice (keys,
  neighbours, weights) is built once per image: keys are packed into int64 codes and made
  unique with ``jnp.unique(size=N (d+1))``; neighbours are found by ``searchsorted``.

The public ``dense_crf`` computes in float32 (the lattice keys in int64 under a local
``jax.enable_x64``) and returns Q ``(H, W, L)``.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxanom._validate import check_finite, check_range, check_rank

_BLOCK = 512  # rows of the exact kernel computed at once


# ---- features ----------------------------------------------------------------------------------


def crf_features(image: jax.Array, sxy_b, srgb, sxy_g) -> tuple[jax.Array, jax.Array]:
    """Scaled features ``(N, 5)`` (bilateral) and ``(N, 2)`` (smoothness); ``image (H, W, 3)`` in [0, 1]."""
    h, w = image.shape[:2]
    yy, xx = jnp.meshgrid(jnp.arange(h, dtype=jnp.float32), jnp.arange(w, dtype=jnp.float32), indexing="ij")
    pos = jnp.stack([yy, xx], axis=-1).reshape(-1, 2)
    rgb = 255.0 * image.reshape(-1, image.shape[-1]).astype(jnp.float32)
    return jnp.concatenate([pos / sxy_b, rgb / srgb], axis=-1), pos / sxy_g


# ---- exact filter ------------------------------------------------------------------------------


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
    ``fits``: whether every key fitted the int64 packing (else the lattice is wrong)."""

    vertex: jax.Array
    weight: jax.Array
    neighbours: jax.Array
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


def build_lattice(features: jax.Array, size: int | None = None) -> Lattice:
    """The permutohedral lattice of ``features (N, d)`` (already divided by their std devs).

    ``size`` (static): room for that many distinct vertices (default ``N (d+1)``, always
    enough); with fewer than the lattice has, ``fits`` is false. ``vertex_count`` tells how
    many there are, so a caller can build with a tight size (blur and search cost O(size)).
    """
    n, d = features.shape
    elevated = _elevate(features)
    rem0 = jnp.round(elevated / (d + 1)) * (d + 1)
    total = jnp.sum(rem0, axis=-1) / (d + 1)
    diff = elevated - rem0
    # rank[i] = position of coordinate i in descending order of diff (ties: the lower index first)
    greater = (diff[:, None, :] > diff[:, :, None]) | ((diff[:, None, :] == diff[:, :, None])
                                                     & (jnp.arange(d + 1)[None, :] < jnp.arange(d + 1)[:, None]))
    rank = jnp.sum(greater, axis=-1) + total[:, None].astype(jnp.int32)
    low, high = rank < 0, rank > d
    rank = jnp.where(low, rank + d + 1, jnp.where(high, rank - d - 1, rank))
    rem0 = jnp.where(low, rem0 + d + 1, jnp.where(high, rem0 - d - 1, rem0))
    v = (elevated - rem0) / (d + 1)
    bary = jnp.zeros((n, d + 2), features.dtype)
    rows = jnp.arange(n)[:, None]
    bary = bary.at[rows, d - rank].add(v).at[rows, d - rank + 1].add(-v)
    bary = bary.at[:, 0].add(1.0 + bary[:, d + 1])[:, : d + 1]

    # vertex r of the simplex: rem0 + canonical[r][rank], with canonical[r][j] = r - (d+1) [j > d - r]
    r = jnp.arange(d + 1)
    canonical = r[:, None] - (d + 1) * (jnp.arange(d + 1)[None, :] > d - r[:, None])
    keys = rem0[:, None, :d].astype(jnp.int64) + canonical[:, rank[:, :d]].transpose(1, 0, 2)  # (N, d+1, d)
    bits = 62 // d
    base = jnp.int64(1) << jnp.arange(d, dtype=jnp.int64) * bits
    half = jnp.int64(1) << (bits - 1)
    codes = jnp.sum((keys + half) * base, axis=-1).reshape(-1)
    capacity = n * (d + 1)
    size = capacity if size is None else size
    empty = jnp.iinfo(jnp.int64).max
    order = jnp.argsort(codes)
    ordered = codes[order]
    slot = jnp.cumsum(jnp.concatenate([jnp.ones((1,), jnp.int32), (ordered[1:] != ordered[:-1]).astype(jnp.int32)])) - 1
    inverse = jnp.zeros((capacity,), jnp.int32).at[order].set(slot)
    unique = jnp.full((size,), empty, jnp.int64).at[slot].set(ordered, mode="drop")  # sorted; unused slots: `empty`
    # neighbour along direction j: key - 1 everywhere and + d at j (j < d); the opposite one: its negative
    step = -jnp.sum(base) + (d + 1) * jnp.concatenate([base, jnp.zeros((1,), jnp.int64)])
    queries = unique[None, None, :] + jnp.stack([step, -step], axis=1)[:, :, None]  # (d+1, 2, size)
    at = jnp.clip(jnp.searchsorted(unique, queries.reshape(-1)), 0, size - 1).reshape(queries.shape)
    found = (unique[at] == queries) & (unique != empty)[None, None, :]
    neighbours = jnp.where(found, at, size)
    fits = (jnp.max(jnp.abs(keys)) < half - (d + 2)) & (slot[-1] < size)  # digits (also neighbours') in their field
    return Lattice(inverse.reshape(n, d + 1), bary, neighbours.astype(jnp.int32), fits)


def vertex_count(features: jax.Array) -> jax.Array:
    """The number of distinct lattice vertices of ``features (N, d)`` (int32 scalar)."""
    return build_lattice(features, size=1).vertex.max() + 1


def lattice_filter(lattice: Lattice, values: jax.Array) -> jax.Array:
    """Approximate ``sum_j exp(-|f_i - f_j|^2 / 2) v_j``: splat, blur along d+1 directions, slice."""
    n, dp1 = lattice.vertex.shape
    size = lattice.neighbours.shape[-1]
    splat = jax.ops.segment_sum((lattice.weight[..., None] * values[:, None, :]).reshape(n * dp1, -1),
                                lattice.vertex.reshape(-1), num_segments=size + 1)  # slot `size` stays 0

    def blur(grid, pair):
        return grid.at[:size].add(0.5 * (grid[pair[0]] + grid[pair[1]])), None

    grid, _ = jax.lax.scan(blur, splat, lattice.neighbours)
    alpha = 1.0 / (1.0 + 2.0 ** (-(dp1 - 1)))
    return alpha * jnp.einsum("nr,nrl->nl", lattice.weight, grid[lattice.vertex])


# ---- mean field --------------------------------------------------------------------------------


def _mean_field(unary, filters, weights, iters: int, symmetric: bool):
    ones = jnp.ones((unary.shape[0], 1), unary.dtype)
    norms = [jax.lax.rsqrt(f(ones)) if symmetric else ones for f in filters]

    def step(q, _):
        message = sum(w * (nm * f(nm * q) - nm * nm * q) for f, w, nm in zip(filters, weights, norms))
        return jax.nn.softmax(-unary + message, axis=-1), None

    q, _ = jax.lax.scan(step, jax.nn.softmax(-unary, axis=-1), None, length=iters)
    return q


def _dense_crf(probs, image, sxy_b, srgb, w_b, sxy_g, w_g, iters: int, symmetric: bool, exact: bool, sizes=(None, None)):
    h, w, num_labels = probs.shape
    unary = -jnp.log(jnp.clip(probs.reshape(-1, num_labels).astype(jnp.float32), 1e-8, None))
    f_b, f_g = crf_features(image, sxy_b, srgb, sxy_g)
    if exact:
        filters = [lambda v: exact_filter(f_b, v), lambda v: exact_filter(f_g, v)]
        fits = jnp.asarray(True)
    else:
        lat_b, lat_g = build_lattice(f_b, sizes[0]), build_lattice(f_g, sizes[1])
        filters = [lambda v: lattice_filter(lat_b, v), lambda v: lattice_filter(lat_g, v)]
        fits = lat_b.fits & lat_g.fits
    q = _mean_field(unary, filters, (w_b, w_g), iters, symmetric)
    return q.reshape(h, w, num_labels), fits


def _vertex_counts(image, sxy_b, srgb, sxy_g):
    f_b, f_g = crf_features(image, sxy_b, srgb, sxy_g)
    return jnp.stack([vertex_count(f_b), vertex_count(f_g)])


def _room(count: int) -> int:
    """Lattice size for ``count`` vertices: the next power of two (few recompiles, tight blur)."""
    return max(64, 1 << (int(count) - 1).bit_length())


_dense_crf_jit = jax.jit(_dense_crf, static_argnums=(7, 8, 9, 10))
_dense_crf_batch = jax.jit(jax.vmap(_dense_crf, in_axes=(0, 0) + (None,) * 9), static_argnums=(7, 8, 9, 10))
_vertex_counts_jit = jax.jit(_vertex_counts)
_vertex_counts_batch = jax.jit(jax.vmap(_vertex_counts, in_axes=(0, None, None, None)))


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
        sigmas = jnp.float32(sxy_b * scale), jnp.float32(srgb), jnp.float32(sxy_g * scale)
        sizes = (None, None)
        if method == "permutohedral":  # size the lattices to their vertex count (two passes, both jitted)
            counts = np.asarray((_vertex_counts_batch if batched else _vertex_counts_jit)(image, *sigmas))
            sizes = tuple(_room(c) for c in counts.reshape(-1, 2).max(axis=0))
        q, fits = fn(jnp.asarray(probs, jnp.float32), image, sigmas[0], sigmas[1], jnp.float32(w_b), sigmas[2],
                     jnp.float32(w_g), int(iters), normalization == "symmetric", method == "exact", sizes)
        if not bool(jnp.all(fits)):
            raise ValueError("features too far apart for the lattice's key packing: increase sxy_b / srgb or use method='exact'")
        return jnp.asarray(np.asarray(q))
