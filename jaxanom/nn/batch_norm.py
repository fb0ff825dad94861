"""BatchNorm over all axes but the last, with its training-mode gradient written out.

The variables, statistics and running averages are ``flax.linen.BatchNorm``'s (``scale``, ``bias``;
``batch_stats`` ``mean``, ``var``; biased batch variance E[x^2] - E[x]^2 in float32; running value
``momentum * old + (1 - momentum) * batch``), so weights and checkpoints carry over. In training
the backward pass is the closed form (Ioffe & Szegedy 2015, Sec. 3), with the two channel sums it
needs taken in one pass:

    dx = scale / sigma * (g - mean(g) - x_hat * mean(g * x_hat)),
    dscale = sum(g * x_hat),  dbias = sum(g),

where autodiff of the forward pass leaves XLA three reductions per layer in the backward pass
(and two in the forward), each recomputing the incoming gradient (on the CPU, writing it out saved
about 11% of DeepLabV3+ R101's training step: docs/decisions/cpu-speed.md).
"""
from __future__ import annotations

import functools
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp


def _channel_sums(a: jax.Array, b: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Sums of ``a`` and ``b`` over every axis but the last, in one reduction."""
    zero = jnp.zeros((), a.dtype)
    return jax.lax.reduce((a, b), (zero, zero), lambda p, q: (p[0] + q[0], p[1] + q[1]),
                          tuple(range(a.ndim - 1)))


def _forward(x, scale, bias, epsilon):
    count = x.size // x.shape[-1]
    total, total_sq = _channel_sums(x, x * x)
    mean = total / count
    var = jnp.maximum(0.0, total_sq / count - mean * mean)
    inv_sigma = jax.lax.rsqrt(var + epsilon)
    return ((x - mean) * (inv_sigma * scale) + bias, mean, var), (x, mean, inv_sigma, scale)


def _backward(epsilon, residuals, cotangents):
    x, mean, inv_sigma, scale = residuals
    g = cotangents[0]  # the statistics' cotangents: they feed only the running averages
    count = x.size // x.shape[-1]
    x_hat = (x - mean) * inv_sigma
    sum_g, sum_g_xhat = _channel_sums(g, g * x_hat)
    dx = (scale * inv_sigma) * (g - sum_g / count - x_hat * (sum_g_xhat / count))
    return dx, sum_g_xhat, sum_g


@functools.partial(jax.custom_vjp, nondiff_argnums=(3,))
def batch_norm_train(x: jax.Array, scale: jax.Array, bias: jax.Array, epsilon: float
                     ) -> tuple[jax.Array, jax.Array, jax.Array]:
    """``x`` (..., C) float normalised with its own statistics: ``(y, mean (C,), biased var (C,))``.
    Only ``y`` carries gradients: the statistics feed the running averages, so their cotangents are dropped."""
    return _forward(x, scale, bias, epsilon)[0]


batch_norm_train.defvjp(lambda x, scale, bias, epsilon: _forward(x, scale, bias, epsilon), _backward)


class BatchNorm(nn.Module):
    """BatchNorm of the last axis; batch statistics and running-average updates when
    ``use_running_average`` is false. Statistics in float32, output in ``dtype``."""

    use_running_average: bool
    momentum: float
    epsilon: float
    dtype: Any = jnp.float32

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        channels = x.shape[-1]
        scale = self.param("scale", nn.initializers.ones, (channels,), jnp.float32)
        bias = self.param("bias", nn.initializers.zeros, (channels,), jnp.float32)
        running_mean = self.variable("batch_stats", "mean", jnp.zeros, (channels,), jnp.float32)
        running_var = self.variable("batch_stats", "var", jnp.ones, (channels,), jnp.float32)
        x = x.astype(jnp.promote_types(x.dtype, jnp.float32))
        if self.use_running_average:
            y = (x - running_mean.value) * (jax.lax.rsqrt(running_var.value + self.epsilon) * scale) + bias
        else:
            y, mean, var = batch_norm_train(x, scale, bias, self.epsilon)
            if not self.is_initializing():
                running_mean.value = self.momentum * running_mean.value + (1 - self.momentum) * mean
                running_var.value = self.momentum * running_var.value + (1 - self.momentum) * var
        return y.astype(self.dtype)
