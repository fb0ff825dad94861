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
* ``espnet-cityscapes``: the ESPNet authors' Cityscapes network with the light decoder
  (github sacmehta/ESPNet, ``pretrained/decoder/espnet_p_<p>_q_<q>.pth``; 20 classes: the 19
  trainIds and void) -> ``jaxanom.models.espnet.ESPNet``, p and q read from the checkpoint.
  Their ``encoder.level{2,3}_0`` (strided ESP, ``bn`` / ``act``) and ``encoder.level{2,3}.{i}``
  (residual ESP, BN and PReLU inside ``bn.bn`` / ``bn.act``) are jaxanom's ``level{2,3}_down``
  and ``level{2,3}_{i}``; convolutions wrapped in their ``C`` module are ``<name>.conv``;
  ``up_l3.0``, ``up_l2.0`` and ``classifier`` are 2x2 transposed convs (``Upsample2``).
  Images are normalised with ``jaxanom.models.espnet.normalize_espnet``.
* ``erfnet-cityscapes``: the ERFNet authors' Cityscapes network (github Eromera/erfnet_pytorch,
  ``trained_models/erfnet_pretrained.pth``; 20 classes: the 19 trainIds and void) ->
  ``jaxanom.models.erfnet.ERFNet``, the class count read from ``decoder.output_conv``. Module paths
  map one to one (``encoder.layers.<i>.conv3x1_1`` is ``encoder/layers_<i>/conv3x1_1``); the
  transposed convs' weights (in, out, k, k) become kernels (k, k, out, in). Two layouts are read:
  the authors' float checkpoint (keys prefixed ``module.``) and the int8 redistribution
  (quantised conv weights, dequantised by ``read_state_dict``; each block's ``bn1`` folded into
  ``conv1x3_1``, so the import gives ``bn1`` the identity: scale 1, shift 0, mean 0 and a variance
  that makes var + eps exactly 1). Ignored: the encoder-only classifier ``encoder.output_conv``
  and the int8 file's output quantisation (``quant.*``, ``<module>.scale`` / ``.zero_point``,
  ``<block>.skip_add.*``). Images are scaled with ``jaxanom.models.erfnet.normalize_erfnet``.
* ``torchvision-vgg16|vgg19``: ``features.{n}`` (conv with bias) -> ``jaxanom.models.vgg.VGG``
  with ``conv{b}_{i}``; the ``classifier`` is not used.
"""
from __future__ import annotations

import re
from collections.abc import Mapping

import jax
import numpy as np

KINDS = ("torchvision-resnet18", "torchvision-resnet50", "torchvision-resnet101", "sml-deeplabv3plus",
         "torchvision-vgg16", "torchvision-vgg19", "espnet-cityscapes", "erfnet-cityscapes")
SML_PRESET = "deeplabv3plus_r101_sml"
# The jaxanom.models preset that each DeepLabV3+ kind builds.
PRESETS = {"torchvision-resnet18": "deeplabv3plus_r18", "torchvision-resnet50": "deeplabv3plus_r50",
           "torchvision-resnet101": "deeplabv3plus_r101", "sml-deeplabv3plus": SML_PRESET}
# the kinds that convert to a run folder (the VGGs do not)
RUN_KINDS = (*PRESETS, "espnet-cityscapes", "erfnet-cityscapes")
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
    train=False)`` takes images (B, H, W, 3) normalised with ImageNet's mean and std, except
    ESPNet's and ERFNet's (``model.normalize_input``). ``espnet-cityscapes`` (class count, p, q) and
    ``erfnet-cityscapes`` (class count) read their configuration from the checkpoint and ignore
    ``num_classes`` and ``output_stride``.
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
    if kind == "espnet-cityscapes":
        model = _espnet_for(state)
        template = jax.eval_shape(lambda x: model.init(jax.random.key(0), x, train=False), probe)
        what = f"{kind} (ESPNet p={model.p}, q={model.q}, {model.num_classes} classes)"
        return model, fill_variables(state, template, _espnet_name, lambda name: False, what)
    if kind == "erfnet-cityscapes":
        model, state = _erfnet_for(state)
        template = jax.eval_shape(lambda x: model.init(jax.random.key(0), x, train=False), probe)
        what = f"{kind} (ERFNet, {model.num_classes} classes)"
        return model, fill_variables(state, template, _erfnet_name, _erfnet_unused, what)
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


def run_preset(kind: str, model) -> str | None:
    """The ``build_model`` name of a network imported as ``kind`` (what its run folder records),
    or None for the kinds that have no run (VGG)."""
    if kind not in RUN_KINDS:
        return None
    if kind == "espnet-cityscapes":
        return f"espnet_p{model.p}_q{model.q}"
    if kind == "erfnet-cityscapes":
        return "erfnet"
    return PRESETS[kind]


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


def _espnet_for(state: Mapping):
    """The ESPNet whose p, q and classes the checkpoint's key names and classifier shape give."""
    from jaxanom.models.espnet import ESPNet

    def depth(level: int) -> int:
        return len({key.split(".")[2] for key in state if key.startswith(f"encoder.level{level}.")})

    classifier = state.get("classifier.weight")
    if classifier is None or classifier.ndim != 4:
        raise ValueError("state dict does not match espnet-cityscapes: expected the 2x2 transposed conv "
                         "'classifier.weight' (C, C, 2, 2) of the light decoder, found none")
    return ESPNet(num_classes=int(classifier.shape[1]), p=depth(2), q=depth(3))


def _espnet_name(path: tuple[str, ...]) -> str:
    """A Flax ESPNet module -> the authors' PyTorch name (see the module docstring)."""
    if path[0] == "encoder":
        stage, rest = path[1], path[2:]
        if match := re.fullmatch(r"(level\d)_(down|\d+)", stage):
            strided = match[2] == "down"
            prefix = f"encoder.{match[1]}_0" if strided else f"encoder.{match[1]}.{match[2]}"
            return _esp_name(prefix, rest[0], strided)
        if stage in ("level1", "classifier"):
            return f"encoder.{stage}.conv"
        return "encoder." + stage.replace("_", ".")  # level1_bn, b1_act, ...
    name = path[0]
    if name == "combine_esp":
        return _esp_name("combine_l2_l3.1", path[1], strided=False)
    return _ESPNET_DECODER[name]


_ESPNET_DECODER = {"br": "br", "up_l3": "up_l3.0", "level3_C": "level3_C.conv", "combine_bn": "combine_l2_l3.0.bn",
                   "combine_act": "combine_l2_l3.0.act", "up_l2": "up_l2.0", "up_l2_bn": "up_l2.1.bn",
                   "up_l2_act": "up_l2.1.act", "conv": "conv.conv", "conv_bn": "conv.bn", "conv_act": "conv.act",
                   "classifier": "classifier"}


def _esp_name(prefix: str, layer: str, strided: bool) -> str:
    if layer in ("bn", "act"):
        return f"{prefix}.{layer}" if strided else f"{prefix}.bn.{layer}"
    return f"{prefix}.{layer}.conv"  # c1, d1, d2, ... wrapped in the authors' C / CDilated


def _erfnet_for(state: Mapping):
    """The ERFNet of the checkpoint's class count, and the state with an identity ``bn1`` in every
    block when the checkpoint has none (the int8 layout, where it is folded into ``conv1x3_1``)."""
    from jaxanom.models.erfnet import BN_EPSILON, ERFNet

    classifier = state.get("decoder.output_conv.weight")
    if classifier is None or classifier.ndim != 4:
        raise ValueError("state dict does not match erfnet-cityscapes: expected the 2x2 transposed conv "
                         "'decoder.output_conv.weight' (16, C, 2, 2), found none")
    if not any(".bn1." in key for key in state):
        unit = np.float32(1 - BN_EPSILON)  # float32(0.999) + 1e-3 is exactly 1 in float32: bn1 is x -> x
        state = dict(state)
        for key in [key for key in state if key.endswith(".conv1x3_1.bias")]:
            block, channels = key.removesuffix(".conv1x3_1.bias"), state[key].shape
            state |= {f"{block}.bn1.weight": np.ones(channels, np.float32),
                      f"{block}.bn1.bias": np.zeros(channels, np.float32),
                      f"{block}.bn1.running_mean": np.zeros(channels, np.float32),
                      f"{block}.bn1.running_var": np.full(channels, unit, np.float32)}
    return ERFNet(num_classes=int(classifier.shape[1])), state


def _erfnet_name(path: tuple[str, ...]) -> str:
    """A Flax ERFNet module -> the authors' PyTorch name (``layers_3`` -> ``layers.3``)."""
    return ".".join(path).replace("layers_", "layers.")


# The encoder-only training's classifier, and the int8 file's output quantisation parameters.
_ERFNET_UNUSED = re.compile(r"encoder\.output_conv\..*|quant\.(scale|zero_point)|.*\.skip_add\.(scale|zero_point)"
                            r"|.*\.(conv|bn|conv3x1_[12]|conv1x3_[12]|bn[12]|output_conv)\.(scale|zero_point)")


def _erfnet_unused(key: str) -> bool:
    return _ERFNET_UNUSED.fullmatch(key) is not None


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
