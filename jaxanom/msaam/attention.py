"""Multi-scale adaptive attention module (MSAAM), Eqs. 1-6 and 8-12 of the MSAAM paper (docs/papers/sml-cudam-msaam.md).

Input: encoder features F (B, h, w, C). Three branches, each giving features of F's shape:

* Scale (Eqs. 1-2): ``A = softmax_{h,w}( sum_i w_i * up(conv_i(P_i(F))) )``, P_i an adaptive
  average pooling to ``bins[i] x bins[i]`` cells (PyTorch's cell boundaries), conv_i a 1x1
  convolution to one channel, up a bilinear resize back to (h, w), w_i learnable level weights
  (init 1/N). The softmax runs over all positions of each image, so A sums to 1 (the paper's
  "constant-sum constraint"); ``f_sc = F + F * A``. Each conv_i is applied before its pooling
  (identical maths, both are linear and the pooling weights sum to 1; one matmul for all levels).
* Spatial (Eq. 3): a non-local block with embedded-Gaussian relation,
  ``y_i = sum_j exp(theta_i . phi_j) g_j / sum_j exp(theta_i . phi_j)`` (theta, phi, g: 1x1
  convolutions to C // ``reduction`` channels), then a 7x7 convolution to one channel and a
  sigmoid: the map ``m_sp`` (B, h, w); ``f_sp = F * m_sp``.
* Channel (Eq. 4): ``f_c = F * sigmoid(W3 relu(W2 relu(W1 gap(F))) + b3)``, W1 and W2 without
  bias (C -> C // ``channel_reduction`` -> same), W3 back to C with the bias b3.

Fusion (Eqs. 5-6): ``x = W_sc gap(f_sc) + W_sp gap(f_sp) + W_c gap(f_c)``; a GRU cell, started
from a zero state, is stepped ``gru_steps`` times (default 1) on x; ``alpha = softmax(W_h h)``
(B, 3) weighs the branches: output ``alpha_sc f_sc + alpha_sp f_sp + alpha_c f_c``.

Highlight maps (Eqs. 8-11, for visualisation): ScAH = alpha_sc * mean_c f_sc, SpAH = alpha_sp *
m_sp, CAH = alpha_c * mean_c f_c (channel means rather than the paper's sums: the same picture
up to the factor C, which the paper's normalisation for display removes) and, literally as
Eq. 11, CoAH = alpha_sc ScAH + alpha_sp SpAH + alpha_c CAH. ``best_rectangle`` is Eq. 12.

Registered as the attention module ``"msaam"`` (``jaxanom.models.attention``): it sits at the
end of a segmenter's encoder (DeepLabV3+'s ``"encoder"`` position, before ASPP; ERFNet's and
ESPNet's ``"deep"`` one, before the decoder) and adds the outputs listed under ``MSAAMAttention``.
"""
from __future__ import annotations

from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np

from jaxanom.models.attention import AttentionModule, register
from jaxanom.nn.layers import resize_bilinear, spatial_softmax


def adaptive_pool_matrix(size: int, bins: int) -> np.ndarray:
    """(bins, size) averaging matrix of PyTorch's adaptive average pooling along one axis.

    Cell i covers ``[floor(i * size / bins), ceil((i + 1) * size / bins))``.
    """
    matrix = np.zeros((bins, size), np.float32)
    for i in range(bins):
        start, stop = (i * size) // bins, -((-(i + 1) * size) // bins)
        matrix[i, start:stop] = 1.0 / (stop - start)
    return matrix


class MSAAMAttention(nn.Module):
    """MSAAM block; see the module docstring for the equations.

    Attributes:
      bins: pyramid levels of the scale branch (PSPNet's 1, 2, 3, 6).
      reduction: C // reduction channels for the non-local embeddings.
      channel_reduction: C // channel_reduction hidden channels of the channel branch.
      gru_features: size of the GRU's hidden state.
      gru_steps: GRU steps on the (constant) branch descriptor.
      dtype: compute dtype of the features; maps and weights are float32.

    ``__call__(f)`` with f (B, h, w, C) returns ``(features, outputs)``: features (B, h, w, C)
    in ``dtype`` and a dict of float32 arrays: ``"attention"`` (A, (B, h, w), sums to 1 per
    image), ``"branch_weights"`` ((B, 3): scale, spatial, channel; rows sum to 1),
    ``"highlight_scale"``, ``"highlight_spatial"``, ``"highlight_channel"``,
    ``"highlight_combined"`` (B, h, w).
    """

    bins: tuple[int, ...] = (1, 2, 3, 6)
    reduction: int = 8
    channel_reduction: int = 16
    gru_features: int = 64
    gru_steps: int = 1
    dtype: Any = jnp.float32

    @nn.compact
    def __call__(self, f: jax.Array) -> tuple[jax.Array, dict[str, jax.Array]]:
        b, h, w, channels = f.shape
        f = f.astype(self.dtype)
        dense = lambda n, name, bias=True: nn.Dense(  # noqa: E731
            n, use_bias=bias, dtype=self.dtype, param_dtype=jnp.float32, name=name
        )

        # Scale branch, Eqs. 1-2.
        level_scores = dense(len(self.bins), "scale_convs")(f).astype(jnp.float32)
        level_weights = self.param(
            "scale_level_weights",
            nn.initializers.constant(1.0 / len(self.bins)),
            (len(self.bins),),
            jnp.float32,
        )
        summed = jnp.zeros((b, h, w), jnp.float32)
        for i, n in enumerate(self.bins):
            pooled = jnp.einsum(
                "ih,bhw,jw->bij",
                adaptive_pool_matrix(h, n),
                level_scores[..., i],
                adaptive_pool_matrix(w, n),
            )
            up = resize_bilinear(pooled[..., None], h, w)[..., 0]
            summed = summed + level_weights[i] * up
        scale_map = spatial_softmax(summed)
        f_sc = f + f * scale_map[..., None].astype(self.dtype)

        # Spatial branch, Eq. 3.
        inner = max(channels // self.reduction, 1)
        theta, phi, g = (dense(inner, name)(f).reshape(b, h * w, 1, inner) for name in ("theta", "phi", "g"))
        related = jax.nn.dot_product_attention(theta, phi, g, scale=1.0).reshape(b, h, w, inner)
        spatial_logits = nn.Conv(
            1, (7, 7), padding=((3, 3), (3, 3)), dtype=self.dtype, param_dtype=jnp.float32,
            name="spatial_conv",
        )(related)
        spatial_map = jax.nn.sigmoid(spatial_logits[..., 0].astype(jnp.float32))
        f_sp = f * spatial_map[..., None].astype(self.dtype)

        # Channel branch, Eq. 4.
        hidden = max(channels // self.channel_reduction, 1)
        d = f.astype(jnp.float32).mean(axis=(1, 2)).astype(self.dtype)
        d = nn.relu(dense(hidden, "channel_w1", bias=False)(d))
        d = nn.relu(dense(hidden, "channel_w2", bias=False)(d))
        gate = jax.nn.sigmoid(dense(channels, "channel_w3")(d).astype(jnp.float32))
        f_c = f * gate[:, None, None, :].astype(self.dtype)

        # Fusion, Eqs. 5-6.
        branches = (f_sc, f_sp, f_c)
        x = sum(
            dense(self.gru_features, f"gru_in_{name}", bias=False)(
                br.astype(jnp.float32).mean(axis=(1, 2)).astype(self.dtype)
            ).astype(jnp.float32)
            for name, br in zip(("scale", "spatial", "channel"), branches)
        )
        cell = nn.GRUCell(self.gru_features, param_dtype=jnp.float32, name="gru")
        state = jnp.zeros((b, self.gru_features), jnp.float32)
        for _ in range(self.gru_steps):
            state, _ = cell(state, x)
        weights = jax.nn.softmax(
            nn.Dense(3, param_dtype=jnp.float32, name="branch_logits")(state), axis=-1
        )
        fused = sum(weights[:, i, None, None, None].astype(self.dtype) * br for i, br in enumerate(branches))

        # Highlight maps, Eqs. 8-11.
        a_sc, a_sp, a_c = (weights[:, i, None, None] for i in range(3))
        scale_hl = a_sc * f_sc.astype(jnp.float32).mean(-1)
        spatial_hl = a_sp * spatial_map
        channel_hl = a_c * f_c.astype(jnp.float32).mean(-1)
        outputs = {
            "attention": scale_map,
            "branch_weights": weights,
            "highlight_scale": scale_hl,
            "highlight_spatial": spatial_hl,
            "highlight_channel": channel_hl,
            "highlight_combined": a_sc * scale_hl + a_sp * spatial_hl + a_c * channel_hl,
        }
        return fused, outputs


def best_rectangle(highlight: jax.Array, height: int, width: int) -> tuple[jax.Array, jax.Array]:
    """Eq. 12: the ``height x width`` window of highest average weight AW in one map (h, w).

    Without a size the best "rectangle" is a single pixel, so the size is given. Returns
    ``(corner, average)``: corner int32 (4,) = (y1, x1, y2, x2), inclusive as in Eq. 12 (the
    first best window in row-major order on ties), and the average, float32 scalar.
    """
    if highlight.ndim != 2:
        raise ValueError(f"highlight: expected one map (h, w), got shape {highlight.shape}")
    h, w = highlight.shape
    if not (1 <= height <= h and 1 <= width <= w):
        raise ValueError(f"height, width: expected 1..{h} and 1..{w}, got {height} and {width}")
    integral = jnp.pad(highlight.astype(jnp.float32).cumsum(0).cumsum(1), ((1, 0), (1, 0)))
    sums = (
        integral[height:, width:]
        - integral[: h - height + 1, width:]
        - integral[height:, : w - width + 1]
        + integral[: h - height + 1, : w - width + 1]
    )
    flat = jnp.argmax(sums)
    y1, x1 = flat // sums.shape[1], flat % sums.shape[1]
    corner = jnp.stack([y1, x1, y1 + height - 1, x1 + width - 1]).astype(jnp.int32)
    return corner, sums.reshape(-1)[flat] / (height * width)


register(AttentionModule("msaam", MSAAMAttention, lambda module, features, taps: module(features), positions=("encoder", "deep"),
                         objective="msaam"))
