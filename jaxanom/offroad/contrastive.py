"""InfoNCE over label-defined positives and negatives (off-road paper, Eq. 2).

Per query ``q``: ``l = -log(exp(z.z+/tau) / (exp(z.z+/tau) + sum_i exp(z.z-_i/tau)))``, computed
as ``logsumexp([z.z+, z.z-_1..n] / tau) - z.z+/tau`` (stable for any tau), averaged over the
queries whose ``mask`` is true. Embeddings are used as given (the encoder L2-normalises them).
"""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxanom._validate import check_finite, check_rank, values_checked


def info_nce_per_query(z: jax.Array, z_pos: jax.Array, z_neg: jax.Array, temperature) -> jax.Array:
    """Eq. 2 per query: ``(Q, D), (Q, D), (Q, n, D) -> (Q,)`` float32. Pure (no checks)."""
    pos = jnp.sum(z * z_pos, axis=-1) / temperature
    neg = jnp.einsum("qd,qnd->qn", z, z_neg) / temperature
    return jax.nn.logsumexp(jnp.concatenate([pos[:, None], neg], axis=-1), axis=-1) - pos


def info_nce(z, z_pos, z_neg, mask=None, temperature=0.1) -> jax.Array:
    """Mean Eq. 2 loss over the masked queries (0 when none is): a float32 scalar.

    ``z`` queries ``(Q, D)``, ``z_pos`` their positives ``(Q, D)``, ``z_neg`` their ``n``
    negatives ``(Q, n, D)`` (n >= 0), ``mask`` ``(Q,)`` bool (default all true), ``temperature``
    tau > 0. Shapes are checked always, values only outside jit; differentiable.
    """
    check_rank("z", z, 2, "(Q, D)")
    q, d = np.shape(z)
    if np.shape(z_pos) != (q, d):
        raise ValueError(f"z_pos must have the shape of z (Q, D) = {(q, d)}, got {np.shape(z_pos)}")
    check_rank("z_neg", z_neg, 3, "(Q, n, D)")
    if np.shape(z_neg)[0] != q or np.shape(z_neg)[2] != d:
        raise ValueError(f"z_neg must have shape (Q, n, D) with Q={q}, D={d}, got {np.shape(z_neg)}")
    if mask is not None and np.shape(mask) != (q,):
        raise ValueError(f"mask must have shape (Q,) = {(q,)}, got {np.shape(mask)}")
    if values_checked(temperature) and not float(temperature) > 0:
        raise ValueError(f"temperature must be > 0, got {temperature}")
    for name, x in (("z", z), ("z_pos", z_pos), ("z_neg", z_neg)):
        check_finite(name, x)
    losses = info_nce_per_query(jnp.asarray(z, jnp.float32), jnp.asarray(z_pos, jnp.float32),
                                jnp.asarray(z_neg, jnp.float32), temperature)
    weight = jnp.ones((q,), jnp.float32) if mask is None else jnp.asarray(mask, jnp.float32)
    return jnp.sum(weight * losses) / jnp.maximum(jnp.sum(weight), 1.0)
