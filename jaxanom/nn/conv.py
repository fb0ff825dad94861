"""2D convolution, channels-last, with a CPU path as one matrix product of the input's patches.

On the CPU, XLA's own convolution needs its operands in one canonical layout, so the gradients of
a convolution (input: the kernel reversed and transposed; kernel: the activations with channels
first) cost a transposed copy of every kernel and of every activation in each training step, and
the 1x1 convolutions' kernel gradients become convolutions with a window the size of the image.
Written as a product of matrices (im2col), forward and backward are three dots whose operands XLA
reads in place; the time and where it goes are in docs/decisions/cpu-speed.md. Elsewhere (GPU,
TPU) ``lax.conv_general_dilated``, which cuDNN and the TPU compiler do well.
"""
from __future__ import annotations

import functools
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp

MAX_PATCH_BYTES = 2**30  # the most memory one convolution's patches may take on the CPU path
# Narrower inputs keep XLA's convolution: their patch products are slower than it and compile
# slower (measured per threshold in docs/decisions/cpu-speed.md, "Which convolutions").
MIN_PATCH_CHANNELS = 128


def _live_taps(size: int, kernel: int, stride: int, dilation: int, pad: int) -> tuple[int, int, int]:
    """(output size, first, last + 1) of the kernel taps along one axis that read some input pixel:
    the others read only the zero padding (e.g. a 3x3 kernel with dilation 12 on an 8x8 map)."""
    out = (size + 2 * pad - dilation * (kernel - 1) - 1) // stride + 1
    live = [i for i in range(kernel) if any(pad <= i * dilation + stride * o < pad + size for o in range(out))]
    return out, live[0], live[-1] + 1


def conv2d_patches(x: jax.Array, kernel: jax.Array, stride: int = 1, dilation: int = 1,
                   pad: int = 0) -> jax.Array:
    """``x`` (B, H, W, Cin) convolved with ``kernel`` (k, k, Cin, Cout), zero padding ``pad`` per side.

    The same as ``lax.conv_general_dilated`` (NHWC, HWIO) up to float rounding: the patches of
    the taps that touch the image, concatenated along channels (B, Ho, Wo, taps * Cin), times the
    matching rows of the kernel. Taps that read only padding add exact zeros and are left out.
    Rematerialised: the backward pass keeps ``x``, not its patches (taps times larger), and
    gathers them again. The forward pass still holds one layer's patches at a time.
    """
    product = functools.partial(_patch_product, stride=stride, dilation=dilation, pad=pad)
    return jax.checkpoint(product)(x, kernel)


def _patch_product(x, kernel, stride, dilation, pad):
    kh, kw, _, cout = kernel.shape
    ho, i0, i1 = _live_taps(x.shape[1], kh, stride, dilation, pad)
    wo, j0, j1 = _live_taps(x.shape[2], kw, stride, dilation, pad)
    padded = jnp.pad(x, ((0, 0), (pad, pad), (pad, pad), (0, 0))) if pad else x
    taps = [padded[:, i * dilation: i * dilation + stride * (ho - 1) + 1: stride,
                   j * dilation: j * dilation + stride * (wo - 1) + 1: stride, :]
            for i in range(i0, i1) for j in range(j0, j1)]
    patches = taps[0] if len(taps) == 1 else jnp.concatenate(taps, axis=-1)
    return jnp.einsum("bhwk,ko->bhwo", patches, kernel[i0:i1, j0:j1].reshape(-1, cout))


class Conv2D(nn.Module):
    """``k x k`` convolution without bias, symmetric padding ``dilation * (k - 1) // 2`` (PyTorch's).

    Parameters as ``flax.linen.Conv``'s (``kernel`` (k, k, Cin, Cout), float32), so weights and
    checkpoints carry over. On the CPU (``jax.default_backend()`` when traced) ``conv2d_patches``
    for inputs of at least ``MIN_PATCH_CHANNELS`` channels whose patches take at most
    ``MAX_PATCH_BYTES`` (e.g. DeepLab's ASPP on a full 1024x2048 frame would need 2.4 GB), else and
    elsewhere ``lax.conv_general_dilated``; ``dtype`` is the compute dtype.
    """

    features: int
    kernel_size: int = 3
    stride: int = 1
    dilation: int = 1
    dtype: Any = jnp.float32

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        k = self.kernel_size
        kernel = self.param("kernel", nn.initializers.variance_scaling(2.0, "fan_out", "normal"),
                            (k, k, x.shape[-1], self.features), jnp.float32)
        x, kernel = x.astype(self.dtype), kernel.astype(self.dtype)
        pad = self.dilation * (k - 1) // 2
        patch_bytes = x.size * k * k * x.dtype.itemsize // self.stride**2
        if jax.default_backend() == "cpu" and x.shape[-1] >= MIN_PATCH_CHANNELS and patch_bytes <= MAX_PATCH_BYTES:
            return conv2d_patches(x, kernel, self.stride, self.dilation, pad)
        return jax.lax.conv_general_dilated(x, kernel, (self.stride,) * 2, [(pad, pad)] * 2,
                                            rhs_dilation=(self.dilation,) * 2,
                                            dimension_numbers=("NHWC", "HWIO", "NHWC"))
