"""Models by name, and parameter counts without allocating parameters.

    model = build_model("deeplabv3plus_r101", num_classes=19, attention="cudam")
    build_model("deeplabv3plus_tiny", num_classes=19)   # small enough for CPU tests and demos
    build_model("espnet_p2_q8", num_classes=20)          # ESPNet, p and q in the name
    build_model("erfnet", num_classes=20)                # ERFNet
    build_model("erfnet_tiny", num_classes=19)           # ERFNet's layers, fewer and narrower (tests, CPU)
    build_model("erfnet", num_classes=20, attention="cudam")   # any of them with an attention module

Keyword arguments override any field of ``DeepLabV3Plus`` (output_stride, dtype...) or of
``ESPNet`` / ``ERFNet`` (dtype), the attention fields of all three (``attention``,
``attention_position``, ``attention_options``: ``jaxanom.models.attention``); ``model_family(name)``
says which of the three a name builds.
"""
from __future__ import annotations

import math
import re
from typing import Any

import jax
import jax.numpy as jnp

from jaxanom.models.deeplab import DeepLabV3Plus
from jaxanom.models.erfnet import ERFNet
from jaxanom.models.espnet import ESPNet

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
    "deeplabv3plus_small": {
        "backbone": "resnet18_quarter",
        "aspp_channels": 64,
        "low_level_channels": 24,
        "decoder_channels": 64,
    },
}

# ERFNet presets: the authors' network, and the same layers fewer and narrower
_ERFNETS: dict[str, dict[str, Any]] = {
    "erfnet": {},
    "erfnet_tiny": {"widths": (4, 8, 16), "encoder_blocks": (1, 2), "decoder_blocks": 1},
}

# ESPNet with p residual ESP modules in stage 2 and q in stage 3 (the authors' espnet_p_<p>_q_<q>).
_ESPNET = re.compile(r"espnet_p([1-9]\d*)_q([1-9]\d*)")


def model_names() -> tuple[str, ...]:
    """Names accepted by ``build_model`` (any ``espnet_p<P>_q<Q>``; the authors' Cityscapes one listed)."""
    return (*_PRESETS, "espnet_p2_q8", *_ERFNETS)


def model_family(name: str) -> str:
    """``"deeplabv3plus"``, ``"espnet"`` or ``"erfnet"``: the class ``build_model(name)`` builds."""
    if name in _PRESETS:
        return "deeplabv3plus"
    if _ESPNET.fullmatch(name):
        return "espnet"
    if name in _ERFNETS:
        return "erfnet"
    raise ValueError(f"name: expected one of {model_names()} or espnet_p<P>_q<Q>, got {name!r}")


def build_model(name: str, num_classes: int = 19, **overrides: Any) -> DeepLabV3Plus | ESPNet | ERFNet:
    """The network of a preset name; ``overrides`` replace preset fields."""
    if model_family(name) == "erfnet":
        return ERFNet(num_classes=num_classes, **{**_ERFNETS[name], **overrides})
    if model_family(name) == "espnet":
        p, q = map(int, _ESPNET.fullmatch(name).groups())
        return ESPNet(num_classes=num_classes, p=p, q=q, **overrides)
    return DeepLabV3Plus(num_classes=num_classes, **{**_PRESETS[name], **overrides})


def count_params(model: DeepLabV3Plus | ESPNet | ERFNet, image_size: tuple[int, int] = (64, 64)) -> int:
    """Number of trainable parameters of ``model``, found with ``jax.eval_shape`` (no allocation).

    The count does not depend on ``image_size``; it only has to be large enough to trace.
    """
    images = jax.ShapeDtypeStruct((1, *image_size, 3), jnp.float32)
    shapes = jax.eval_shape(
        lambda x: model.init(jax.random.key(0), x, train=False), images
    )
    return sum(math.prod(leaf.shape) for leaf in jax.tree.leaves(shapes["params"]))
