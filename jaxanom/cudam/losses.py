"""CuDAM's training terms: the reward (Eq. 4), the attention loss (Eq. 7) and the self-regulated
lambda (Eq. 9); ``jaxanom.cudam.objective`` combines them with the cross-entropy (Eq. 8).

Every function takes a batch: logits ``(B, H, W, C)``, labels ``(B, H, W)`` int with ``ignore``
(255) on void pixels, attention ``(B, H, W)`` already upsampled to label size, anomaly scores
``(B, H, W)`` (higher = more anomalous). They are pure and jit-friendly; shape agreement is
checked on the static shapes (so also under ``jit``), values are not.

Decisions where the paper is silent (see docs/papers/sml-cudam-msaam.md):

- A batch with no valid pixel gives a loss of 0 (and lambda 0), never NaN.
- The attention loss (Eq. 7) sums over the pixels of an image, as printed, and averages over the
  images of the batch, so it does not grow with the batch size. psi is the mean attention over
  one image's correctly predicted pixels (the map sums to 1 per image).
"""
from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxanom.losses import IGNORE, check_map, check_pair, valid_pixels


def reward_logits(logits, attention_up, labels, tau: float = 5e4, ignore: int = IGNORE) -> jax.Array:
    """CuDAM reward (Eq. 4): ``P = tau * up(M_att) * onehot(G) + P_a`` on valid pixels only.

    Returns float32 logits (B, H, W, C); void pixels keep ``P_a`` unchanged.
    """
    check_pair(logits, labels)
    check_map("attention_up", attention_up, labels)
    valid = valid_pixels(labels, ignore)
    onehot = jax.nn.one_hot(jnp.where(valid, labels, 0), logits.shape[-1], dtype=jnp.float32)
    reward = tau * attention_up.astype(jnp.float32)[..., None] * onehot * valid[..., None]
    return logits.astype(jnp.float32) + reward


def study_logits(key, logits, attention_up, labels, tau: float = 5e4, reward_prob: float = 0.5,
                 ignore: int = IGNORE) -> tuple[jax.Array, jax.Array]:
    """One CuDAM iteration's logits: rewarded with probability ``reward_prob`` ("study"), else not ("exam").

    ``key`` is this iteration's PRNG key. Returns ``(P, study)``: float32 logits (B, H, W, C) and a
    bool scalar telling whether the reward was given. Never use it at evaluation.
    """
    study = jax.random.bernoulli(key, reward_prob)
    rewarded = reward_logits(logits, attention_up, labels, tau, ignore)
    return jnp.where(study, rewarded, logits.astype(jnp.float32)), study


def _correct(logits, labels, ignore):
    return valid_pixels(labels, ignore) & (jnp.argmax(logits, axis=-1) == labels)


def attention_loss(attention_up, logits, labels, anomaly_score, beta: float = 0.5,
                   literal: bool = False, ignore: int = IGNORE) -> jax.Array:
    """CuDAM attention loss (Eq. 7); float32 scalar.

    ``logits`` are the model's own ``P_a`` (no reward): a pixel is correct where
    ``argmax P_a == label``, incorrect where it is valid and not correct. Per image,
    ``psi`` = mean attention over correct pixels (stop-gradient); the penalised pixels are the
    incorrect ones with ``m < beta * psi``, weighted by ``exp(k)``, k = ``anomaly_score``
    (stop-gradient).

    - default (the paper's stated aim, more attention on uncertain pixels):
      ``sum exp(k) * (beta * psi - m)``, which falls as those pixels' attention rises;
    - ``literal=True`` (the printed formula): ``sum exp(k) * m``, which pushes it down.

    Summed over pixels, averaged over images. An image with no correct pixel contributes 0.
    """
    check_pair(logits, labels)
    check_map("attention_up", attention_up, labels)
    check_map("anomaly_score", anomaly_score, labels)
    m = attention_up.astype(jnp.float32)
    correct = _correct(logits, labels, ignore)
    incorrect = valid_pixels(labels, ignore) & ~correct
    n_correct = jnp.sum(correct, axis=(1, 2))
    psi = jnp.sum(jnp.where(correct, m, 0.0), axis=(1, 2)) / jnp.maximum(n_correct, 1)
    threshold = jax.lax.stop_gradient(beta * psi)[:, None, None]
    penalised = incorrect & (m < threshold)
    weight = jnp.exp(jax.lax.stop_gradient(anomaly_score.astype(jnp.float32)))
    per_pixel = m if literal else threshold - m
    per_image = jnp.sum(jnp.where(penalised, weight * per_pixel, 0.0), axis=(1, 2))
    return jnp.mean(per_image)


def self_regulated_lambda(logits, labels, ignore: int = IGNORE) -> jax.Array:
    """CuDAM's weight of the attention loss (Eq. 9): ``a_correct / a_total`` over the batch's valid pixels.

    Stop-gradient float32 scalar in [0, 1]; 0 when there is no valid pixel.
    """
    check_pair(logits, labels)
    correct = jnp.sum(_correct(logits, labels, ignore))
    total = jnp.sum(valid_pixels(labels, ignore))
    return jax.lax.stop_gradient(correct / jnp.maximum(total, 1)).astype(jnp.float32)
