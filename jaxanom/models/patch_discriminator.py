"""The SPADE generator's critic (docs/papers/mmf.md#spade-generator): a conditional multi-scale PatchGAN (pix2pixHD / [34]).

::

    model = MultiscaleDiscriminator(num_classes=19, nf=8)
    out = model.apply(variables, image, semantic)   # {"logits": [(B, h_k, w_k, 1)] * scales,
                                                     #  "features": [[(B, h, w, c)] * layers] * scales}

``image`` (B, H, W, 3) float in [0, 1] (a photo or a resynthesis; mapped to [-1, 1] here);
``semantic`` (B, H, W) int, 255 = unknown, one-hot with C + 1 channels and concatenated to the
image. Scale k sees the input average-pooled k times (3x3, stride 2, padding 1, padding not
counted). Each PatchGAN: conv4x4 stride 2 (nf) + LeakyReLU(0.2), then ``layers - 1`` conv4x4
(widths doubling, at most 8 nf; stride 2 except the last, stride 1) + parameter-free instance
norm + LeakyReLU(0.2), then conv4x4 stride 1 to one logit per patch; padding 2 throughout.
``features`` are the LeakyReLU outputs (the feature-matching taps), ``logits`` the last conv.
Unlike [34], no spectral norm.
"""
from __future__ import annotations

import flax.linen as nn
import jax
import jax.numpy as jnp

from jaxanom.models.spade_generator import check_semantic
from jaxanom.nn.layers import Dtype
from jaxanom.nn.spade import one_hot_semantic


def _conv(features: int, stride: int, dtype, name: str) -> nn.Conv:
    return nn.Conv(features, (4, 4), strides=stride, padding=2, dtype=dtype, param_dtype=jnp.float32, name=name)


class PatchDiscriminator(nn.Module):
    """One scale: ``(x (B, H, W, K)) -> (logits, [features])``; see the module docstring."""

    nf: int = 64
    layers: int = 4
    dtype: Dtype = jnp.float32

    @nn.compact
    def __call__(self, x: jax.Array) -> tuple[jax.Array, list[jax.Array]]:
        features = []
        for i in range(self.layers):
            x = _conv(min(2 ** i, 8) * self.nf, 1 if i == self.layers - 1 else 2, self.dtype, f"conv{i}")(x)
            if i:
                x = nn.InstanceNorm(use_bias=False, use_scale=False, epsilon=1e-5, dtype=self.dtype, name=f"norm{i}")(x)
            x = nn.leaky_relu(x, 0.2)
            features.append(x)
        return _conv(1, 1, self.dtype, "logits")(x).astype(jnp.float32), features


class MultiscaleDiscriminator(nn.Module):
    """``scales`` PatchGANs on ever coarser copies of [one_hot(Ŝ), 2 image - 1]."""

    num_classes: int
    nf: int = 64
    layers: int = 4
    scales: int = 2
    dtype: Dtype = jnp.float32

    @nn.compact
    def __call__(self, image: jax.Array, semantic: jax.Array) -> dict[str, list]:
        if image.ndim != 4 or image.shape[-1] != 3 or not jnp.issubdtype(image.dtype, jnp.floating):
            raise ValueError(f"image: expected float (B, H, W, 3), got {image.dtype} {image.shape}")
        check_semantic(semantic, self.num_classes, 1)
        if semantic.shape != image.shape[:3]:
            raise ValueError(f"semantic: expected shape {image.shape[:3]} (the image's), got {semantic.shape}")
        x = jnp.concatenate([one_hot_semantic(semantic, self.num_classes, self.dtype),
                             (2 * image - 1).astype(self.dtype)], axis=-1)
        logits, features = [], []
        for k in range(self.scales):
            if k:
                x = nn.avg_pool(x, (3, 3), strides=(2, 2), padding=((1, 1), (1, 1)), count_include_pad=False)
            out, taps = PatchDiscriminator(self.nf, self.layers, self.dtype, name=f"scale{k}")(x)
            logits.append(out)
            features.append(taps)
        return {"logits": logits, "features": features}
