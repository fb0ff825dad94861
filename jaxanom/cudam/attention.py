"""Curiosity-driven attention module (CuDAM), Eqs. 1-3 of the CuDAM paper (docs/papers/sml-cudam-msaam.md).

Given decoder features ``F_a`` (B, h, w, C') and two encoder stages ``F_low``, ``F_mid``:

* Eq. 1  ``M_att = softmax_{h,w}( f([mean_c F_a ; max_c F_a]) )``: channel-wise average and max
  pooling (CBAM), one ``k x k`` convolution to one channel, softmax over all h*w positions of
  each image, so every image's map sums to 1. Computed in float32: its values are ~1/(h*w).
* Eq. 2  ``F_sc = eta(concat(F_low, F_mid, F_a))``: one 1x1 convolution to C' channels of the
  three maps brought to F_a's size by bilinear resizing. We apply each input's slice of the
  single 1x1 kernel at the input's own size and resize afterwards: the same result (resizing
  is linear and its weights sum to 1), but the 512-channel ``F_mid`` is projected at its own,
  four times smaller size and no concatenated tensor is built.
* Eq. 3  ``F = alpha * M_att * (F_a + F_sc) + F_a`` with a learnable scalar ``alpha``
  initialised to 0, so an untrained module returns ``F_a`` exactly.

Deviation (off by default, ``gate="scale_free"``): Eq. 3 with ``h * w * M_att`` in place of
``M_att``. The map sums to 1, so its values are ~1 / (h w) and ``alpha * M_att`` stays ~1e-3 or
less after hundreds of AdamW steps (alpha moves ~lr per step): the attention barely touches the
features. Multiplied by h * w the map averages 1 per position, so alpha means the same at every
map size ("alpha = 1: the average position's features are doubled"). The attention map returned
(and used by Eqs. 4, 7, 10) is ``M_att`` itself in both cases.

Registered as the attention module ``"cudam"`` (``jaxanom.models.attention``): at a segmenter's
position it gates the features there (``F_a``) with ``F_low`` and ``F_mid`` the segmenter's taps
``"low"`` and ``"mid"``, and adds the output ``"attention"`` (``M_att``). Its positions: ``"deep"``
(the paper's best, Table V: DeepLabV3+'s first decoder convolution, ERFNet's and ESPNet's encoder
output), ``"surface"`` (DeepLabV3+'s last decoder feature, our earlier reading) and ``"output"`` (the
logits at input size, the paper's surface position); its option ``gate`` (above).
"""
from __future__ import annotations

from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp

from jaxanom.models.attention import AttentionModule, register
from jaxanom.nn.layers import resize_bilinear, spatial_softmax

GATES = ("paper", "scale_free")


class CuDAMAttention(nn.Module):
    """CuDAM attention block (Eqs. 1-3).

    Attributes:
      kernel_size: size of the convolution ``f`` of Eq. 1 (7, as CBAM's spatial attention).
      dtype: compute dtype of the features; the attention map is always float32.
      gate: ``"paper"`` (Eq. 3 as printed) or ``"scale_free"`` (``alpha * h * w * M_att``, see above).

    ``__call__(f_a, f_low, f_mid)`` with f_a (B, h, w, C'), f_low (B, h1, w1, C1), f_mid
    (B, h2, w2, C2) returns ``(features, attention)``: features (B, h, w, C') in ``dtype``
    (Eq. 3) and the attention map ``M_att`` (B, h, w) float32, summing to 1 per image.
    Parameters: ``attention_conv`` (k*k*2 + 1), ``fusion_kernel`` ((C1+C2+C') x C'),
    ``fusion_bias`` (C') and ``alpha`` (scalar, init 0).
    """

    kernel_size: int = 7
    dtype: Any = jnp.float32
    gate: str = "paper"

    def __post_init__(self):
        if self.gate not in GATES:
            raise ValueError(f"gate: expected one of {GATES}, got {self.gate!r}")
        super().__post_init__()

    @nn.compact
    def __call__(
        self, f_a: jax.Array, f_low: jax.Array, f_mid: jax.Array
    ) -> tuple[jax.Array, jax.Array]:
        b, h, w, channels = f_a.shape
        # Eq. 1, in float32.
        f32 = f_a.astype(jnp.float32)
        pooled = jnp.stack([f32.mean(-1), channel_max(f32)], axis=-1)
        pad = self.kernel_size // 2
        scores = nn.Conv(
            1,
            (self.kernel_size, self.kernel_size),
            padding=((pad, pad), (pad, pad)),
            dtype=jnp.float32,
            param_dtype=jnp.float32,
            name="attention_conv",
        )(pooled)[..., 0]
        attention = spatial_softmax(scores)

        # Eq. 2: one 1x1 convolution over concat(F_low, F_mid, F_a), applied slice by slice.
        parts = (f_low, f_mid, f_a)
        fan_in = sum(p.shape[-1] for p in parts)
        kernel = self.param(
            "fusion_kernel", nn.initializers.lecun_normal(), (fan_in, channels), jnp.float32
        ).astype(self.dtype)
        bias = self.param("fusion_bias", nn.initializers.zeros, (channels,), jnp.float32)
        f_sc = bias.astype(self.dtype)
        start = 0
        for part in parts:
            stop = start + part.shape[-1]
            projected = jnp.einsum("bhwc,cd->bhwd", part.astype(self.dtype), kernel[start:stop])
            f_sc = f_sc + resize_bilinear(projected, h, w)
            start = stop

        # Eq. 3.
        alpha = self.param("alpha", nn.initializers.zeros, (), jnp.float32)
        scale = float(h * w) if self.gate == "scale_free" else 1.0
        gate = (alpha * scale * attention)[..., None].astype(self.dtype)
        features = gate * (f_a.astype(self.dtype) + f_sc) + f_a.astype(self.dtype)
        return features, attention


@jax.custom_jvp
def channel_max(x: jax.Array) -> jax.Array:
    """Max over the last axis, (..., C) -> (...), differentiated as JAX differentiates a max.

    The derivative is JAX's: the tangent averaged over the channels equal to the max (ties
    share it), and at XLA's default optimisation level the gradients are bitwise those of
    ``x.max(-1)``. The rule is written out to count the tied channels in integers: JAX's own
    sums the comparison as float32, and XLA:CPU (jaxlib 0.10.2) at optimisation level 0
    miscompiles that fused comparison and sum in the tiny DeepLab's train step: a third of
    the positions counted 0 though one channel equalled the max, and the gradient was 0 / 0.
    """
    return x.max(-1)


@channel_max.defjvp
def _channel_max_jvp(primals, tangents):
    (x,), (dx,) = primals, tangents
    top = x.max(-1)
    is_top = x == top[..., None]
    return top, jnp.sum(dx * is_top, -1) / jnp.sum(is_top, -1)


def _attend(module: CuDAMAttention, features, taps):
    features, attention = module(features, taps["low"], taps["mid"])
    return features, {"attention": attention}


register(AttentionModule(
    "cudam", CuDAMAttention, _attend, positions=("deep", "surface", "output"), options={"gate": "paper"},
    objective="cudam", method_inputs=frozenset({"attention"}),
    recorded_as={"position": "cudam_position", "gate": "cudam_gate"}))
