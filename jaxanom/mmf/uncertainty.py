"""MMF's segmentation-side maps (Eqs. 1-2, normalised to [0, 1]) and Eq. 6's road probability.

``uncertainty_maps(logits)`` gives, for logits (H, W, C):

- ``"entropy"``  U = -sum_c p_c log2 p_c (Eq. 1), normalised by ``normalize``:
  ``"max"`` divides by log2 C (the largest entropy; scores.entropy(normalize=True)),
  ``"minmax"`` rescales the image's own range (SynBoost's code);
- ``"distance"`` D = 1 - p_(1) + p_(2) (Eq. 2; already in [0, 1]; min-max too under "minmax");
- ``"road"``     p_road = softmax(logits)[..., road] (Eq. 6's p_j before averaging);
- ``"prediction"`` the predicted classes argmax_c, int32 (the synthesizer's input).
"""
from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from jaxanom._validate import check_finite, check_rank
from jaxanom import scores

NORMALIZATIONS = ("max", "minmax")


def minmax(x: jax.Array) -> jax.Array:
    """Per-image min-max to [0, 1] of any map; a constant map gives 0."""
    low, high = jnp.min(x), jnp.max(x)
    scaled = (x - low) / jnp.where(high > low, high - low, 1.0)
    # clipped: XLA may fuse x's computation into min / max with other rounding
    return jnp.where(high > low, jnp.clip(scaled, 0.0, 1.0), 0.0)


def _maps(logits: jax.Array, road: int, normalize: str) -> dict:
    logits = logits.astype(jnp.float32)
    bits = scores.entropy(logits) / jnp.log(2.0)  # Eq. 1 in bits (the checks skip traced logits)
    distance = scores.softmax_distance(logits)
    if normalize == "max":
        entropy = jnp.clip(bits / jnp.log2(float(logits.shape[-1])), 0.0, 1.0)  # float32 rounding
    else:
        entropy, distance = minmax(bits), minmax(distance)
    return {"entropy": entropy, "distance": distance,
            "road": jax.nn.softmax(logits, axis=-1)[..., road],
            "prediction": jnp.argmax(logits, axis=-1).astype(jnp.int32)}


_STATIC = ("road", "normalize")
_maps_jit = jax.jit(_maps, static_argnames=_STATIC)


@functools.partial(jax.jit, static_argnames=_STATIC)
def _maps_batch(logits, road: int, normalize: str) -> dict:
    return jax.vmap(functools.partial(_maps, road=road, normalize=normalize))(logits)


def _check(logits, road, normalize, batched: bool):
    check_rank("logits", logits, 4 if batched else 3, "(B, H, W, C)" if batched else "(H, W, C)")
    classes = np.shape(logits)[-1]
    if classes < 2:
        raise ValueError(f"logits must have C >= 2 classes for Eqs. 1-2, got C={classes}")
    if not isinstance(road, (int, np.integer)) or not 0 <= road < classes:
        raise ValueError(f"road must be a class index in [0, {classes}), got {road!r}")
    if normalize not in NORMALIZATIONS:
        raise ValueError(f"normalize must be one of {NORMALIZATIONS}, got {normalize!r}")
    check_finite("logits", logits)
    return jnp.asarray(logits)


def uncertainty_maps(logits, *, road: int = 0, normalize: str = "max") -> dict:
    """Eqs. 1-2 normalised, road probability and prediction from logits ``(H, W, C)``, C >= 2.

    Returns float32 ``(H, W)`` maps ``"entropy"``, ``"distance"``, ``"road"`` and the int32
    ``(H, W)`` ``"prediction"``. ``road``: the road class (0 in Cityscapes trainIds).
    """
    return _maps_jit(_check(logits, road, normalize, batched=False), road=int(road), normalize=normalize)


def uncertainty_maps_batch(logits, *, road: int = 0, normalize: str = "max") -> dict:
    """``uncertainty_maps`` over a batch: logits ``(B, H, W, C)`` -> maps ``(B, H, W)``."""
    return _maps_batch(_check(logits, road, normalize, batched=True), road=int(road), normalize=normalize)
