"""Adaptive average pooling with PyTorch's bins, and SwiftNet's spatial pyramid pooling (RFNet).

Bin i of n inputs into g outputs covers [floor(i n / g), ceil((i + 1) n / g)), as
``torch.nn.functional.adaptive_avg_pool2d``; bins may overlap when g does not divide n.
"""
from __future__ import annotations

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np

from jaxanom.nn.layers import ConvBN, Dtype, resize_bilinear


def pooling_matrix(size_in: int, size_out: int) -> np.ndarray:
    """(size_out, size_in) float32: row i averages input bin i (PyTorch's adaptive bins)."""
    matrix = np.zeros((size_out, size_in), np.float32)
    for i in range(size_out):
        start, stop = (i * size_in) // size_out, -((-(i + 1) * size_in) // size_out)
        matrix[i, start:stop] = 1.0 / (stop - start)
    return matrix


def adaptive_avg_pool(x: jax.Array, out_hw: tuple[int, int]) -> jax.Array:
    """(B, h, w, C) -> (B, oh, ow, C) adaptive average pooling (separable: rows, then columns)."""
    rows = jnp.asarray(pooling_matrix(x.shape[1], out_hw[0]), x.dtype)
    cols = jnp.asarray(pooling_matrix(x.shape[2], out_hw[1]), x.dtype)
    return jnp.einsum("ih,bhwc,jw->bijc", rows, x, cols)


class SpatialPyramidPooling(nn.Module):
    """SwiftNet SPP: 1x1 bottleneck, pooled branches on grids g x max(1, round(g w / h)), 1x1 fuse.

    (B, h, w, C) -> (B, h, w, ``features``); each branch is pooled, 1x1 conv-BN-ReLU to
    ``branch_features`` and resized bilinearly back to (h, w).
    """

    features: int = 128
    branch_features: int = 32
    grids: tuple[int, ...] = (8, 4, 2, 1)
    dtype: Dtype = jnp.float32

    @nn.compact
    def __call__(self, x: jax.Array, train: bool) -> jax.Array:
        height, width = x.shape[1:3]
        x = ConvBN(self.features, 1, dtype=self.dtype, name="bottleneck")(x, train)
        levels = [x]
        for g in self.grids:
            pooled = adaptive_avg_pool(x, (g, max(1, round(g * width / height))))
            pooled = ConvBN(self.branch_features, 1, dtype=self.dtype, name=f"grid{g}")(pooled, train)
            levels.append(resize_bilinear(pooled, height, width))
        return ConvBN(self.features, 1, dtype=self.dtype, name="fuse")(jnp.concatenate(levels, axis=-1), train)
