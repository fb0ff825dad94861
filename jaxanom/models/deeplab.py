"""DeepLabV3+ (Chen et al. 2018) on a ResNet, with an optional attention module (CuDAM, MSAAM, ...).

Contract (the training loop and the scorers rely on it)::

    model = DeepLabV3Plus(num_classes=19, backbone="resnet101", output_stride=8, attention="cudam")
    variables = model.init(key, images, train=False)        # {"params", "batch_stats"}
    out, state = model.apply(variables, images, train=True, mutable=["batch_stats"])
    out = model.apply(variables, images, train=False)

``images``: float32 (B, H, W, 3), already normalised by the caller; any H, W >= 1.
``train`` is a Python bool (static under ``jax.jit``): True normalises with batch statistics and
returns updated ``batch_stats`` (pass ``mutable=["batch_stats"]``), False uses running averages.
``out`` is a dict:

  * ``"logits"``: float32 (B, H, W, num_classes), bilinearly resized to the input size.
  * with an attention module, its outputs (``jaxanom.models.attention``): with ``"cudam"``,
    ``"attention"`` float32 (B, h, w), CuDAM's map M_att at the resolution of the features it
    gates (stride 4 at "deep": h = ceil(ceil(H/2)/2)); sums to 1 per image. With ``"msaam"``,
    ``"attention"`` (MSAAM's scale-attention map at the encoder's output, stride
    ``output_stride``; sums to 1 per image), ``"branch_weights"`` (B, 3) (the GRU's softmax
    weights for the scale, spatial and channel branches, Eq. 6) and the highlight maps
    ``"highlight_scale"``, ``"highlight_spatial"``, ``"highlight_channel"``,
    ``"highlight_combined"`` (B, h, w) (Eqs. 8-11).

Mixed precision: parameters and BatchNorm statistics are float32; ``dtype`` (e.g. bfloat16) is
the compute dtype; logits and attention outputs are float32. There is no dropout, so ``apply``
needs no random key.

Architecture: ResNet trunk; ASPP on ``layer4`` (1x1 conv, three 3x3 atrous convs with rates
(6, 12, 18) at output stride 16 and (12, 24, 36) at 8, image pooling; concatenated and projected
to ``aspp_channels``); decoder: ``layer1`` projected to ``low_level_channels``, ASPP output
upsampled to its size, concatenated, two 3x3 conv-BN-ReLU of ``decoder_channels``, a 1x1
classifier with bias. The attention positions (``ATTENTION_POSITIONS``): ``"encoder"`` (the end
of the encoder, ``layer4`` before ASPP: MSAAM's), ``"deep"`` after the first decoder convolution
(CuDAM's, the paper's best, Table V), ``"surface"`` after the second, just before the classifier
(our variant), ``"output"`` on the logits at input size (the paper's surface position: its (19,
720, 720)); the taps are ``"low"`` = ``layer1`` and ``"mid"`` = ``layer2`` (CuDAM's F_low and
F_mid). At ``"output"`` CuDAM's map is (B, H, W).

On the CuDAM position: the paper inserts the module "after the convolution layer following the
concatenation" (256 channels here: docs/papers/sml-cudam-msaam.md#insertion-position) yet lists the inserted feature as
(304, 180, 180), the concatenation itself; with 304 channels Eq. 2's 1x1 conv would have
(256 + 512 + 304) * 304 weights, about the paper's +0.34M, against +0.26M here. Its "surface"
position is the output (the paper's (19, 720, 720)): ``"output"`` here; ``"surface"`` is our
earlier reading (the last decoder feature before the classifier, stride 4), kept as a variant.

BatchNorm in train mode needs more than one value per channel: the ASPP image-pooling branch
sees one pixel per image, so train with batches of 2 or more (as in PyTorch).
"""
from __future__ import annotations

import numbers

import flax.linen as nn
import jax
import jax.numpy as jnp

from jaxanom.models.attention import Attachment, check_attachment
from jaxanom.models.resnet import RESNETS, ResNet, ResNetSpec
from jaxanom.nn.layers import ConvBN, Dtype, resize_bilinear

_DECODER_POSITIONS = ("deep", "surface")  # after the first and the second decoder convolution
RESIZES = ("half_pixel", "align_corners")


class ASPP(nn.Module):
    """Atrous spatial pyramid pooling: (B, h, w, C) -> (B, h, w, ``features``)."""

    features: int
    rates: tuple[int, ...]
    dtype: Dtype = jnp.float32

    @nn.compact
    def __call__(self, x: jax.Array, train: bool) -> jax.Array:
        branches = [ConvBN(self.features, 1, dtype=self.dtype, name="conv1x1")(x, train)]
        for i, rate in enumerate(self.rates):
            branches.append(
                ConvBN(self.features, 3, dilation=rate, dtype=self.dtype, name=f"atrous{i}")(x, train)
            )
        pooled = x.astype(jnp.float32).mean(axis=(1, 2), keepdims=True).astype(self.dtype)
        pooled = ConvBN(self.features, 1, dtype=self.dtype, name="image_pool")(pooled, train)
        branches.append(jnp.broadcast_to(pooled, branches[0].shape))
        x = jnp.concatenate(branches, axis=-1)
        return ConvBN(self.features, 1, dtype=self.dtype, name="project")(x, train)


class DeepLabV3Plus(nn.Module):
    """DeepLabV3+ segmenter; see the module docstring for the input/output contract.

    Attributes:
      num_classes: classifier outputs C.
      backbone: a key of ``jaxanom.models.resnet.RESNETS`` ("resnet18", "resnet50",
        "resnet101", "resnet_tiny") or a ``ResNetSpec``.
      output_stride: 8 or 16 (stride of the encoder's output).
      attention: None or a registered attention module's name (``jaxanom.models.attention``).
      attention_position: one of ``ATTENTION_POSITIONS`` (module docstring) where the module
        may sit; None: the first of its positions this network offers.
      attention_options: ``(name, value)`` pairs of the module's options (e.g. CuDAM's gate).
      aspp_channels, low_level_channels, decoder_channels: head widths (256, 48, 256 as in
        the paper's DeepLabV3+).
      dtype: compute dtype (float32 or bfloat16); parameters stay float32.
      resize: the decoder's and the logits' bilinear upsampling, "half_pixel" (PyTorch's
        ``align_corners=False``) or "align_corners" (``align_corners=True``, as in the SML
        authors' network; ``jaxanom.weights`` imports it with this setting).
    """

    ATTENTION_POSITIONS = ("encoder", "deep", "surface", "output")

    num_classes: int
    backbone: str | ResNetSpec = "resnet101"
    output_stride: int = 8
    attention: str | None = None
    attention_position: str | None = None
    attention_options: tuple[tuple[str, object], ...] = ()
    aspp_channels: int = 256
    low_level_channels: int = 48
    decoder_channels: int = 256
    dtype: Dtype = jnp.float32
    resize: str = "half_pixel"

    def __post_init__(self):
        if not isinstance(self.num_classes, numbers.Integral) or self.num_classes < 1:
            raise ValueError(f"num_classes: expected a positive int, got {self.num_classes!r}")
        if isinstance(self.backbone, str) and self.backbone not in RESNETS:
            raise ValueError(f"backbone: expected one of {sorted(RESNETS)}, got {self.backbone!r}")
        if self.output_stride not in (8, 16):
            raise ValueError(f"output_stride: expected 8 or 16, got {self.output_stride!r}")
        check_attachment(self)
        if self.resize not in RESIZES:
            raise ValueError(f"resize: expected one of {RESIZES}, got {self.resize!r}")
        super().__post_init__()

    @nn.compact
    def __call__(self, images: jax.Array, train: bool = False) -> dict[str, jax.Array]:
        if images.ndim != 4 or images.shape[-1] != 3:
            raise ValueError(f"images: expected shape (B, H, W, 3), got {images.shape}")
        if not jnp.issubdtype(images.dtype, jnp.floating):
            raise ValueError(f"images: expected a float dtype (normalised), got {images.dtype}")
        spec = RESNETS[self.backbone] if isinstance(self.backbone, str) else self.backbone
        height, width = images.shape[1:3]
        out = {}
        attachment = Attachment(self)

        feats = ResNet(spec, self.output_stride, dtype=self.dtype, name="backbone")(images, train)
        taps = {"low": feats["layer1"], "mid": feats["layer2"]}
        x = attachment.at("encoder", feats["layer4"], taps, out)

        rate = 16 // self.output_stride
        x = ASPP(self.aspp_channels, (6 * rate, 12 * rate, 18 * rate), self.dtype, name="aspp")(x, train)

        low = feats["layer1"]
        low_proj = ConvBN(self.low_level_channels, 1, dtype=self.dtype, name="low_level")(low, train)
        align_corners = self.resize == "align_corners"
        x = resize_bilinear(x, *low.shape[1:3], align_corners)
        x = jnp.concatenate([x, low_proj], axis=-1)
        # two 3x3 convolutions, each followed by an attention position
        for i, position in enumerate(_DECODER_POSITIONS):
            x = ConvBN(self.decoder_channels, 3, dtype=self.dtype, name=f"decoder{i}")(x, train)
            x = attachment.at(position, x, taps, out)

        logits = nn.Conv(
            self.num_classes, (1, 1), dtype=self.dtype, param_dtype=jnp.float32, name="classifier"
        )(x)
        logits = resize_bilinear(logits.astype(jnp.float32), height, width, align_corners)
        if attachment.position == "output":
            logits = attachment.at("output", logits.astype(self.dtype), taps, out)
        out["logits"] = logits.astype(jnp.float32)
        return out
