"""Building blocks shared by the networks: conv + BatchNorm (+ ReLU), bilinear resize, spatial softmax.

Mixed precision: parameters are always float32 (``param_dtype``); ``dtype`` is the compute dtype
(e.g. ``jnp.bfloat16``). BatchNorm statistics are reduced in float32 whatever ``dtype`` is.
"""
from __future__ import annotations

from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np

from jaxanom.nn.batch_norm import BatchNorm
from jaxanom.nn.conv import Conv2D

Dtype = Any

# PyTorch's BatchNorm defaults (momentum 0.1 on the new value = 0.9 on the running value).
BN_MOMENTUM = 0.9
BN_EPSILON = 1e-5


class ConvBN(nn.Module):
    """``k x k`` convolution without bias, BatchNorm, optional ReLU; channels-last.

    Padding is symmetric, ``dilation * (k - 1) // 2`` per side, as in PyTorch, so a stride-2
    layer maps a side of n pixels to ceil(n / 2) and weights ported from PyTorch line up.
    ``train=True`` normalises with batch statistics and updates ``batch_stats``;
    ``train=False`` uses the running averages.
    """

    features: int
    kernel_size: int = 3
    stride: int = 1
    dilation: int = 1
    relu: bool = True
    dtype: Dtype = jnp.float32

    @nn.compact
    def __call__(self, x: jax.Array, train: bool) -> jax.Array:
        x = Conv2D(self.features, self.kernel_size, self.stride, self.dilation, self.dtype, name="conv")(x)
        x = BatchNorm(not train, BN_MOMENTUM, BN_EPSILON, self.dtype, name="bn")(x)
        return nn.relu(x) if self.relu else x


def _linear_taps(size_in: int, size_out: int, align_corners: bool = False
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Source indices (i0, i1) and weight of i1 for linear resampling.

    Half-pixel centres (``align_corners=False``): ``src = (o + 0.5) * size_in / size_out - 0.5``,
    clamped to [0, size_in - 1]. Corner-aligned (``align_corners=True``): ``src = o * (size_in - 1)
    / (size_out - 1)`` (0 when ``size_out`` is 1). The value at ``o`` is ``(1 - t) x[i0] + t x[i1]``,
    as PyTorch's ``interpolate(mode="bilinear", align_corners=...)``.
    """
    if align_corners:
        src = np.arange(size_out) * ((size_in - 1) / (size_out - 1) if size_out > 1 else 0.0)
    else:
        src = np.clip((np.arange(size_out) + 0.5) * size_in / size_out - 0.5, 0, size_in - 1)
    i0 = np.floor(src).astype(np.int32)
    return i0, np.minimum(i0 + 1, size_in - 1), (src - i0).astype(np.float32)


def resize_bilinear(x: jax.Array, height: int, width: int, align_corners: bool = False) -> jax.Array:
    """Bilinear resize of ``x`` (B, h, w, C) to (B, height, width, C), half-pixel centres by default.

    Half-pixel centres with clamped borders are PyTorch's ``align_corners=False``;
    ``align_corners=True`` maps the corner pixels onto each other, as PyTorch's; no
    antialiasing on downscaling, also as PyTorch. Two gathers and a blend per axis (memory-bound;
    ``jax.image.resize`` would multiply by dense (out x in) matrices instead). Same dtype out.
    """
    for axis, size in ((1, height), (2, width)):
        if x.shape[axis] == size:
            continue
        i0, i1, t = _linear_taps(x.shape[axis], size, align_corners)
        t = t.reshape((-1,) + (1,) * (x.ndim - axis - 1)).astype(x.dtype)
        x = jnp.take(x, i0, axis=axis) * (1 - t) + jnp.take(x, i1, axis=axis) * t
    return x


def spatial_softmax(scores: jax.Array) -> jax.Array:
    """Softmax over the positions of each image: (B, h, w) -> (B, h, w), each map sums to 1."""
    b, h, w = scores.shape
    return jax.nn.softmax(scores.reshape(b, h * w), axis=-1).reshape(b, h, w)
