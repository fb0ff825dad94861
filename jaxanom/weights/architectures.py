"""Which PyTorch module holds each jaxanom layer, for the architectures users have weights of.

* ``torchvision-resnet18|50|101``: torchvision's ImageNet ResNets (7x7 stem ``conv1``/``bn1``,
  ``layer{i}.{j}.conv{k}``/``bn{k}``, ``downsample.0``/``.1``; the classifier ``fc`` is not
  used) -> the backbone of a jaxanom ``DeepLabV3Plus``, whose head is initialised at random.
  Bottlenecks put the stride on the 3x3 conv in both. At output stride 8/16 jaxanom dilates every
  block of a dilated stage (as DeepLab and the SML code do), where torchvision's
  ``replace_stride_with_dilation`` keeps the previous dilation in the first block.
* ``sml-deeplabv3plus``: the SML authors' ``DeepR101V3PlusD_OS8`` (``network/deepv3.py``) ->
  preset ``deeplabv3plus_r101_sml``: deep stem ``layer0.{0,1,3,4,6,7}`` (64, 64, 128 channels),
  ResNet-101 stages dilated as above, ASPP ``aspp.features.{0..3}`` (1x1, rates 12/24/36) and
  ``aspp.img_conv`` (image pooling), ``bot_aspp`` (1280 -> 256), ``bot_fine`` (layer1 -> 48),
  ``final1.{0,1,3,4}`` (two 3x3 conv-BN), ``final2.0`` (classifier with bias), bilinear resizes
  with ``align_corners=True``. The auxiliary head ``dsn`` (training only) is not used. Their ASPP
  concatenates the image-pooling branch first and their decoder puts ``bot_fine`` before the
  upsampled ASPP output; jaxanom concatenates in the other order, so the input channels of
  ``bot_aspp`` and ``final1.0`` are rotated on import (the same function, exactly).
* ``torchvision-vgg16|vgg19``: ``features.{n}`` (conv with bias) -> ``jaxanom.models.vgg.VGG``
  with ``conv{b}_{i}``; the ``classifier`` is not used.
"""
from __future__ import annotations

import re
from collections.abc import Mapping

import jax
import numpy as np

KINDS = ("torchvision-resnet18", "torchvision-resnet50", "torchvision-resnet101", "sml-deeplabv3plus",
         "torchvision-vgg16", "torchvision-vgg19")
SML_PRESET = "deeplabv3plus_r101_sml"
# The jaxanom.models preset that each DeepLabV3+ kind builds.
PRESETS = {"torchvision-resnet18": "deeplabv3plus_r18", "torchvision-resnet50": "deeplabv3plus_r50",
           "torchvision-resnet101": "deeplabv3plus_r101", "sml-deeplabv3plus": SML_PRESET}
_SML_HEAD = {("aspp", "conv1x1"): "aspp.features.0", ("aspp", "atrous0"): "aspp.features.1",
             ("aspp", "atrous1"): "aspp.features.2", ("aspp", "atrous2"): "aspp.features.3",
             ("aspp", "image_pool"): "aspp.img_conv", ("aspp", "project"): "bot_aspp",
             ("low_level",): "bot_fine", ("decoder0",): "final1", ("decoder1",): "final1"}
_PROBE = (1, 32, 32, 3)  # any image size traces the same variables


def from_torch(state_dict: Mapping, kind: str, num_classes: int = 19, *, key: jax.Array | None = None,
               output_stride: int = 8):
    """``(model, variables)`` carrying the weights of a PyTorch ``state_dict`` of ``kind``.

    ``state_dict``: tensors or arrays by name (``read_state_dict``'s output, or
    ``torch_model.state_dict()``). ``kind``: one of ``KINDS``. ``num_classes`` and
    ``output_stride`` (8 or 16) configure the DeepLabV3+ kinds; the VGG kinds ignore them.
    ``key``: a ``jax.random`` key initialising the DeepLabV3+ head of the ``torchvision-resnet*``
    kinds (required there; the other kinds load every variable). ``model.apply(variables, images,
    train=False)`` takes images (B, H, W, 3) normalised with ImageNet's mean and std.
    Raises ValueError listing missing, unexpected and mis-shaped keys when the state dict does not
    fit ``kind`` (nothing is loaded partially).
    """
    from jaxanom.models import build_model
    from jaxanom.models.vgg import VGG
    from jaxanom.weights.files import state_dict_arrays
    from jaxanom.weights.mapping import fill_variables

    if kind not in KINDS:
        raise ValueError(f"kind: expected one of {KINDS}, got {kind!r}")
    state = state_dict_arrays(state_dict)
    probe = np.zeros(_PROBE, np.float32)
    if kind.startswith("torchvision-vgg"):
        model = VGG(kind.removeprefix("torchvision-"))
        template = jax.eval_shape(lambda x: model.init(jax.random.key(0), x), probe)
        return model, fill_variables(state, template, _vgg_name(model.config),
                                     lambda name: name.startswith("classifier."), kind)
    if kind == "sml-deeplabv3plus":
        model = build_model(SML_PRESET, num_classes=num_classes, output_stride=output_stride, attention=None)
        template = jax.eval_shape(lambda x: model.init(jax.random.key(0), x, train=False), probe)
        shift = {"bot_aspp.0": model.aspp_channels, "final1.0": model.low_level_channels}
        variables = fill_variables(state, template, _sml_name, lambda name: name.startswith("dsn."),
                                   f"{kind} ({SML_PRESET}, {num_classes} classes)", shift)
        return model, variables
    if key is None:
        raise ValueError(f"key: {kind} initialises the DeepLabV3+ head at random; pass key=jax.random.key(seed)")
    model = build_model(PRESETS[kind], num_classes=num_classes, output_stride=output_stride, attention=None)
    template = _with_initial_head(model, key, probe)
    variables = fill_variables(state, template, _torchvision_resnet_name,
                               lambda name: name.startswith("fc."), f"{kind} (ImageNet backbone)")
    return model, variables


def _with_initial_head(model, key: jax.Array, probe: np.ndarray) -> dict:
    """The backbone's shapes and the head's initial values (exactly ``model.init``'s): only the head
    leaves are computed, so XLA drops the backbone's initialisation and forward pass."""

    def head(key):
        variables = model.init(key, probe, train=False)
        return {collection: {name: tree for name, tree in trees.items() if name != "backbone"}
                for collection, trees in variables.items()}

    shapes = jax.eval_shape(lambda x: model.init(key, x, train=False), probe)
    initial = jax.device_get(jax.jit(head)(key))
    return {collection: {**trees, **initial.get(collection, {})} for collection, trees in shapes.items()}


def _resnet_name(path: tuple[str, ...]) -> str:
    """A ResNet module below ``backbone`` -> its PyTorch prefix (torchvision / SML stage naming)."""
    stage, block = path[0], path[1:]
    if match := re.fullmatch(r"layer(\d+)_(\d+)", stage):
        prefix = f"layer{match[1]}.{match[2]}"
        if block[0] == "downsample":
            return f"{prefix}.downsample.{0 if block[1] == 'conv' else 1}"
        index = block[0].removeprefix("conv")
        return f"{prefix}.{'conv' if block[1] == 'conv' else 'bn'}{index}"
    if stage == "stem":  # torchvision's 7x7 stem
        return "conv1" if block[0] == "conv" else "bn1"
    if match := re.fullmatch(r"stem(\d)", stage):  # the deep stem: nn.Sequential(conv, bn, relu) x 3
        return f"layer0.{3 * (int(match[1]) - 1) + (0 if block[0] == 'conv' else 1)}"
    raise ValueError(f"no PyTorch name for the backbone module {'/'.join(path)}")


def _torchvision_resnet_name(path: tuple[str, ...]) -> str | None:
    return _resnet_name(path[1:]) if path[0] == "backbone" else None


def _sml_name(path: tuple[str, ...]) -> str:
    if path[0] == "backbone":
        return _resnet_name(path[1:])
    if path == ("classifier",):
        return "final2.0"
    module, layer = path[:-1], path[-1]
    offset = 3 if module == ("decoder1",) else 0
    return f"{_SML_HEAD[module]}.{offset + (0 if layer == 'conv' else 1)}"


def _vgg_name(config: str):
    """``conv{b}_{i}`` -> ``features.{n}``: each conv and its ReLU take two slots, each pool one."""
    from jaxanom.models.vgg import layer_names

    index, slots = 0, {}
    for name in layer_names(config):
        block, conv = name[4:].split("_")
        if conv == "1" and block != "1":
            index += 1  # the max-pool before this block
        slots[f"conv{block}_{conv}"] = f"features.{index}"
        index += 2
    return lambda path: slots[path[0]]
