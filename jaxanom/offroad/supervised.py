"""A fully supervised patch classifier: the off-road encoder's network trained on dense labels.

The baseline of Table III's "fully supervised" group at comparable capacity: ``PatchAlexNet`` with
the encoder's widths, its last layer giving ``classes`` logits (``EncoderConfig(dim=classes,
unit=False)``). Each step draws ``frames_per_step`` frames and ``patches_per_frame`` uniformly
random centres in each; a patch's target is its centre pixel's class (every pixel is labelled:
full labels; void 255 is left out of the mean softmax cross-entropy). Prediction is per window:
the argmax of its logits, voted into dense maps like the weakly supervised path (docs/papers/offroad.md#voting).
"""
from __future__ import annotations

import dataclasses
from functools import partial
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np
import optax

from jaxanom._validate import check_count, check_labels, check_range, check_rank
from jaxanom.offroad.encoder import EncoderConfig, init_encoder, run_updates
from jaxanom.offroad.patches import patches_batch

VOID = 255


def classifier_config(encoder: EncoderConfig, classes: int) -> EncoderConfig:
    """The encoder's settings with ``classes`` raw outputs (logits) in place of the unit embedding."""
    check_count("classes", classes)
    return dataclasses.replace(encoder, dim=int(classes), unit=False)


def patch_targets(labels: jax.Array, centers: jax.Array) -> jax.Array:
    """(F, H, W) labels, (F, P, 2) int centres -> (F, P): the class of each patch's centre pixel."""
    return jax.vmap(lambda lab, c: lab[c[:, 0], c[:, 1]])(labels, centers)


def masked_cross_entropy(logits: jax.Array, targets: jax.Array) -> jax.Array:
    """Mean softmax cross-entropy of ``logits (N, L)`` against ``targets (N,)`` over the non-void targets
    (0 when every target is void)."""
    keep = targets != VOID
    losses = optax.softmax_cross_entropy_with_integer_labels(logits, jnp.where(keep, targets, 0))
    return jnp.sum(jnp.where(keep, losses, 0.0)) / jnp.maximum(keep.sum(), 1)


@partial(jax.jit, static_argnames=("config", "patches_per_frame"), donate_argnums=(0, 1))
def _train_step(params, opt_state, key, images, labels, config: EncoderConfig, patches_per_frame: int):
    k_frames, k_rows, k_cols = jax.random.split(key, 3)
    count, height, width = labels.shape
    chosen = jax.random.choice(k_frames, count, (config.frames_per_step,), replace=count < config.frames_per_step)
    shape = (config.frames_per_step, patches_per_frame)
    centers = jnp.stack([jax.random.randint(k_rows, shape, 0, height), jax.random.randint(k_cols, shape, 0, width)], -1)
    x = patches_batch(images[chosen], centers, config.size, config.context)
    targets = patch_targets(labels[chosen], centers).reshape(-1)

    def loss_fn(p):
        logits = config.model().apply({"params": p}, x.reshape(-1, *x.shape[2:]))["embedding"]
        return masked_cross_entropy(logits, targets)

    loss, grads = jax.value_and_grad(loss_fn)(params)
    updates, opt_state = optax.adam(config.lr).update(grads, opt_state, params)
    return optax.apply_updates(params, updates), opt_state, loss


def train_classifier(key, images, labels, config: EncoderConfig, *, steps: int, patches_per_frame: int,
                     progress: Callable | None = None) -> tuple[object, np.ndarray]:
    """Train from scratch on ``images (F, H, W, 3)`` in [0, 1] with dense ``labels (F, H, W)`` in
    [0, config.dim) or 255; ``config`` from ``classifier_config``. Returns ``(params, losses (steps,))``."""
    if config.unit:
        raise ValueError("config: expected a classifier config (unit=False, from classifier_config), got unit=True")
    check_rank("images", images, 4, "(F, H, W, 3)")
    check_rank("labels", labels, 3, "(F, H, W)")
    if np.shape(images)[:3] != np.shape(labels):
        raise ValueError(f"labels: expected the images' (F, H, W) {np.shape(images)[:3]}, got {np.shape(labels)}")
    check_range("images", images, 0.0, 1.0)
    check_labels("labels", labels, config.dim, void=VOID)
    check_count("steps", steps)
    check_count("patches_per_frame", patches_per_frame)
    k_init, k_train = jax.random.split(key)
    params = init_encoder(k_init, config)
    opt_state = optax.adam(config.lr).init(params)
    images, labels = jnp.asarray(images, jnp.float32), jnp.asarray(labels, jnp.int32)
    return run_updates(lambda params, opt_state, key: _train_step(params, opt_state, key, images, labels, config,
                                                                  int(patches_per_frame)),
                       params, opt_state, k_train, steps, progress)
