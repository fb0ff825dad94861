"""Per-pixel anomaly scores from segmentation logits.

Every score takes logits ``(H, W, C)`` (any float dtype; computed in float32) and returns a
float32 map ``(H, W)`` in which *higher means more anomalous*. The public functions check their
input's rank, C and dtype, and NaN/Inf in a host (NumPy) input, and raise ``ValueError``; a
``jax.Array`` is not read back for it (``jaxanom.validate_values`` asks for that). The
``*_batch`` entry points take ``(B, H, W, C)``, validate, then call a ``jax.jit(jax.vmap(...))``
built once at import.
"""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxanom._validate import check_finite, check_rank, check_real, check_static, values_checked
from jaxanom.errors import InputError


def _checked(logits, *, batched: bool = False, min_classes: int = 1) -> jax.Array:
    if batched:
        check_rank("logits", logits, 4, "(B, H, W, C)")
    else:
        check_rank("logits", logits, 3, "(H, W, C)")
    if np.shape(logits)[-1] < min_classes:
        raise ValueError(f"logits need C >= {min_classes} classes here, got C={np.shape(logits)[-1]}")
    check_real("logits", logits)
    check_finite("logits", logits)
    return jnp.asarray(logits, jnp.float32)


def _check_temperature(temperature) -> None:
    """T > 0 where its value is on the host; a traced T (jit / vmap over a grid) is not read."""
    if np.ndim(temperature) != 0:
        raise InputError("temperature", f"must be a scalar (vmap over a grid of temperatures), got shape "
                         f"{np.shape(temperature)}")
    if values_checked(temperature) and not temperature > 0:
        raise ValueError(f"temperature must be > 0, got {temperature}")


def _msp(logits: jax.Array) -> jax.Array:
    # 1 - p_max = s / (1 + s) with s = sum over the other classes of exp(F_c - F_max): keeps
    # its precision on confident pixels, where 1 - p_max would round to 0 and tie them all.
    top = jnp.argmax(logits, axis=-1)[..., None]
    others = jnp.where(jnp.arange(logits.shape[-1]) == top, 0.0, jnp.exp(logits - jnp.max(logits, axis=-1, keepdims=True)))
    s = jnp.sum(others, axis=-1)
    return s / (1.0 + s)


def _max_logit(logits: jax.Array) -> jax.Array:
    return -jnp.max(logits, axis=-1)


def _entropy(logits: jax.Array, normalize: bool = False) -> jax.Array:
    log_p = jax.nn.log_softmax(logits, axis=-1)
    h = -jnp.sum(jnp.exp(log_p) * log_p, axis=-1)
    return h / jnp.log(logits.shape[-1]) if normalize else h


def _energy(logits: jax.Array, temperature=1.0) -> jax.Array:
    return -temperature * jax.nn.logsumexp(logits / temperature, axis=-1)


def _softmax_distance(logits: jax.Array) -> jax.Array:
    top2 = jax.lax.top_k(jax.nn.softmax(logits, axis=-1), 2)[0]
    return 1.0 - top2[..., 0] + top2[..., 1]


# Built once at import: single images, and jax.jit(jax.vmap(...)) over a leading batch axis.
_msp_jit = jax.jit(_msp)
_max_logit_jit = jax.jit(_max_logit)
_entropy_jit = jax.jit(_entropy, static_argnums=1)
_energy_jit = jax.jit(_energy)
_softmax_distance_jit = jax.jit(_softmax_distance)
_msp_batch = jax.jit(jax.vmap(_msp))
_max_logit_batch = jax.jit(jax.vmap(_max_logit))
_entropy_batch = jax.jit(jax.vmap(_entropy, in_axes=(0, None)), static_argnums=1)
_energy_batch = jax.jit(jax.vmap(_energy, in_axes=(0, None)))
_softmax_distance_batch = jax.jit(jax.vmap(_softmax_distance))


def msp(logits) -> jax.Array:
    """Maximum softmax probability as an anomaly score, ``1 - max_c p_c``: ``(H, W, C) -> (H, W)`` in [0, 1)."""
    return _msp_jit(_checked(logits))


def max_logit(logits) -> jax.Array:
    """Negative max logit ``-max_c F_c`` (SML paper's baseline): ``(H, W, C) -> (H, W)``."""
    return _max_logit_jit(_checked(logits))


def entropy(logits, normalize: bool = False) -> jax.Array:
    """Softmax entropy ``-sum_c p_c log p_c`` in nats: ``(H, W, C) -> (H, W)``.

    ``normalize=True`` divides by ``log C`` (needs C >= 2), giving [0, 1]: MMF Eq. 1 normalised
    to [0, 1] as the MMF paper asks (the logarithm's base cancels). ``normalize`` is static.
    """
    check_static("normalize", normalize, "chooses the formula")
    return _entropy_jit(_checked(logits, min_classes=2 if normalize else 1), normalize)


def energy(logits, temperature: float = 1.0) -> jax.Array:
    """Free energy ``-T logsumexp(F / T)`` (Liu et al. 2020), T > 0: ``(H, W, C) -> (H, W)``.
    ``temperature`` may be traced (``jax.jit`` / ``vmap`` over a grid of temperatures)."""
    _check_temperature(temperature)
    return _energy_jit(_checked(logits), jnp.float32(temperature))


def softmax_distance(logits) -> jax.Array:
    """MMF Eq. 2, ``D = 1 - p_(1) + p_(2)`` from the two largest softmax values, C >= 2: ``(H, W, C) -> (H, W)``.

    D already lies in [0, 1] (0: one certain class, 1: two classes tied), so it needs no
    further normalisation.
    """
    return _softmax_distance_jit(_checked(logits, min_classes=2))


def msp_batch(logits) -> jax.Array:
    """``msp`` over a batch: ``(B, H, W, C) -> (B, H, W)``."""
    return _msp_batch(_checked(logits, batched=True))


def max_logit_batch(logits) -> jax.Array:
    """``max_logit`` over a batch: ``(B, H, W, C) -> (B, H, W)``."""
    return _max_logit_batch(_checked(logits, batched=True))


def entropy_batch(logits, normalize: bool = False) -> jax.Array:
    """``entropy`` over a batch: ``(B, H, W, C) -> (B, H, W)``."""
    check_static("normalize", normalize, "chooses the formula")
    return _entropy_batch(_checked(logits, batched=True, min_classes=2 if normalize else 1), normalize)


def energy_batch(logits, temperature: float = 1.0) -> jax.Array:
    """``energy`` over a batch: ``(B, H, W, C) -> (B, H, W)``; the temperature is traced, so no recompiles."""
    _check_temperature(temperature)
    return _energy_batch(_checked(logits, batched=True), jnp.float32(temperature))


def softmax_distance_batch(logits) -> jax.Array:
    """``softmax_distance`` over a batch: ``(B, H, W, C) -> (B, H, W)``."""
    return _softmax_distance_batch(_checked(logits, batched=True, min_classes=2))
