"""Training losses: cross-entropy with ignore, CuDAM reward / attention loss / lambda, MSAAM loss,
and the plain cross-entropy objective (``CrossEntropy``, see ``jaxanom.objectives``).

Every function takes a batch: logits ``(B, H, W, C)``, labels ``(B, H, W)`` int with ``ignore``
(255) on void pixels, attention ``(B, H, W)`` already upsampled to label size, anomaly scores
``(B, H, W)`` (higher = more anomalous). They are pure and jit-friendly; shape agreement is
checked on the static shapes (so also under ``jit``), values are not.

Decisions where the papers are silent (see docs/papers/sml-cudam-msaam.md):

- A batch with no valid pixel gives a loss of 0 (and lambda 0), never NaN.
- The CuDAM attention loss (Eq. 7) sums over the pixels of an image, as printed, and averages
  over the images of the batch, so it does not grow with the batch size. psi is the mean
  attention over one image's correctly predicted pixels (the map sums to 1 per image).
- The MSAAM variance (Eq. 7) is the population variance of the three branch weights of one
  image (the text asks for different weights "across scale, space and channel"), averaged
  over the batch.
"""
from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import optax

from jaxanom._validate import check_number
from jaxanom.objectives import Objective, register

IGNORE = 255


def _check_pair(logits: jax.Array, labels: jax.Array) -> None:
    if logits.ndim != 4:
        raise ValueError(f"logits: expected shape (B, H, W, C), got {logits.shape}")
    if labels.shape != logits.shape[:3]:
        raise ValueError(f"labels: expected shape {logits.shape[:3]} to match logits, got {labels.shape}")


def _check_map(name: str, value: jax.Array, labels: jax.Array) -> None:
    if value.shape != labels.shape:
        raise ValueError(f"{name}: expected shape {labels.shape} (the labels' shape), got {value.shape}")


def _valid(labels: jax.Array, ignore: int) -> jax.Array:
    return labels != ignore


def cross_entropy(logits, labels, ignore: int = IGNORE, class_weights=None) -> jax.Array:
    """Mean softmax cross-entropy over valid pixels; float32 scalar.

    With ``class_weights`` (C,) it is the weighted mean ``sum w_y * nll / sum w_y`` (as
    PyTorch's ``CrossEntropyLoss(weight=..., ignore_index=...)``).
    """
    _check_pair(logits, labels)
    num_classes = logits.shape[-1]
    valid = _valid(labels, ignore)
    safe = jnp.where(valid, labels, 0)
    nll = optax.softmax_cross_entropy_with_integer_labels(logits.astype(jnp.float32), safe)
    if class_weights is None:
        weight = valid.astype(jnp.float32)
    else:
        class_weights = jnp.asarray(class_weights, jnp.float32)
        if class_weights.shape != (num_classes,):
            raise ValueError(f"class_weights: expected shape ({num_classes},), got {class_weights.shape}")
        weight = jnp.where(valid, class_weights[safe], 0.0)
    return jnp.sum(weight * nll) / jnp.maximum(jnp.sum(weight), jnp.finfo(jnp.float32).tiny)


def balanced_class_weights(labels, num_classes: int, ignore: int = IGNORE) -> np.ndarray:
    """Class weights ``w_c = N / (C N_c)`` (float64 (C,)) from host labels, ``ignore`` left out:
    scikit-learn's ``"balanced"``; with them ``cross_entropy`` averages the per-class mean losses.
    A class with no pixel gets 0. ValueError when no label is valid."""
    labels = np.asarray(labels).ravel()
    counts = np.bincount(labels[labels != ignore], minlength=num_classes).astype(np.float64)
    if counts.size != num_classes:
        raise ValueError(f"labels: expected values in [0, {num_classes}) or {ignore}, got up to {counts.size - 1}")
    if not counts.sum():
        raise ValueError(f"labels: expected at least one label other than {ignore}, got none")
    return np.where(counts > 0, counts.sum() / (num_classes * np.maximum(counts, 1)), 0.0)


def reward_logits(logits, attention_up, labels, tau: float = 5e4, ignore: int = IGNORE) -> jax.Array:
    """CuDAM reward (Eq. 4): ``P = tau * up(M_att) * onehot(G) + P_a`` on valid pixels only.

    Returns float32 logits (B, H, W, C); void pixels keep ``P_a`` unchanged.
    """
    _check_pair(logits, labels)
    _check_map("attention_up", attention_up, labels)
    valid = _valid(labels, ignore)
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
    return _valid(labels, ignore) & (jnp.argmax(logits, axis=-1) == labels)


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
    _check_pair(logits, labels)
    _check_map("attention_up", attention_up, labels)
    _check_map("anomaly_score", anomaly_score, labels)
    m = attention_up.astype(jnp.float32)
    correct = _correct(logits, labels, ignore)
    incorrect = _valid(labels, ignore) & ~correct
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
    _check_pair(logits, labels)
    correct = jnp.sum(_correct(logits, labels, ignore))
    total = jnp.sum(_valid(labels, ignore))
    return jax.lax.stop_gradient(correct / jnp.maximum(total, 1)).astype(jnp.float32)


def msaam_loss(logits, labels, branch_weights, lam: float, literal: bool = False,
               ignore: int = IGNORE, class_weights=None) -> jax.Array:
    """MSAAM loss (Eq. 7): cross-entropy -/+ ``lam`` * variance of the branch weights; float32 scalar.

    ``branch_weights`` (B, 3) are (alpha_sc, alpha_sp, alpha_c) per image. The default subtracts
    the variance (the text wants high variance); ``literal=True`` adds it, as printed.
    """
    _check_pair(logits, labels)
    if branch_weights.ndim != 2 or branch_weights.shape[0] != logits.shape[0]:
        raise ValueError(f"branch_weights: expected shape ({logits.shape[0]}, n_branches), got {branch_weights.shape}")
    variance = jnp.mean(jnp.var(branch_weights.astype(jnp.float32), axis=1))
    sign = 1.0 if literal else -1.0
    return cross_entropy(logits, labels, ignore, class_weights) + sign * lam * variance


def check_class_weights(class_weights) -> None:
    """ValueError unless ``class_weights`` is None or finite numbers >= 0 (the class count is checked
    against the logits when the loss is traced)."""
    for index, weight in enumerate(class_weights or ()):
        check_number(f"class_weights[{index}]", weight, 0.0)


@register
@dataclasses.dataclass(frozen=True)
class CrossEntropy(Objective):
    """Softmax cross-entropy over the valid pixels (``cross_entropy``), optionally class-weighted;
    reads the logits only, keeps no state."""

    class_weights: tuple[float, ...] | None = None
    name: str = dataclasses.field(default="cross_entropy", init=False)

    def __post_init__(self):
        check_class_weights(self.class_weights)

    def loss(self, outputs, batch, key, state, ignore):
        return cross_entropy(outputs["logits"], batch["label"], ignore, self.class_weights), {}, state
