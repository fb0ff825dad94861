"""Training losses: cross-entropy with ignore, balanced class weights, and the plain cross-entropy
objective (``CrossEntropy``, see ``jaxanom.objectives``). The papers' own terms sit in their packages
(``jaxanom.cudam.losses``, ``jaxanom.msaam.objective``) and build on these.

Every function takes a batch: logits ``(B, H, W, C)``, labels ``(B, H, W)`` int with ``ignore``
(255) on void pixels. They are pure and jit-friendly; shape agreement is checked on the static
shapes (so also under ``jit``), values are not. A batch with no valid pixel gives a loss of 0,
never NaN.
"""
from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import optax

from jaxanom._validate import check_number
from jaxanom.objectives import Objective, legacy_class_weights, register

IGNORE = 255


def check_pair(logits: jax.Array, labels: jax.Array) -> None:
    """ValueError unless ``logits`` are (B, H, W, C) and ``labels`` (B, H, W)."""
    if logits.ndim != 4:
        raise ValueError(f"logits: expected shape (B, H, W, C), got {logits.shape}")
    if labels.shape != logits.shape[:3]:
        raise ValueError(f"labels: expected shape {logits.shape[:3]} to match logits, got {labels.shape}")


def check_map(name: str, value: jax.Array, labels: jax.Array) -> None:
    """ValueError naming ``name`` unless the map ``value`` has the labels' shape."""
    if value.shape != labels.shape:
        raise ValueError(f"{name}: expected shape {labels.shape} (the labels' shape), got {value.shape}")


def valid_pixels(labels: jax.Array, ignore: int) -> jax.Array:
    """(B, H, W) bool: the labels that are not ``ignore``."""
    return labels != ignore


def cross_entropy(logits, labels, ignore: int = IGNORE, class_weights=None) -> jax.Array:
    """Mean softmax cross-entropy over valid pixels; float32 scalar.

    With ``class_weights`` (C,) it is the weighted mean ``sum w_y * nll / sum w_y`` (as
    PyTorch's ``CrossEntropyLoss(weight=..., ignore_index=...)``).
    """
    check_pair(logits, labels)
    num_classes = logits.shape[-1]
    valid = valid_pixels(labels, ignore)
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

    @classmethod
    def from_legacy_loss(cls, loss, own_terms):
        return cls(class_weights=legacy_class_weights(loss))

    def loss(self, outputs, batch, key, state, ignore):
        return cross_entropy(outputs["logits"], batch["label"], ignore, self.class_weights), {}, state
