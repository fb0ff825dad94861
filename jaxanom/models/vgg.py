"""VGG-16 / VGG-19 feature extractors (Simonyan & Zisserman 2015), as torchvision's ``features``.

    model = VGG("vgg16")                                   # taps: last ReLU of every block
    feats = model.apply(variables, images)                 # {"relu1_2": (B, H, W, 64), ...}
    VGG("vgg19", taps=PERCEPTUAL_TAPS).apply(variables, images)   # same weights, other taps

``images``: float32 (B, H, W, 3), ImageNet-normalised (``jaxanom.data.transforms.normalize``).
Convolutions are 3x3 with bias, padding 1, each followed by a ReLU; block b's convolutions are
``conv{b}_{i}`` and their ReLU outputs ``relu{b}_{i}``; blocks are separated by 2x2 stride-2
max-pools without padding (odd sides round down, as PyTorch). The network stops after the
deepest requested tap, so parameters of later layers are not needed (Flax ignores extra ones):
weights loaded for all taps serve any choice of ``taps``. There is no BatchNorm: ``train``
changes nothing and exists for the jaxanom.models calling convention.
"""
from __future__ import annotations

import flax.linen as nn
import jax
import jax.numpy as jnp

from jaxanom.nn.layers import Dtype

BLOCK_DEPTHS = {"vgg16": (2, 2, 3, 3, 3), "vgg19": (2, 2, 4, 4, 4)}
WIDTHS = (64, 128, 256, 512, 512)
# MMF's taps (docs/papers/mmf.md#dissimilarity-network): the dissimilarity encoder E1 (VGG16) and the perceptual
# difference (VGG19, the first four of SynBoost's five).
ENCODER_TAPS = ("relu1_2", "relu2_2", "relu3_3", "relu4_3")
PERCEPTUAL_TAPS = ("relu1_1", "relu2_1", "relu3_1", "relu4_1")


def layer_names(config: str) -> tuple[str, ...]:
    """Names of the ReLU outputs of ``config`` in order: relu1_1, relu1_2, relu2_1, ..."""
    return tuple(f"relu{b + 1}_{i + 1}" for b, depth in enumerate(BLOCK_DEPTHS[config]) for i in range(depth))


def default_taps(config: str) -> tuple[str, ...]:
    """The last ReLU of every block, e.g. relu1_2, relu2_2, relu3_3, relu4_3, relu5_3 for VGG16."""
    return tuple(f"relu{b + 1}_{depth}" for b, depth in enumerate(BLOCK_DEPTHS[config]))


class VGG(nn.Module):
    """VGG convolutional trunk returning the requested ReLU features (channels-last).

    Attributes:
      config: "vgg16" or "vgg19".
      taps: names from ``layer_names(config)``; default ``default_taps(config)``.
      widths: channels of the five blocks (torchvision: 64, 128, 256, 512, 512).
      dtype: compute dtype; parameters stay float32.
    """

    config: str = "vgg16"
    taps: tuple[str, ...] | None = None
    widths: tuple[int, ...] = WIDTHS
    dtype: Dtype = jnp.float32

    def __post_init__(self):
        if self.config not in BLOCK_DEPTHS:
            raise ValueError(f"config: expected one of {sorted(BLOCK_DEPTHS)}, got {self.config!r}")
        names = layer_names(self.config)
        if self.taps is not None and (not self.taps or not set(self.taps) <= set(names)):
            raise ValueError(f"taps: expected a non-empty subset of {names}, got {self.taps!r}")
        if len(self.widths) != 5:
            raise ValueError(f"widths: expected 5 block widths, got {self.widths!r}")
        super().__post_init__()

    @nn.compact
    def __call__(self, images: jax.Array, train: bool = False) -> dict[str, jax.Array]:
        if images.ndim != 4 or images.shape[-1] != 3:
            raise ValueError(f"images: expected shape (B, H, W, 3), got {images.shape}")
        taps = self.taps or default_taps(self.config)
        names = layer_names(self.config)
        last = max(names.index(tap) for tap in taps)
        x = images.astype(self.dtype)
        out = {}
        for name in names[: last + 1]:
            block, index = name[4:].split("_")
            if index == "1" and block != "1":
                x = nn.max_pool(x, (2, 2), strides=(2, 2), padding="VALID")
            x = nn.Conv(self.widths[int(block) - 1], (3, 3), padding=((1, 1), (1, 1)), dtype=self.dtype,
                        param_dtype=jnp.float32,
                        kernel_init=nn.initializers.variance_scaling(2.0, "fan_out", "normal"),
                        name=f"conv{block}_{index}")(x)
            x = nn.relu(x)
            if name in taps:
                out[name] = x.astype(jnp.float32)
        return out
