"""RGB-D segmenter of MMF's depth module (§III-A3; RFNet [9]): two ResNet trunks fused by AFC.

    model = RGBDNet(num_classes=19, backbone="resnet18")
    out = model.apply(variables, images, depth=depth, train=False)   # {"logits": (B, H, W, C)}

``images``: float32 (B, H, W, 3) normalised; ``depth``: float32 (B, H, W, 1), the normalised
disparity of ``depth_input`` (docs/papers/mmf.md#depth-input). The RGB and depth trunks run stage by stage; after
the stem (post max-pool) and after each of layer1..4 an AFC (Eq. 5) fuses them, the fused map
feeds the next RGB stage and the depth trunk goes on with its own features. SwiftNet's SPP sits
on fused layer4; the decoder has three upsampling blocks with skips from fused layer3, 2, 1
(skip 1x1 conv-BN-ReLU, added to the bilinearly upsampled map, then 3x3 conv-BN-ReLU), then a
1x1 classifier and a bilinear resize to the input size. Ŝ_D = argmax of the logits.
"""
from __future__ import annotations

from typing import ClassVar

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np

from jaxanom.models.resnet import RESNETS, BasicBlock, Bottleneck, ResNetSpec
from jaxanom.nn.afc import AFC
from jaxanom.nn.layers import ConvBN, Dtype, resize_bilinear
from jaxanom.nn.spp import SpatialPyramidPooling


def depth_input(disparity, width: int):
    """Normalised disparity: clip(disparity_px / (W / 16), 0, 1); invalid (0) and sky stay 0. (..., H, W) -> same."""
    return np.clip(np.asarray(disparity, np.float32) / np.float32(width / 16), 0, 1)


class _Trunk(nn.Module):
    """One ResNet stage (``stage`` 0 = stem + max-pool, 1..4 = layer1..4) of a trunk."""

    spec: ResNetSpec
    stage: int
    dtype: Dtype

    @nn.compact
    def __call__(self, x: jax.Array, train: bool) -> jax.Array:
        spec = self.spec
        if self.stage == 0:
            x = ConvBN(spec.width, 7, 2, dtype=self.dtype, name="stem")(x, train)
            return nn.max_pool(x, (3, 3), strides=(2, 2), padding=((1, 1), (1, 1)))
        block = Bottleneck if spec.bottleneck else BasicBlock
        i = self.stage - 1
        for j in range(spec.stage_sizes[i]):
            x = block(spec.width * 2**i, stride=2 if i > 0 and j == 0 else 1, dtype=self.dtype, name=f"block{j}")(x, train)
        return x


class RGBDNet(nn.Module):
    """RFNet-style RGB-D segmenter (see the module docstring).

    Attributes: ``num_classes``; ``backbone`` a key of ``RESNETS``; ``decoder_channels`` (128 in
    RFNet); ``spp_branch_channels`` (32); ``dtype`` the compute dtype.
    """

    num_classes: int
    backbone: str = "resnet18"
    decoder_channels: int = 128
    spp_branch_channels: int = 32
    dtype: Dtype = jnp.float32
    extra_inputs: ClassVar[tuple[str, ...]] = ("depth",)  # batch entries the train loop passes

    @nn.compact
    def __call__(self, images: jax.Array, depth: jax.Array, train: bool = False) -> dict[str, jax.Array]:
        if images.ndim != 4 or images.shape[-1] != 3:
            raise ValueError(f"images: expected shape (B, H, W, 3), got {images.shape}")
        if depth.shape != images.shape[:3] + (1,):
            raise ValueError(f"depth: expected shape {images.shape[:3] + (1,)}, got {depth.shape}")
        if self.backbone not in RESNETS:
            raise ValueError(f"backbone: expected one of {sorted(RESNETS)}, got {self.backbone!r}")
        spec = RESNETS[self.backbone]
        height, width = images.shape[1:3]
        rgb, dep = images.astype(self.dtype), depth.astype(self.dtype)
        fused = []
        for stage in range(5):
            rgb = _Trunk(spec, stage, self.dtype, name=f"rgb{stage}")(rgb, train)
            dep = _Trunk(spec, stage, self.dtype, name=f"depth{stage}")(dep, train)
            rgb = AFC(self.dtype, name=f"afc{stage}")(rgb, dep)
            fused.append(rgb)
        x = SpatialPyramidPooling(self.decoder_channels, self.spp_branch_channels, dtype=self.dtype, name="spp")(
            fused[4], train)
        for level in (3, 2, 1):
            skip = ConvBN(self.decoder_channels, 1, dtype=self.dtype, name=f"skip{level}")(fused[level], train)
            x = resize_bilinear(x, *skip.shape[1:3]) + skip
            x = ConvBN(self.decoder_channels, 3, dtype=self.dtype, name=f"up{level}")(x, train)
        logits = nn.Conv(self.num_classes, (1, 1), dtype=self.dtype, param_dtype=jnp.float32, name="classifier")(x)
        return {"logits": resize_bilinear(logits.astype(jnp.float32), height, width)}
