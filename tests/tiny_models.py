"""A tiny Flax model honouring the jaxanom.models contract, for the training tests.

``TinySegNet(num_classes, head)``: conv + BatchNorm at input size, a stride-2 feature map, and
logits (B, H, W, C) at input size. ``head="cudam"`` adds ``"attention"`` (B, H/2, W/2), a
softmax over each image's positions; ``head="msaam"`` adds ``"branch_weights"`` (B, 3).
"""
from __future__ import annotations

import functools

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np


class TinySegNet(nn.Module):
    num_classes: int = 3
    head: str = "plain"
    width: int = 8

    @nn.compact
    def __call__(self, images, train: bool = False):
        x = nn.Conv(self.width, (3, 3))(images)
        x = nn.BatchNorm(use_running_average=not train, momentum=0.9)(x)
        x = nn.relu(x)
        features = nn.relu(nn.Conv(self.width, (3, 3), strides=(2, 2))(x))
        b, h, w, _ = features.shape
        out = {}
        if self.head == "cudam":
            attention_logits = nn.Conv(1, (1, 1))(features)[..., 0].reshape(b, h * w)
            out["attention"] = jax.nn.softmax(attention_logits, axis=-1).reshape(b, h, w)
        if self.head == "msaam":
            out["branch_weights"] = jax.nn.softmax(nn.Dense(3)(jnp.mean(features, axis=(1, 2))), axis=-1)
        up = jax.image.resize(features, (b,) + images.shape[1:3] + (self.width,), "bilinear")
        out["logits"] = nn.Conv(self.num_classes, (1, 1))(jnp.concatenate([x, up], axis=-1))
        return out


def numpy_variables(model, size: int = 8) -> dict:
    """Variables for ``model`` on (1, size, size, 3) images, made with NumPy.

    Same tree as ``model.init`` (taken from ``jax.eval_shape``), filled with He-normal kernels,
    zero biases and means, unit scales and variances: compiling ``model.init`` costs seconds on
    2 CPU cores.
    """
    shapes = jax.eval_shape(lambda x: model.init(jax.random.key(0), x, train=False), jnp.zeros((1, size, size, 3)))
    rng = np.random.default_rng(0)

    def fill(path, leaf):
        name = path[-1].key
        if name.endswith("kernel"):
            fan_in = int(np.prod(leaf.shape[:-1]))
            return (rng.normal(size=leaf.shape) * np.sqrt(2.0 / fan_in)).astype(leaf.dtype)
        return np.full(leaf.shape, 1.0 if name in ("scale", "var") else 0.0, leaf.dtype)

    return jax.tree_util.tree_map_with_path(fill, shapes)


def random_variables(seed: int, init, *args, **kwargs) -> dict:
    """Variables shaped as ``init(key, *args, **kwargs)`` makes them, drawn by NumPy (no compile: an
    eager ``init`` compiles every primitive of every network): kernels N(0, 1 / fan-in), biases and
    running means 0, scales and running variances 1; another seed, other weights."""
    rng = np.random.default_rng(seed)

    def draw(path, leaf):
        name = jax.tree_util.keystr(path[-1:])
        if any(k in name for k in ("bias", "mean")):
            return np.zeros(leaf.shape, leaf.dtype)
        if any(k in name for k in ("scale", "var")):
            return np.ones(leaf.shape, leaf.dtype)
        fan_in = max(1, int(np.prod(leaf.shape[:-1])))
        return rng.normal(0, fan_in**-0.5, leaf.shape).astype(leaf.dtype)

    return jax.tree_util.tree_map_with_path(draw, jax.eval_shape(init, jax.random.key(seed), *args, **kwargs))


@functools.lru_cache(maxsize=None)
def init_variables(head: str = "plain") -> dict:
    """``numpy_variables`` of ``TinySegNet(head=head)``, computed once."""
    return numpy_variables(TinySegNet(head=head))


def make_batch(seed: int, batch: int = 4, size: int = 8, num_classes: int = 3, void_fraction: float = 0.1) -> dict:
    """A learnable batch: the label is the brightest colour channel (mod C), some void pixels."""
    rng = np.random.default_rng(seed)
    image = rng.normal(size=(batch, size, size, 3)).astype(np.float32)
    label = (np.argmax(image, axis=-1) % num_classes).astype(np.int32)
    label[rng.random(label.shape) < void_fraction] = 255
    return {"image": image, "label": label}


class IndexedBatches:
    """An endless, resumable input: batch i is ``make_batch(seed + i)``; get_state/set_state like grain's."""

    def __init__(self, seed: int = 0, delay_s: float = 0.0, **batch_kwargs):
        self.seed, self.delay_s, self.batch_kwargs, self.index = seed, delay_s, batch_kwargs, 0

    def __iter__(self):
        return self

    def __next__(self) -> dict:
        if self.delay_s:
            import time

            time.sleep(self.delay_s)
        batch = make_batch(self.seed + self.index, **self.batch_kwargs)
        self.index += 1
        return batch

    def get_state(self) -> dict:
        return {"index": self.index}

    def set_state(self, state: dict) -> None:
        self.index = state["index"]
