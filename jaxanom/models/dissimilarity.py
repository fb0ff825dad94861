"""MMF's dissimilarity network (§III-A4; SynBoost's ``DissimNetPrior`` [29]): image vs resynthesis.

::

    model = DissimilarityNet(num_classes=19)                  # the paper's widths
    out = model.apply(variables, images, resynthesis=r, semantic=s, semantic_depth=s_d,
                      uncertainty=u, train=False)             # {"logits": (B, H, W, 2)}

Inputs (H, W divisible by 8): ``images``, ``resynthesis`` (B, H, W, 3) ImageNet-normalised;
``semantic``, ``semantic_depth`` (B, H, W) int (Ŝ of the segmenter and Ŝ_D of the RGB-D net;
255 = unknown), one-hot encoded here with C + 1 channels; ``uncertainty`` (B, H, W, k) the
assistant maps (MMF: [A, D]). ``use_depth=False`` drops Ŝ_D and ``uncertainty_channels=0`` drops
the assistant maps (the plain resynthesis baseline); ``extra_inputs`` lists what is read.

Encoders: E1, a VGG16 shared by image and resynthesis, tapped after relu1_2, relu2_2, relu3_3,
relu4_3 (strides 1, 2, 4, 8); E2 (separate weights for Ŝ, Ŝ_D and the assistant maps): conv7x7
+ ReLU, then three stride-2 conv3x3 + ReLU, tapped after each. Level l fuses
h_l = conv1x1([E1_l(x), E1_l(r), E2_l(Ŝ), E2_l(Ŝ_D)]), multiplies it point by point with
E2_l(u), then (``correlation``) prepends the channel sum_c E1_l(x) E1_l(r), as SynBoost's
``DissimNetPrior`` does (after the product: with E2(u) = 0, e.g. u = 0 at initialisation, the
output still depends on x and r). Decoder (four blocks, as SynBoost's): conv3x3 + SELU, SPADE block conditioned
on Ŝ, transposed conv 2x2 stride 2 (the last block ends with a 1x1 conv to 2 classes instead),
each later block reading the previous output concatenated with h_l. a = softmax(logits)[..., 1].
``width`` scales every width (1/8 is the CPU preset). E1 is trained from scratch here (no ImageNet VGG weights at hand).
"""
from __future__ import annotations

import flax.linen as nn
import jax
import jax.numpy as jnp

from jaxanom.nn.layers import Dtype
from jaxanom.nn.spade import SPADEBlock, one_hot_semantic

_VGG16 = ((64, 64), (128, 128), (256, 256, 256), (512, 512, 512))  # the first four stages


def _conv(features: int, kernel: int, dtype, name: str, stride: int = 1) -> nn.Conv:
    return nn.Conv(features, (kernel, kernel), strides=stride, padding=kernel // 2, dtype=dtype,
                   param_dtype=jnp.float32, name=name)


class _VGGTaps(nn.Module):
    """VGG16 stages 1-4 (ReLU after each conv, 2x2 max-pool between stages) -> 4 taps."""

    width: float
    dtype: Dtype

    @nn.compact
    def __call__(self, x: jax.Array) -> list[jax.Array]:
        taps = []
        for i, stage in enumerate(_VGG16):
            if i:
                x = nn.max_pool(x, (2, 2), strides=(2, 2))
            for j, features in enumerate(stage):
                x = nn.relu(_conv(max(1, round(features * self.width)), 3, self.dtype, f"conv{i + 1}_{j + 1}")(x))
            taps.append(x)
        return taps


class _MapEncoder(nn.Module):
    """E2: conv7x7 + ReLU, then three conv3x3 stride 2 + ReLU; widths ``features``; 4 taps."""

    features: tuple[int, ...]
    dtype: Dtype

    @nn.compact
    def __call__(self, x: jax.Array) -> list[jax.Array]:
        taps = []
        for i, features in enumerate(self.features):
            x = nn.relu(_conv(features, 7 if i == 0 else 3, self.dtype, f"conv{i}", stride=1 if i == 0 else 2)(x))
            taps.append(x)
        return taps


class DissimilarityNet(nn.Module):
    """See the module docstring. ``num_classes``: C of the semantic maps."""

    num_classes: int
    uncertainty_channels: int = 2
    use_depth: bool = True
    correlation: bool = True
    width: float = 1.0
    dtype: Dtype = jnp.float32

    @property
    def extra_inputs(self) -> tuple[str, ...]:
        """Batch entries the train loop passes as keyword arguments."""
        return (("resynthesis", "semantic") + (("semantic_depth",) if self.use_depth else ())
                + (("uncertainty",) if self.uncertainty_channels else ()))

    def _w(self, features: int) -> int:
        return max(1, round(features * self.width))

    def _check(self, images, resynthesis, semantic, semantic_depth, uncertainty) -> None:
        b, h, w = images.shape[:3]
        if images.ndim != 4 or images.shape[-1] != 3 or h % 8 or w % 8:
            raise ValueError(f"images: expected (B, H, W, 3) with H, W divisible by 8, got {images.shape}")
        expected = {"resynthesis": (resynthesis, (b, h, w, 3)), "semantic": (semantic, (b, h, w))}
        if self.use_depth:
            expected["semantic_depth"] = (semantic_depth, (b, h, w))
        if self.uncertainty_channels:
            expected["uncertainty"] = (uncertainty, (b, h, w, self.uncertainty_channels))
        for name, (value, shape) in expected.items():
            if value is None or value.shape != shape:
                raise ValueError(f"{name}: expected shape {shape}, got {None if value is None else value.shape}")

    def _one_hot(self, labels: jax.Array) -> jax.Array:
        return one_hot_semantic(labels, self.num_classes, self.dtype)

    @nn.compact
    def __call__(self, images: jax.Array, resynthesis: jax.Array, semantic: jax.Array,
                 semantic_depth: jax.Array | None = None, uncertainty: jax.Array | None = None,
                 train: bool = False) -> dict[str, jax.Array]:
        self._check(images, resynthesis, semantic, semantic_depth, uncertainty)
        dt = self.dtype
        vgg = _VGGTaps(self.width, dt, name="vgg")
        fx, fr = vgg(images.astype(dt)), vgg(resynthesis.astype(dt))
        s = self._one_hot(semantic)
        maps = [_MapEncoder(tuple(self._w(f) for f in (32, 64, 128, 256)), dt, name="semantic_encoder")(s)]
        if self.use_depth:
            sd = self._one_hot(semantic_depth)
            maps.append(_MapEncoder(tuple(self._w(f) for f in (32, 64, 128, 256)), dt, name="depth_encoder")(sd))
        prior = None
        if self.uncertainty_channels:
            prior = _MapEncoder(tuple(self._w(f) for f in (64, 128, 256, 512)), dt, name="prior_encoder")(
                uncertainty.astype(dt))
        fused = []
        for level, features in enumerate((64, 128, 256, 512)):
            parts = [fx[level], fr[level]] + [m[level] for m in maps]
            h = _conv(self._w(features), 1, dt, f"fuse{level}")(jnp.concatenate(parts, axis=-1))
            if prior is not None:
                h = h * prior[level]
            if self.correlation:  # after the product, as SynBoost: it reaches the decoder even where E2(u) = 0
                h = jnp.concatenate([(fx[level] * fr[level]).sum(axis=-1, keepdims=True), h], axis=-1)
            fused.append(h)
        hidden = self._w(128)
        x = fused[3]
        for block, features in enumerate((256, 256, 128, 64)):
            if block:
                x = jnp.concatenate([x, fused[3 - block]], axis=-1)
            x = nn.selu(_conv(self._w(features), 3, dt, f"decoder{block}")(x))
            x = SPADEBlock(hidden, dt, name=f"spade{block}")(x, s, train)
            if block < 3:
                x = nn.ConvTranspose(self._w(features), (2, 2), strides=(2, 2), dtype=dt, param_dtype=jnp.float32,
                                     name=f"up{block}")(x)
        logits = _conv(2, 1, dt, "classifier")(x)
        return {"logits": logits.astype(jnp.float32)}


def anomaly_probability(logits: jax.Array) -> jax.Array:
    """a = softmax(logits)[..., 1]: (..., 2) -> (...), the dissimilarity score."""
    return jax.nn.softmax(logits.astype(jnp.float32), axis=-1)[..., 1]
