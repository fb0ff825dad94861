"""Attention feature complementarity (MMF Eq. 5; RFNet's AFC): fuse RGB and depth features.

    F = O * sigmoid(W1 GAP(O) + b1) + Dp * sigmoid(W2 GAP(Dp) + b2)

``O``, ``Dp``: (B, h, w, C); GAP is the global average over (h, w); W1, W2 are C x C 1x1
convolutions with bias (on a 1x1 map: dense layers); the channel weights broadcast over (h, w)
(the paper's "outer product", read as in docs/papers/mmf.md#afc-fusion).
"""
from __future__ import annotations

import flax.linen as nn
import jax
import jax.numpy as jnp

from jaxanom.nn.layers import Dtype


class AFC(nn.Module):
    """``AFC()(rgb, depth) -> fused``, all (B, h, w, C); see the module docstring (Eq. 5)."""

    dtype: Dtype = jnp.float32

    @nn.compact
    def __call__(self, rgb: jax.Array, depth: jax.Array) -> jax.Array:
        if rgb.shape != depth.shape or rgb.ndim != 4:
            raise ValueError(f"rgb, depth: expected equal shapes (B, h, w, C), got {rgb.shape}, {depth.shape}")
        channels = rgb.shape[-1]

        def gate(x, name):
            pooled = x.astype(jnp.float32).mean(axis=(1, 2), keepdims=True).astype(self.dtype)
            return nn.sigmoid(nn.Dense(channels, dtype=self.dtype, param_dtype=jnp.float32, name=name)(pooled))

        return rgb * gate(rgb, "rgb_gate") + depth * gate(depth, "depth_gate")
