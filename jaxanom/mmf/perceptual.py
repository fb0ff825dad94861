"""MMF's perceptual difference (Eq. 3) and anomaly map A = U * L (Eq. 4).

Feature maps come from any extractor (VGG stages, the segmenter's ResNet stages) applied to the
image x and to its resynthesis r: two lists of ``(h_i, w_i, C_i)`` arrays, layer i of both of the
same shape. Per layer, d_i = ``sum_c |F_i(x) - F_i(r)|`` (``reduction="mean"``: the channel mean,
SynBoost's choice, an option), resized bilinearly (half-pixel centres, no antialiasing) to ``out_hw``;
L = sum_i w_i d_i, min-max normalised over the image (0 where x and r agree everywhere).
"""
from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from jaxanom._validate import check_finite, check_rank
from jaxanom.mmf.uncertainty import minmax

REDUCTIONS = ("sum", "mean")


def _resize_map(x: jax.Array, out_hw: tuple[int, int]) -> jax.Array:
    """(h, w, ...) -> (H, W, ...) bilinear with half-pixel centres and edge clamping, no antialiasing."""
    return jax.image.resize(x, tuple(out_hw) + x.shape[2:], "bilinear", antialias=False)


def _perceptual(feats_x, feats_r, out_hw, weights, reduction: str):
    total = jnp.zeros(out_hw, jnp.float32)
    for fx, fr, w in zip(feats_x, feats_r, weights):
        diff = jnp.abs(fx.astype(jnp.float32) - fr.astype(jnp.float32))
        per_pixel = jnp.sum(diff, -1) if reduction == "sum" else jnp.mean(diff, -1)
        total = total + w * _resize_map(per_pixel, out_hw)
    return minmax(total)


def _anomaly(entropy, perceptual):
    return _resize_map(entropy.astype(jnp.float32), perceptual.shape[:2]) * perceptual


_STATIC = ("out_hw", "reduction")
_perceptual_jit = jax.jit(_perceptual, static_argnames=_STATIC)
_anomaly_jit = jax.jit(_anomaly)
_anomaly_batch = jax.jit(jax.vmap(_anomaly))


@functools.partial(jax.jit, static_argnames=_STATIC)
def _perceptual_batch(feats_x, feats_r, out_hw, weights, reduction: str):
    return jax.vmap(lambda x, r: _perceptual(x, r, out_hw, weights, reduction))(feats_x, feats_r)


def _check_features(feats_x, feats_r, out_hw, weights, reduction, batched: bool):
    feats_x, feats_r = list(feats_x), list(feats_r)
    if not feats_x or len(feats_x) != len(feats_r):
        raise ValueError(f"feats_x and feats_r must be equally long non-empty lists, got {len(feats_x)} and {len(feats_r)}")
    rank, layout = (4, "(B, h, w, C)") if batched else (3, "(h, w, C)")
    for i, (fx, fr) in enumerate(zip(feats_x, feats_r)):
        check_rank(f"feats_x[{i}]", fx, rank, layout)
        if np.shape(fr) != np.shape(fx):
            raise ValueError(f"feats_r[{i}] must have the shape of feats_x[{i}] {np.shape(fx)}, got {np.shape(fr)}")
        if batched and np.shape(fx)[0] != np.shape(feats_x[0])[0]:
            raise ValueError(f"feats_x[{i}] must have batch size {np.shape(feats_x[0])[0]}, got {np.shape(fx)[0]}")
        check_finite(f"feats_x[{i}]", fx)
        check_finite(f"feats_r[{i}]", fr)
    out_hw = tuple(int(v) for v in out_hw)
    if len(out_hw) != 2 or min(out_hw) < 1:
        raise ValueError(f"out_hw must be (H, W) with H, W >= 1, got {out_hw}")
    weights = (1.0,) * len(feats_x) if weights is None else tuple(float(w) for w in weights)
    if len(weights) != len(feats_x):
        raise ValueError(f"weights must have one entry per layer ({len(feats_x)}), got {len(weights)}")
    if reduction not in REDUCTIONS:
        raise ValueError(f"reduction must be one of {REDUCTIONS}, got {reduction!r}")
    return [jnp.asarray(f) for f in feats_x], [jnp.asarray(f) for f in feats_r], out_hw, jnp.asarray(weights, jnp.float32)


def perceptual_difference(feats_x, feats_r, out_hw, *, weights=None, reduction: str = "sum") -> jax.Array:
    """Eq. 3, normalised: lists of features ``(h_i, w_i, C_i)`` of x and r -> L ``out_hw`` float32 in [0, 1].

    weights: one per layer (default all 1, the paper's unweighted sum).
    """
    args = _check_features(feats_x, feats_r, out_hw, weights, reduction, batched=False)
    return _perceptual_jit(args[0], args[1], args[2], args[3], reduction)


def perceptual_difference_batch(feats_x, feats_r, out_hw, *, weights=None, reduction: str = "sum") -> jax.Array:
    """``perceptual_difference`` over a batch: features ``(B, h_i, w_i, C_i)`` -> ``(B, H, W)``."""
    args = _check_features(feats_x, feats_r, out_hw, weights, reduction, batched=True)
    return _perceptual_batch(args[0], args[1], args[2], args[3], reduction)


def _check_anomaly(entropy, perceptual, batched: bool):
    rank, layout = (3, "(B, H, W)") if batched else (2, "(H, W)")
    check_rank("entropy", entropy, rank, layout)
    check_rank("perceptual", perceptual, rank, layout)
    if batched and np.shape(entropy)[0] != np.shape(perceptual)[0]:
        raise ValueError(f"entropy must have the batch size of perceptual {np.shape(perceptual)[0]}, got {np.shape(entropy)[0]}")
    check_finite("entropy", entropy)
    check_finite("perceptual", perceptual)
    return jnp.asarray(entropy), jnp.asarray(perceptual)


def anomaly_map(entropy, perceptual) -> jax.Array:
    """Eq. 4, A = U * L: entropy U ``(h, w)`` resized bilinearly to L's ``(H, W)``, times L; float32."""
    return _anomaly_jit(*_check_anomaly(entropy, perceptual, batched=False))


def anomaly_map_batch(entropy, perceptual) -> jax.Array:
    """``anomaly_map`` over a batch: ``(B, h, w)`` and ``(B, H, W)`` -> ``(B, H, W)``."""
    return _anomaly_batch(*_check_anomaly(entropy, perceptual, batched=True))
