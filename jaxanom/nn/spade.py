"""Spatially-adaptive normalisation (SPADE, Park et al. 2019 [34]) and SynBoost's SPADE block.

    SPADE(x, s) = BN(x) * (1 + gamma(s)) + beta(s),
    gamma, beta = conv3x3(ReLU(conv3x3(nearest(s), hidden)))

``x``: (B, h, w, C) features; ``s``: (B, H, W, K) a conditioning map (one-hot semantics),
resized to (h, w) by nearest neighbour (PyTorch's rule: source index floor(o * H / h)). BN is
a parameter-free BatchNorm (batch statistics with ``train=True``, running averages otherwise).
``SPADEBlock(x; s) = SELU(SPADE(conv3x3(SELU(SPADE(x, s))), s))`` (docs/papers/mmf.md#spade-block).
"""
from __future__ import annotations

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np

from jaxanom.nn.layers import BN_EPSILON, BN_MOMENTUM, Dtype


def one_hot_semantic(labels: jax.Array, num_classes: int, dtype: Dtype = jnp.float32) -> jax.Array:
    """(..., ) int classes -> (..., C + 1) one-hot; channel C holds 255 (unknown) and anything
    outside [0, C) (the SPADE conditioning of MMF's networks)."""
    labels = jnp.where((labels >= 0) & (labels < num_classes), labels, num_classes)
    return jax.nn.one_hot(labels, num_classes + 1, dtype=dtype)


def resize_nearest(x: jax.Array, height: int, width: int) -> jax.Array:
    """(B, H, W, K) -> (B, height, width, K); output pixel o takes source floor(o * H / height)."""
    rows = (np.arange(height) * x.shape[1]) // height
    cols = (np.arange(width) * x.shape[2]) // width
    return x[:, rows][:, :, cols]


class SPADE(nn.Module):
    """``SPADE(hidden)(x, s, train) -> (B, h, w, C)``; see the module docstring."""

    hidden: int = 128
    dtype: Dtype = jnp.float32

    @nn.compact
    def __call__(self, x: jax.Array, s: jax.Array, train: bool) -> jax.Array:
        normed = nn.BatchNorm(use_running_average=not train, use_scale=False, use_bias=False, momentum=BN_MOMENTUM,
                              epsilon=BN_EPSILON, dtype=self.dtype, name="bn")(x)
        s = resize_nearest(s.astype(self.dtype), *x.shape[1:3])
        conv = lambda features, name: nn.Conv(features, (3, 3), padding=1, dtype=self.dtype,  # noqa: E731
                                              param_dtype=jnp.float32, name=name)
        shared = nn.relu(conv(self.hidden, "shared")(s))
        gamma, beta = conv(x.shape[-1], "gamma")(shared), conv(x.shape[-1], "beta")(shared)
        return normed * (1 + gamma) + beta


class SPADEBlock(nn.Module):
    """SELU(SPADE(conv3x3(SELU(SPADE(x, s))), s)); keeps the channels of ``x``."""

    hidden: int = 128
    dtype: Dtype = jnp.float32

    @nn.compact
    def __call__(self, x: jax.Array, s: jax.Array, train: bool) -> jax.Array:
        y = nn.selu(SPADE(self.hidden, self.dtype, name="spade0")(x, s, train))
        y = nn.Conv(x.shape[-1], (3, 3), padding=1, dtype=self.dtype, param_dtype=jnp.float32, name="conv")(y)
        return nn.selu(SPADE(self.hidden, self.dtype, name="spade1")(y, s, train))
