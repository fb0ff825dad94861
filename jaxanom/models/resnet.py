"""ResNet backbones (He et al. 2016) for dense prediction: stage features, dilation, deep stem.

``ResNet(...)(images, train)`` returns the features of every stage, channels-last:
``{"stem": stride 4, "layer1": stride 4, "layer2": stride 8, "layer3": 16, "layer4": 32}``
(strides relative to the input, each side ``ceil(n / stride)``). With ``output_stride`` 16 the
last stage keeps stride 16 and uses dilation 2; with 8, ``layer3`` uses dilation 2 and
``layer4`` dilation 4 (every block of a dilated stage, as in DeepLab and SML's code).
Bottleneck blocks put the stride on the 3x3 convolution (torchvision's "v1.5").
"""
from __future__ import annotations

import dataclasses

import flax.linen as nn
import jax
import jax.numpy as jnp

from jaxanom.nn.layers import ConvBN, Dtype


@dataclasses.dataclass(frozen=True)
class ResNetSpec:
    """Depth and width of a ResNet: blocks per stage, block kind, stage width, stem kind and width.

    ``stem_width``: channels out of the stem (default ``width``); a deep stem's three convolutions
    have ``stem_width // 2``, ``stem_width // 2`` and ``stem_width`` channels.
    """

    stage_sizes: tuple[int, ...]
    bottleneck: bool
    width: int = 64
    deep_stem: bool = False
    stem_width: int | None = None


RESNETS: dict[str, ResNetSpec] = {
    "resnet18": ResNetSpec((2, 2, 2, 2), bottleneck=False),
    "resnet50": ResNetSpec((3, 4, 6, 3), bottleneck=True),
    "resnet101": ResNetSpec((3, 4, 23, 3), bottleneck=True),
    # The SML authors' trunk (their Resnet.py "ResNet3X3"): a deep stem 64, 64, 128.
    "resnet101_deep_stem": ResNetSpec((3, 4, 23, 3), bottleneck=True, deep_stem=True, stem_width=128),
    # For tests and demos: one basic block per stage, 8 channels in the first stage.
    "resnet_tiny": ResNetSpec((1, 1, 1, 1), bottleneck=False, width=8),
    # For the CPU experiments: ResNet-18's depth at a quarter of its width.
    "resnet18_quarter": ResNetSpec((2, 2, 2, 2), bottleneck=False, width=16),
}


def stage_dilations(output_stride: int) -> tuple[tuple[int, int], ...]:
    """(stride, dilation) of the first block of ``layer1 .. layer4`` for an output stride."""
    if output_stride == 32:
        return ((1, 1), (2, 1), (2, 1), (2, 1))
    if output_stride == 16:
        return ((1, 1), (2, 1), (2, 1), (1, 2))
    if output_stride == 8:
        return ((1, 1), (2, 1), (1, 2), (1, 4))
    raise ValueError(f"output_stride: expected 8, 16 or 32, got {output_stride!r}")


class BasicBlock(nn.Module):
    """Two 3x3 conv-BN layers and a shortcut (ResNet-18/34). Output channels = ``features``."""

    features: int
    stride: int = 1
    dilation: int = 1
    dtype: Dtype = jnp.float32

    @nn.compact
    def __call__(self, x: jax.Array, train: bool) -> jax.Array:
        y = ConvBN(self.features, 3, self.stride, self.dilation, dtype=self.dtype, name="conv1")(x, train)
        y = ConvBN(self.features, 3, 1, self.dilation, relu=False, dtype=self.dtype, name="conv2")(y, train)
        if x.shape[-1] != self.features or self.stride != 1:
            x = ConvBN(self.features, 1, self.stride, relu=False, dtype=self.dtype, name="downsample")(x, train)
        return nn.relu(x + y)


class Bottleneck(nn.Module):
    """1x1 -> 3x3 (stride, dilation) -> 1x1 conv-BN and a shortcut. Output = 4 * ``features``."""

    features: int
    stride: int = 1
    dilation: int = 1
    dtype: Dtype = jnp.float32

    @nn.compact
    def __call__(self, x: jax.Array, train: bool) -> jax.Array:
        out = 4 * self.features
        y = ConvBN(self.features, 1, dtype=self.dtype, name="conv1")(x, train)
        y = ConvBN(self.features, 3, self.stride, self.dilation, dtype=self.dtype, name="conv2")(y, train)
        y = ConvBN(out, 1, relu=False, dtype=self.dtype, name="conv3")(y, train)
        if x.shape[-1] != out or self.stride != 1:
            x = ConvBN(out, 1, self.stride, relu=False, dtype=self.dtype, name="downsample")(x, train)
        return nn.relu(x + y)


class ResNet(nn.Module):
    """ResNet trunk returning the stage features (no classifier).

    Args:
      spec: depth and width, e.g. ``RESNETS["resnet101"]``.
      output_stride: 8, 16 or 32; stride of ``layer4`` relative to the input.
      dtype: compute dtype; parameters stay float32.

    Call with images (B, H, W, 3) and ``train``; BatchNorm uses batch statistics and updates
    ``batch_stats`` when ``train`` is true, running averages otherwise. The deep stem is three
    3x3 convolutions (stem_width/2, stem_width/2, stem_width; "ResNet-C") instead of one 7x7.
    The max-pool pads with -inf, as PyTorch's ``MaxPool2d(3, 2, padding=1)``.
    """

    spec: ResNetSpec
    output_stride: int = 32
    dtype: Dtype = jnp.float32

    @nn.compact
    def __call__(self, images: jax.Array, train: bool = False) -> dict[str, jax.Array]:
        spec = self.spec
        stem_width = spec.stem_width or spec.width
        x = images.astype(self.dtype)
        if spec.deep_stem:
            x = ConvBN(stem_width // 2, 3, 2, dtype=self.dtype, name="stem1")(x, train)
            x = ConvBN(stem_width // 2, 3, 1, dtype=self.dtype, name="stem2")(x, train)
            x = ConvBN(stem_width, 3, 1, dtype=self.dtype, name="stem3")(x, train)
        else:
            x = ConvBN(stem_width, 7, 2, dtype=self.dtype, name="stem")(x, train)
        x = nn.max_pool(x, (3, 3), strides=(2, 2), padding=((1, 1), (1, 1)))
        features = {"stem": x}
        block = Bottleneck if spec.bottleneck else BasicBlock
        for i, (blocks, (stride, dilation)) in enumerate(
            zip(spec.stage_sizes, stage_dilations(self.output_stride))
        ):
            for j in range(blocks):
                x = block(
                    spec.width * 2**i,
                    stride=stride if j == 0 else 1,
                    dilation=dilation,
                    dtype=self.dtype,
                    name=f"layer{i + 1}_{j}",
                )(x, train)
            features[f"layer{i + 1}"] = x
        return features
