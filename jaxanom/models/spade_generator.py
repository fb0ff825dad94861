"""MMF's "lighter" synthesizer (Table 4; docs/papers/mmf.md#spade-generator): a SPADE generator (Park et al. 2019 [34]).

    model = SPADEGenerator(num_classes=19, nf=8, upsamples=3)   # the CPU preset (paper: nf 64)
    out = model.apply(variables, semantic, train=False)          # {"image": (B, H, W, 3) in [0, 1]}

``semantic`` (B, H, W) int: classes in [0, C), 255 = unknown; H and W divisible by 2^n. It is
one-hot encoded with C + 1 channels (the last one for unknown) and conditions every SPADE layer.
The generator starts from the one-hot map resized (nearest) to H/2^n x W/2^n and a conv3x3, then
SPADE-ResBlocks, each after a nearest x2 upsampling except the first; level i (0 = coarsest) has
min(16, 2^(n-i)) * nf channels. The output is leaky_relu(0.2) -> conv3x3 -> 3 -> tanh, mapped to
r = (tanh + 1) / 2.

SPADE-ResBlock(x, s) = shortcut(x) + conv3x3(lrelu(SPADE(conv3x3(lrelu(SPADE(x, s))), s))), the
middle width min(in, out); the shortcut is conv1x1(SPADE(x, s)) (no bias) when the width changes,
else x. SPADE's parameter-free BatchNorm uses batch statistics with ``train=True``.
Unlike [34], no spectral norm and no VAE encoder (the synthesis is deterministic in Ŝ).
"""
from __future__ import annotations

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np

from jaxanom._validate import check_integer, check_rank, values_checked
from jaxanom.nn.layers import Dtype
from jaxanom.nn.spade import SPADE, one_hot_semantic, resize_nearest

UNKNOWN = 255


def check_semantic(semantic, num_classes: int, multiple: int) -> None:
    """ValueError unless ``semantic`` is (B, H, W) int with H, W divisible by ``multiple`` and
    (when on the host, ``_validate.values_checked``) values in [0, num_classes) or 255."""
    check_rank("semantic", semantic, 3, "(B, H, W)")
    check_integer("semantic", semantic)
    if semantic.shape[1] % multiple or semantic.shape[2] % multiple:
        raise ValueError(f"semantic: expected H and W divisible by {multiple}, got shape {semantic.shape}")
    if values_checked(semantic):
        values = np.asarray(semantic)
        bad = ~(((values >= 0) & (values < num_classes)) | (values == UNKNOWN))
        if bad.any():
            raise ValueError(f"semantic: expected classes in [0, {num_classes}) or {UNKNOWN}, "
                             f"got {np.unique(values[bad])[:5].tolist()}")


def _conv(features: int, kernel: int, dtype, name: str, bias: bool = True) -> nn.Conv:
    return nn.Conv(features, (kernel, kernel), padding=kernel // 2, use_bias=bias, dtype=dtype,
                   param_dtype=jnp.float32, name=name)


class SPADEResBlock(nn.Module):
    """``SPADEResBlock(features, hidden)(x, s, train) -> (B, h, w, features)``; see the module docstring."""

    features: int
    hidden: int = 128
    dtype: Dtype = jnp.float32

    @nn.compact
    def __call__(self, x: jax.Array, s: jax.Array, train: bool) -> jax.Array:
        middle = min(x.shape[-1], self.features)
        shortcut = x
        if x.shape[-1] != self.features:
            shortcut = _conv(self.features, 1, self.dtype, "shortcut", bias=False)(
                SPADE(self.hidden, self.dtype, name="spade_shortcut")(x, s, train))
        dx = _conv(middle, 3, self.dtype, "conv0")(
            nn.leaky_relu(SPADE(self.hidden, self.dtype, name="spade0")(x, s, train), 0.2))
        dx = _conv(self.features, 3, self.dtype, "conv1")(
            nn.leaky_relu(SPADE(self.hidden, self.dtype, name="spade1")(dx, s, train), 0.2))
        return shortcut + dx


class SPADEGenerator(nn.Module):
    """Ŝ -> r; see the module docstring. ``nf``: base width; ``upsamples``: n; ``hidden``: the
    SPADE layers' hidden width (128 in [34])."""

    num_classes: int
    nf: int = 64
    upsamples: int = 3
    hidden: int = 128
    dtype: Dtype = jnp.float32

    def check(self, semantic) -> None:
        """The input check of ``__call__`` (ValueError naming ``semantic``)."""
        check_semantic(semantic, self.num_classes, 2 ** self.upsamples)

    def width(self, level: int) -> int:
        return min(16, 2 ** (self.upsamples - level)) * self.nf

    @nn.compact
    def __call__(self, semantic: jax.Array, train: bool = False) -> dict[str, jax.Array]:
        scale = 2 ** self.upsamples
        self.check(semantic)
        s = one_hot_semantic(semantic, self.num_classes, self.dtype)
        _, height, width, _ = s.shape
        x = _conv(self.width(0), 3, self.dtype, "head")(resize_nearest(s, height // scale, width // scale))
        for level in range(self.upsamples + 1):
            if level:
                x = jnp.repeat(jnp.repeat(x, 2, axis=1), 2, axis=2)  # nearest x2
            x = SPADEResBlock(self.width(level), self.hidden, self.dtype, name=f"block{level}")(x, s, train)
        x = _conv(3, 3, self.dtype, "to_rgb")(nn.leaky_relu(x, 0.2))
        return {"image": (jnp.tanh(x.astype(jnp.float32)) + 1) / 2}
