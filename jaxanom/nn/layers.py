"""Building blocks shared by the backbone and the heads: conv + BatchNorm (+ ReLU), bilinear resize.

Mixed precision: parameters are always float32 (``param_dtype``); ``dtype`` is the compute dtype
(e.g. ``jnp.bfloat16``). BatchNorm statistics are reduced in float32 whatever ``dtype`` is.
"""
from __future__ import annotations

from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp

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
        pad = self.dilation * (self.kernel_size - 1) // 2
        x = nn.Conv(
            self.features,
            (self.kernel_size, self.kernel_size),
            strides=self.stride,
            padding=((pad, pad), (pad, pad)),
            kernel_dilation=self.dilation,
            use_bias=False,
            dtype=self.dtype,
            param_dtype=jnp.float32,
            kernel_init=nn.initializers.variance_scaling(2.0, "fan_out", "normal"),
            name="conv",
        )(x)
        x = nn.BatchNorm(
            use_running_average=not train,
            momentum=BN_MOMENTUM,
            epsilon=BN_EPSILON,
            dtype=self.dtype,
            param_dtype=jnp.float32,
            name="bn",
        )(x)
        return nn.relu(x) if self.relu else x


def resize_bilinear(x: jax.Array, height: int, width: int) -> jax.Array:
    """Bilinear resize of ``x`` (B, h, w, C) to (B, height, width, C), half-pixel centres.

    Half-pixel centres are PyTorch's ``align_corners=False``; no antialiasing, so a
    downscale samples like PyTorch's ``interpolate`` does. Same dtype out as in.
    """
    if x.shape[1:3] == (height, width):
        return x
    shape = (x.shape[0], height, width, x.shape[3])
    return jax.image.resize(x, shape, "bilinear", antialias=False).astype(x.dtype)
