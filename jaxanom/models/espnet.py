"""ESPNet (Mehta et al., ECCV 2018) with its light decoder, as the authors' Cityscapes weights have it.

::

    model = ESPNet(num_classes=20, p=2, q=8)
    out = model.apply(variables, normalize_espnet(images_uint8_rgb), train=False)   # {"logits"}

``images``: float32 (B, H, W, 3), H and W multiples of 8, normalised with
``normalize_espnet`` (the authors' BGR mean / std, then / 255); uint8
batches given to ``jaxanom.app.evaluate.predictor`` or the training step are normalised that way
(``ESPNet.normalize_input``). ``out["logits"]``: float32 (B, H, W, num_classes).

An attention module (``attention=NAME``, ``jaxanom.models.attention``) sits at the one position
``"deep"``: the encoder's output (c8, C channels at 1/8) before the decoder, with the taps
``"low"`` (t2, 131 channels at 1/4) and ``"mid"`` (t3, 256 channels at 1/8, c8's input); its
outputs join ``out``.

Architecture (paper Sec. 3 and Fig. 4d; layer names follow the authors' checkpoint, see
``jaxanom.weights.architectures``):

* ESP module (Fig. 3b): reduce to n = out // 5 channels (1x1 conv; 3x3 stride 2 when strided),
  five parallel 3x3 convs with dilations 1, 2, 4, 8, 16 (d = 1 gives the out - 4n leftover
  channels), hierarchical feature fusion (the d = 2..16 outputs summed cumulatively), concatenated,
  plus the input when in == out and not strided, then BN + PReLU.
* Encoder: 3x3 stride-2 conv 3 -> 16 (s1); BN+PReLU on [s1, I/2]; a strided ESP -> 64 (d2) and
  p residual ESPs (y2); BN+PReLU on [y2, d2, I/4] (t2, 131 channels); a strided ESP -> 128 (d3)
  and q residual ESPs (y3); BN+PReLU on [d3, y3]; 1x1 conv -> C (c8, stride 8). I/2 and I/4 are
  the image average-pooled (3x3, stride 2, zero padding 1 counted) once and twice.
* Decoder: BN on c8, 2x2 stride-2 transposed conv (u4); 1x1 conv of t2 -> C (p4); BN+PReLU on
  [p4, u4] and a non-residual ESP 2C -> C; transposed conv, BN+PReLU (u2); 3x3 conv of [u2, s1]
  -> C, BN+PReLU; a last transposed conv gives the logits at full resolution.

Every conv is bias-free, every BN has eps 1e-3, PReLU has one slope per channel.
"""
from __future__ import annotations

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np

from jaxanom._validate import check_image_batch
from jaxanom.models.attention import Attachment, check_attachment
from jaxanom.nn.layers import BN_MOMENTUM, Dtype

# The authors' Cityscapes preprocessing (their VisualizeResults.py), per channel in BGR order.
BGR_MEAN = np.array([72.3923111, 82.90893555, 73.15840149], np.float32)
BGR_STD = np.array([45.3192215, 46.15289307, 44.91483307], np.float32)
BN_EPSILON = 1e-3
DILATIONS = (2, 4, 8, 16)  # the branches fused hierarchically; the d = 1 branch stands alone
_KERNEL_INIT = nn.initializers.variance_scaling(2.0, "fan_out", "normal")


def normalize_espnet(images):
    """uint8 RGB (..., 3) -> float32 ``((bgr - BGR_MEAN) / BGR_STD) / 255``, the input the authors'
    weights were trained on (they resize between the two steps; resizing is linear, so resizing the
    uint8 image first differs only by its rounding). NumPy or JAX arrays, usable inside ``jit``."""
    bgr = images[..., ::-1].astype("float32")
    return (bgr - BGR_MEAN) / BGR_STD / 255.0


def _conv(features: int, kernel: int, dtype: Dtype, name: str, stride: int = 1, dilation: int = 1) -> nn.Conv:
    pad = dilation * (kernel // 2)
    return nn.Conv(features, (kernel, kernel), strides=stride, padding=((pad, pad), (pad, pad)),
                   kernel_dilation=dilation, use_bias=False, dtype=dtype, param_dtype=jnp.float32,
                   kernel_init=_KERNEL_INIT, name=name)


def _bn(x, train: bool, dtype: Dtype, name: str):
    return nn.BatchNorm(use_running_average=not train, momentum=BN_MOMENTUM, epsilon=BN_EPSILON, dtype=dtype,
                        param_dtype=jnp.float32, name=name)(x)


def _bn_prelu(x, train: bool, dtype: Dtype, prefix: str = ""):
    """BN then PReLU, as modules ``{prefix}bn`` and ``{prefix}act`` of the calling module."""
    return PReLU(name=f"{prefix}act")(_bn(x, train, dtype, f"{prefix}bn"))


class PReLU(nn.Module):
    """``max(x, 0) + a * min(x, 0)`` with one slope ``a`` per channel (PyTorch's init 0.25)."""

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        slope = self.param("slope", nn.initializers.constant(0.25), (x.shape[-1],), jnp.float32)
        return jnp.where(x >= 0, x, slope.astype(x.dtype) * x)


class Upsample2(nn.Module):
    """2x2 stride-2 transposed convolution without bias: each pixel becomes a 2x2 block,
    ``y[2i + k, 2j + l] = x[i, j] @ kernel[k, l].T``; ``kernel`` is (2, 2, out, in), PyTorch's
    ``ConvTranspose2d`` weight (in, out, 2, 2) transposed."""

    features: int
    dtype: Dtype = jnp.float32

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        init = nn.initializers.variance_scaling(1.0, "fan_in", "normal", in_axis=-1, out_axis=-2)
        kernel = self.param("kernel", init, (2, 2, self.features, x.shape[-1]), jnp.float32)
        b, h, w, _ = x.shape
        y = jnp.einsum("bhwi,kloi->bhkwlo", x, kernel.astype(self.dtype))
        return y.reshape(b, 2 * h, 2 * w, self.features)


class ESP(nn.Module):
    """The ESP module (see the module docstring); ``strided`` halves H and W."""

    features: int
    strided: bool = False
    residual: bool = True
    dtype: Dtype = jnp.float32

    @nn.compact
    def __call__(self, x: jax.Array, train: bool) -> jax.Array:
        n = self.features // 5
        reduced = _conv(n, 3 if self.strided else 1, self.dtype, "c1", stride=2 if self.strided else 1)(x)
        branches = [_conv(self.features - 4 * n, 3, self.dtype, "d1")(reduced)]
        fused = 0
        for d in DILATIONS:
            fused = fused + _conv(n, 3, self.dtype, f"d{d}", dilation=d)(reduced)
            branches.append(fused)
        y = jnp.concatenate(branches, axis=-1)
        if self.residual and not self.strided and x.shape[-1] == self.features:
            y = y + x
        return _bn_prelu(y, train, self.dtype)


def _input_pool(x: jax.Array) -> jax.Array:
    """3x3 average pool, stride 2, zero padding 1 counted in the average (PyTorch's AvgPool2d default)."""
    return nn.avg_pool(x, (3, 3), strides=(2, 2), padding=((1, 1), (1, 1)), count_include_pad=True)


class ESPNetEncoder(nn.Module):
    """Stages 1-3 -> (s1 at 1/2, t2 at 1/4, t3 at 1/8, c8 at 1/8), see the module docstring."""

    num_classes: int
    p: int
    q: int
    dtype: Dtype = jnp.float32

    @nn.compact
    def __call__(self, x: jax.Array, train: bool):
        half = _input_pool(x)
        quarter = _input_pool(half)
        s1 = _bn_prelu(_conv(16, 3, self.dtype, "level1", stride=2)(x), train, self.dtype, "level1_")
        t1 = _bn_prelu(jnp.concatenate([s1, half], -1), train, self.dtype, "b1_")
        d2 = ESP(64, strided=True, dtype=self.dtype, name="level2_down")(t1, train)
        y2 = d2
        for i in range(self.p):
            y2 = ESP(64, dtype=self.dtype, name=f"level2_{i}")(y2, train)
        t2 = _bn_prelu(jnp.concatenate([y2, d2, quarter], -1), train, self.dtype, "b2_")
        d3 = ESP(128, strided=True, dtype=self.dtype, name="level3_down")(t2, train)
        y3 = d3
        for i in range(self.q):
            y3 = ESP(128, dtype=self.dtype, name=f"level3_{i}")(y3, train)
        t3 = _bn_prelu(jnp.concatenate([d3, y3], -1), train, self.dtype, "b3_")
        return s1, t2, t3, _conv(self.num_classes, 1, self.dtype, "classifier")(t3)


class ESPNet(nn.Module):
    """ESPNet with the light decoder; ``__call__(images, train) -> {"logits", the attention module's
    outputs?}`` (module docstring). ``attention``, ``attention_position``, ``attention_options``:
    as ``DeepLabV3Plus``'s."""

    ATTENTION_POSITIONS = ("deep",)

    num_classes: int = 20
    p: int = 2
    q: int = 8
    dtype: Dtype = jnp.float32
    attention: str | None = None
    attention_position: str | None = None
    attention_options: tuple[tuple[str, object], ...] = ()

    normalize_input = staticmethod(normalize_espnet)  # uint8 RGB -> the input these weights expect

    def __post_init__(self):
        check_attachment(self)
        super().__post_init__()

    @nn.compact
    def __call__(self, images: jax.Array, train: bool = False) -> dict[str, jax.Array]:
        check_image_batch(images, 8, "normalised")
        c, dt, out = self.num_classes, self.dtype, {}
        s1, t2, t3, c8 = ESPNetEncoder(c, self.p, self.q, dt, name="encoder")(images.astype(dt), train)
        c8 = Attachment(self).at("deep", c8, {"low": t2, "mid": t3}, out)
        u4 = Upsample2(c, dt, name="up_l3")(_bn(c8, train, dt, "br"))
        p4 = _conv(c, 1, dt, "level3_C")(t2)
        x = _bn_prelu(jnp.concatenate([p4, u4], -1), train, dt, "combine_")
        x = ESP(c, residual=False, dtype=dt, name="combine_esp")(x, train)
        u2 = _bn_prelu(Upsample2(c, dt, name="up_l2")(x), train, dt, "up_l2_")
        x = _bn_prelu(_conv(c, 3, dt, "conv")(jnp.concatenate([u2, s1], -1)), train, dt, "conv_")
        return {**out, "logits": Upsample2(c, dt, name="classifier")(x).astype(jnp.float32)}
