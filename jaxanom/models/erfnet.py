"""ERFNet (Romera et al., T-ITS 2018), as the authors' Cityscapes weights have it.

::

    model = ERFNet(num_classes=20)
    out = model.apply(variables, normalize_erfnet(images_uint8_rgb), train=False)   # {"logits"}

``images``: float32 (B, H, W, 3), H and W multiples of 8, RGB scaled to [0, 1] with no mean or
std (``normalize_erfnet``: what the authors trained and evaluated on); uint8 batches given to
``jaxanom.app.evaluate.predictor`` or the training step are scaled that way
(``ERFNet.normalize_input``). ``out["logits"]``: float32 (B, H, W, num_classes).

An attention module (``attention=NAME``, ``jaxanom.models.attention``) sits at the one position
``"deep"``: the encoder's output (128 channels at 1/8) before the decoder, with the taps ``"low"``
(the 64 channels at 1/4 after ``layers_5``) and ``"mid"`` (the 128 channels at 1/8 after the third
downsampler, ``layers_6``); its outputs join ``out``. ``erfnet_tiny`` is the same network with
fewer, narrower layers (tests, CPU demos).

Architecture (paper Sec. III, Table I; layer names follow the authors' checkpoint, see
``jaxanom.weights.architectures``):

* Downsampler: a 3x3 stride-2 conv to out - in channels, concatenated (after it) with a 2x2
  max-pool of the input, then BN + ReLU.
* Non-bottleneck-1D block (dilation d): 3x1 conv, ReLU, 1x3 conv, BN, ReLU, 3x1 conv with
  dilation (d, 1), ReLU, 1x3 conv with dilation (1, d), BN, channel dropout (training only),
  the input added, ReLU. Every conv keeps the size (padding d along its long axis).
* Encoder: downsamplers 3 -> 16 and 16 -> 64, five blocks at 64 (d = 1, dropout 0.03), a
  downsampler 64 -> 128, then twice the blocks at 128 with d = 2, 4, 8, 16 (dropout 0.3).
* Decoder: 3x3 stride-2 transposed conv (padding 1, output padding 1) + BN + ReLU 128 -> 64, two
  blocks at 64, the same 64 -> 16, two blocks at 16 (no dropout), and a 2x2 stride-2 transposed
  conv to the classes.

Every conv has a bias; every BN has eps 1e-3. Dropout is the authors' ``Dropout2d``: whole
channels of a sample, the others scaled by 1 / (1 - p); it needs ``rngs={"dropout": key}`` when
``train=True``.
"""
from __future__ import annotations

import flax.linen as nn
import jax
import jax.numpy as jnp

from jaxanom._validate import check_image_batch
from jaxanom.models.attention import Attachment, check_attachment
from jaxanom.nn.batch_norm import BatchNorm
from jaxanom.nn.layers import BN_MOMENTUM, Dtype

BN_EPSILON = 1e-3
DILATIONS = (2, 4, 8, 16)  # the 128-channel blocks, repeated twice
ENCODER_DROPOUT = (0.03, 0.3)  # the authors' channel-dropout rates at 64 and at 128 channels
_KERNEL_INIT = nn.initializers.variance_scaling(1.0, "fan_in", "normal")


def normalize_erfnet(images):
    """uint8 RGB (..., 3) -> float32 RGB in [0, 1] (``ToTensor``: no mean, no std), the input the
    authors' weights were trained on. NumPy or JAX arrays, usable inside ``jit``."""
    return images.astype("float32") / 255.0


def _conv(features: int, kernel: tuple[int, int], dtype: Dtype, name: str, stride: int = 1,
          dilation: tuple[int, int] = (1, 1)) -> nn.Conv:
    padding = [(d * (k // 2),) * 2 for k, d in zip(kernel, dilation)]
    return nn.Conv(features, kernel, strides=stride, padding=padding, kernel_dilation=dilation, use_bias=True,
                   dtype=dtype, param_dtype=jnp.float32, kernel_init=_KERNEL_INIT, name=name)


def _bn(x, train: bool, dtype: Dtype, name: str):
    return BatchNorm(use_running_average=not train, momentum=BN_MOMENTUM, epsilon=BN_EPSILON, dtype=dtype,
                     name=name)(x)


class ConvTranspose2x(nn.Module):
    """PyTorch's ``ConvTranspose2d(cin, features, k, stride=2, padding, output_padding)`` with bias, for
    the sizes where it doubles H and W (k - 2 - 2 padding + output_padding = 0; here k=3, padding=1,
    output_padding=1 and k=2, padding=0): (B, H, W, cin) -> (B, 2H, 2W, features). ``kernel`` is
    (k, k, features, cin): PyTorch's weight (cin, features, k, k) with its axes reversed.

    Computed per output phase (sub-pixel): output row 2i + a takes the taps ky with a + padding - ky
    even, applied to input row i + (a + padding - ky) / 2. The few shifted copies of the input,
    side by side, times one matrix (taps x cin, 4 x features; zero where a shift feeds no phase) give
    all four phases at once; no zeros are inserted into the input (XLA's input-dilated convolution
    was slower on the CPU, docs/decisions/erfnet.md)."""

    features: int
    kernel_size: int
    padding: int = 0
    output_padding: int = 0
    dtype: Dtype = jnp.float32

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        k, p, cin = self.kernel_size, self.padding, x.shape[-1]
        if k - 2 - 2 * p + self.output_padding:
            raise ValueError(f"kernel_size, padding, output_padding: expected sizes that double H and W, got "
                             f"{k}, {p}, {self.output_padding}")
        init = nn.initializers.variance_scaling(1.0, "fan_in", "normal", in_axis=-1, out_axis=-2)
        kernel = self.param("kernel", init, (k, k, self.features, cin), jnp.float32)
        bias = self.param("bias", nn.initializers.zeros, (self.features,), jnp.float32)
        taps = [(a, tap, (a + p - tap) // 2) for a in (0, 1) for tap in range(k) if (a + p - tap) % 2 == 0]
        shifts = sorted({shift for _, _, shift in taps})
        matrix = jnp.zeros((len(shifts), len(shifts), cin, 2, 2, self.features), jnp.float32)
        for a, ky, sy in taps:
            for b, kx, sx in taps:
                matrix = matrix.at[shifts.index(sy), shifts.index(sx), :, a, b, :].set(kernel[ky, kx].T)
        before, after = max(0, -shifts[0]), max(0, shifts[-1])
        padded = jnp.pad(x.astype(self.dtype), ((0, 0), (before, after), (before, after), (0, 0)))
        bsz, h, w, _ = x.shape
        views = [padded[:, before + sy: before + sy + h, before + sx: before + sx + w]
                 for sy in shifts for sx in shifts]
        patches = views[0] if len(views) == 1 else jnp.concatenate(views, -1)
        y = patches @ matrix.reshape(-1, 4 * self.features).astype(self.dtype)
        y = y.reshape(bsz, h, w, 2, 2, self.features).transpose(0, 1, 3, 2, 4, 5)
        return y.reshape(bsz, 2 * h, 2 * w, self.features) + bias.astype(self.dtype)


class Downsampler(nn.Module):
    """[3x3 stride-2 conv to ``features - in``, 2x2 max-pool], BN, ReLU: halves H and W."""

    features: int
    dtype: Dtype = jnp.float32

    @nn.compact
    def __call__(self, x: jax.Array, train: bool) -> jax.Array:
        conv = _conv(self.features - x.shape[-1], (3, 3), self.dtype, "conv", stride=2)(x)
        pooled = nn.max_pool(x, (2, 2), strides=(2, 2))
        return nn.relu(_bn(jnp.concatenate([conv, pooled], -1), train, self.dtype, "bn"))


class NonBottleneck1D(nn.Module):
    """The factorised residual block (module docstring); keeps shape."""

    dilation: int = 1
    dropout: float = 0.0
    dtype: Dtype = jnp.float32

    @nn.compact
    def __call__(self, x: jax.Array, train: bool) -> jax.Array:
        c, d, dt = x.shape[-1], self.dilation, self.dtype
        y = nn.relu(_conv(c, (3, 1), dt, "conv3x1_1")(x))
        y = nn.relu(_bn(_conv(c, (1, 3), dt, "conv1x3_1")(y), train, dt, "bn1"))
        y = nn.relu(_conv(c, (3, 1), dt, "conv3x1_2", dilation=(d, 1))(y))
        y = _bn(_conv(c, (1, 3), dt, "conv1x3_2", dilation=(1, d))(y), train, dt, "bn2")
        if self.dropout:
            y = nn.Dropout(self.dropout, broadcast_dims=(1, 2), deterministic=not train)(y)  # whole channels
        return nn.relu(y + x)


class Upsampler(nn.Module):
    """3x3 stride-2 transposed conv (padding 1, output padding 1), BN, ReLU: doubles H and W."""

    features: int
    dtype: Dtype = jnp.float32

    @nn.compact
    def __call__(self, x: jax.Array, train: bool) -> jax.Array:
        y = ConvTranspose2x(self.features, 3, padding=1, output_padding=1, dtype=self.dtype, name="conv")(x)
        return nn.relu(_bn(y, train, self.dtype, "bn"))


class ERFNetEncoder(nn.Module):
    """Image -> (``widths[2]`` channels at 1/8, the taps {"low", "mid"}) (module docstring); ``layers_<i>``
    are the authors' ``layers.<i>``. ``widths`` and ``blocks``: the channels of the three stages and the
    blocks at 1/4 and at 1/8 (the authors': (16, 64, 128) and (5, 8))."""

    dtype: Dtype = jnp.float32
    widths: tuple[int, int, int] = (16, 64, 128)
    blocks: tuple[int, int] = (5, 8)

    @nn.compact
    def __call__(self, x: jax.Array, train: bool) -> tuple[jax.Array, dict[str, jax.Array]]:
        dt, (low, high), (quarter, eighth) = self.dtype, ENCODER_DROPOUT, self.blocks
        x = Downsampler(self.widths[0], dt, name="initial_block")(x, train)
        x = Downsampler(self.widths[1], dt, name="layers_0")(x, train)
        for i in range(1, 1 + quarter):
            x = NonBottleneck1D(1, low, dt, name=f"layers_{i}")(x, train)
        taps = {"low": x}
        x = taps["mid"] = Downsampler(self.widths[2], dt, name=f"layers_{1 + quarter}")(x, train)
        for i, d in enumerate((DILATIONS * 2)[:eighth], start=2 + quarter):
            x = NonBottleneck1D(d, high, dt, name=f"layers_{i}")(x, train)
        return x, taps


class ERFNetDecoder(nn.Module):
    """``widths[2]`` channels at 1/8 -> ``num_classes`` logits at full size, with ``blocks`` blocks
    after each upsampler (the authors': 2)."""

    num_classes: int
    dtype: Dtype = jnp.float32
    widths: tuple[int, int, int] = (16, 64, 128)
    blocks: int = 2

    @nn.compact
    def __call__(self, x: jax.Array, train: bool) -> jax.Array:
        dt, i = self.dtype, 0
        for features in (self.widths[1], self.widths[0]):
            x = Upsampler(features, dt, name=f"layers_{i}")(x, train)
            for j in range(1, 1 + self.blocks):
                x = NonBottleneck1D(dtype=dt, name=f"layers_{i + j}")(x, train)
            i += 1 + self.blocks
        return ConvTranspose2x(self.num_classes, 2, dtype=dt, name="output_conv")(x)


class ERFNet(nn.Module):
    """ERFNet; ``__call__(images, train) -> {"logits", the attention module's outputs?}`` (module
    docstring). ``attention``, ``attention_position``, ``attention_options``: as ``DeepLabV3Plus``'s.
    ``widths``, ``encoder_blocks``, ``decoder_blocks``: the authors' by default; fewer and narrower
    layers make ``erfnet_tiny`` (``jaxanom.models.build_model``), for tests and CPU demos."""

    ATTENTION_POSITIONS = ("deep",)

    num_classes: int = 20
    dtype: Dtype = jnp.float32
    attention: str | None = None
    attention_position: str | None = None
    attention_options: tuple[tuple[str, object], ...] = ()
    widths: tuple[int, int, int] = (16, 64, 128)
    encoder_blocks: tuple[int, int] = (5, 8)
    decoder_blocks: int = 2

    normalize_input = staticmethod(normalize_erfnet)  # uint8 RGB -> the input these weights expect

    def __post_init__(self):
        check_attachment(self)
        super().__post_init__()

    @nn.compact
    def __call__(self, images: jax.Array, train: bool = False) -> dict[str, jax.Array]:
        check_image_batch(images, 8, "scaled to [0, 1]")
        out = {}
        encoder = ERFNetEncoder(self.dtype, self.widths, self.encoder_blocks, name="encoder")
        features, taps = encoder(images.astype(self.dtype), train)
        features = Attachment(self).at("deep", features, taps, out)
        decoder = ERFNetDecoder(self.num_classes, self.dtype, self.widths, self.decoder_blocks, name="decoder")
        logits = decoder(features, train)
        return {**out, "logits": logits.astype(jnp.float32)}
