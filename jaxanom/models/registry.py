"""Models by name, and parameter counts without allocating parameters.

    model = build_model("deeplabv3plus_r101", num_classes=19, attention="cudam")
    build_model("deeplabv3plus_tiny", num_classes=19)   # small enough for CPU tests and demos

Keyword arguments override any field of ``DeepLabV3Plus`` (output_stride, attention, dtype...).
"""
from __future__ import annotations

import math
from typing import Any

import jax
import jax.numpy as jnp

from jaxanom.models.deeplab import DeepLabV3Plus

_PRESETS: dict[str, dict[str, Any]] = {
    "deeplabv3plus_r18": {"backbone": "resnet18"},
    "deeplabv3plus_r50": {"backbone": "resnet50"},
    "deeplabv3plus_r101": {"backbone": "resnet101"},
    # The SML authors' DeepR101V3PlusD_OS8 (jaxanom.weights imports its checkpoints).
    "deeplabv3plus_r101_sml": {"backbone": "resnet101_deep_stem", "resize": "align_corners"},
    "deeplabv3plus_tiny": {
        "backbone": "resnet_tiny",
        "aspp_channels": 16,
        "low_level_channels": 8,
        "decoder_channels": 16,
    },
}


def model_names() -> tuple[str, ...]:
    """Names accepted by ``build_model``."""
    return tuple(_PRESETS)


def build_model(name: str, num_classes: int = 19, **overrides: Any) -> DeepLabV3Plus:
    """A ``DeepLabV3Plus`` from a preset name; ``overrides`` replace preset fields."""
    if name not in _PRESETS:
        raise ValueError(f"name: expected one of {model_names()}, got {name!r}")
    return DeepLabV3Plus(num_classes=num_classes, **{**_PRESETS[name], **overrides})


def count_params(model: DeepLabV3Plus, image_size: tuple[int, int] = (64, 64)) -> int:
    """Number of trainable parameters of ``model``, found with ``jax.eval_shape`` (no allocation).

    The count does not depend on ``image_size``; it only has to be large enough to trace.
    """
    images = jax.ShapeDtypeStruct((1, *image_size, 3), jnp.float32)
    shapes = jax.eval_shape(
        lambda x: model.init(jax.random.key(0), x, train=False), images
    )
    return sum(math.prod(leaf.shape) for leaf in jax.tree.leaves(shapes["params"]))
