"""Queries, positives and negatives for InfoNCE from per-frame patch annotations (docs/papers/offroad.md#infonce).

Label ids are comparable only within a frame (the annotator renumbers them per image), so every
pair is drawn inside one frame. Each anchor j of a frame gives two augmented patches: ``view_j``
at its own centre (the query) and ``near_j`` at a random neighbour centre (``neighbour_centers``).
For the query of anchor i:

- positive: ``near_j`` for j drawn uniformly from ``P_i = {j != i : id_j = id_i}``, or
  ``near_i`` (its own neighbourhood) when that set is empty (a label with one anchor);
- negatives: ``near_j`` for ``n`` draws of j with replacement from ``N_i = {j : id_j != id_i}``;
- mask: anchor i is valid and ``N_i`` is not empty.

All queries of a frame share its ``near`` patches (one neighbour sample per anchor and step), so
a step encodes 2 A patches per frame instead of A (n + 2); see docs/decisions/offroad-pipeline.md.
Pure JAX.
"""
from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp

from jaxanom.offroad.patches import augment, neighbour_centers, patch_sample


def _draw(key, allowed: jax.Array, shape: tuple) -> jax.Array:
    """Indices drawn uniformly from the true entries of ``allowed`` (A,) (uniform over all if none)."""
    logits = jnp.where(allowed.any(), jnp.where(allowed, 0.0, -jnp.inf), 0.0)
    return jax.random.categorical(key, logits, shape=shape)


def _frame_pairs(key, image, centers, ids, valid, size: int, negatives: int, context: int):
    a = centers.shape[0]
    k_pos, k_neg, k_near, k_aug = jax.random.split(key, 4)
    same = (ids[:, None] == ids[None, :]) & valid[None, :] & ~jnp.eye(a, dtype=bool)
    other = (ids[:, None] != ids[None, :]) & valid[None, :]
    pos = jax.vmap(lambda k, s, i: jnp.where(s.any(), _draw(k, s, ()), i))(jax.random.split(k_pos, a), same, jnp.arange(a))
    neg = jax.vmap(lambda k, o: _draw(k, o, (negatives,)))(jax.random.split(k_neg, a), other)
    near = neighbour_centers(k_near, centers, size, 1, image.shape[0], image.shape[1])[:, 0]
    raw = jax.vmap(lambda c: patch_sample(image, c, size, context))(jnp.concatenate([centers, near]))
    views = jax.vmap(augment)(jax.random.split(k_aug, 2 * a), raw)
    return views[:a], views[a:], pos, neg, valid & other.any(axis=1)


@partial(jax.jit, static_argnames=("size", "negatives", "context"))
def contrastive_batch(key, images, centers, ids, valid, size: int, negatives: int = 16, context: int = 2) -> dict:
    """Pairs from ``F`` annotated frames with ``A`` anchor slots each (padding has ``valid = False``).

    images (F, H, W, 3) float [0, 1]; centers (F, A, 2) int; ids (F, A) int; valid (F, A) bool.
    Returns ``"query"`` (F, A, s, s, 6) and ``"near"`` (F, A, s, s, 6) patches,
    ``"positive_index"`` (F, A) and ``"negative_index"`` (F, A, n) anchor indices into ``near``
    of the same frame, and ``"mask"`` (F, A) bool.
    """
    keys = jax.random.split(key, images.shape[0])
    query, near, pos, neg, mask = jax.vmap(
        lambda k, im, c, i, v: _frame_pairs(k, im, c, i, v, size, negatives, context))(keys, images, centers, ids, valid)
    return {"query": query, "near": near, "positive_index": pos, "negative_index": neg, "mask": mask}


def gather_pairs(z_query: jax.Array, z_near: jax.Array, batch: dict) -> tuple[jax.Array, jax.Array, jax.Array, jax.Array]:
    """Embeddings (F, A, D) of queries and near patches -> InfoNCE inputs
    ``z (F A, D), z_pos (F A, D), z_neg (F A, n, D), mask (F A,)``."""
    take = jax.vmap(lambda zn, idx: zn[idx])
    z_pos, z_neg = take(z_near, batch["positive_index"]), take(z_near, batch["negative_index"])
    flat = lambda x: x.reshape(-1, *x.shape[2:])  # noqa: E731
    return flat(z_query), flat(z_pos), flat(z_neg), flat(batch["mask"])
