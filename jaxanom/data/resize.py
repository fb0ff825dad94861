"""Resizing frames as torchvision's ``Resize`` (PIL) does, for reproducing published protocols.

Published road-anomaly tables (e.g. the community's ERFNet evaluations) resize images with PIL's
``BILINEAR`` (a triangle filter widened by the scale when shrinking, so it antialiases) and
labels with PIL's ``NEAREST``.

- ``resize_image_antialiased``: the same triangle filter through ``jax.image.resize(...,
  antialias=True)``, rounded to uint8 as PIL's output is. PIL computes in 22-bit fixed point
  and rounds to uint8 between its two one-dimensional passes (and its pass order varies between
  versions), so the two differ by at most one grey level (measured on random and real frames,
  ``tests/data/test_data_resize.py``).
- ``resize_labels_nearest``: PIL's nearest neighbour exactly. PIL walks the source by repeated
  addition of the scale in double precision, which picks another pixel than
  ``floor((x + 0.5) * scale)`` (``jax.image.resize``'s rule) for about a third of size pairs.
"""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np


def resize_image_antialiased(image, size: tuple[int, int]) -> np.ndarray:
    """uint8 ``(H, W, C)`` -> uint8 ``(h, w, C)`` for ``size = (h, w)``: triangle filter, antialiased
    when shrinking (PIL's ``BILINEAR`` within one grey level)."""
    image = np.asarray(image)
    if image.dtype != np.uint8 or image.ndim != 3:
        raise ValueError(f"image: expected uint8 (H, W, C), got {image.dtype} {image.shape}")
    height, width = _check_size(size)
    return np.asarray(_resize_rounded(image, (height, width, image.shape[2])))


@jax.jit(static_argnums=1)
def _resize_rounded(image, shape):
    resized = jax.image.resize(image.astype(jnp.float32), shape, "linear", antialias=True)
    return jnp.clip(jnp.round(resized), 0, 255).astype(jnp.uint8)


def _nearest_index(in_size: int, out_size: int) -> np.ndarray:
    """PIL's nearest source index: ``scale / 2`` then ``+= scale`` per output, in float64."""
    steps = np.full(out_size, in_size / out_size)
    steps[0] *= 0.5
    return np.minimum(np.cumsum(steps).astype(np.int64), in_size - 1)


def resize_labels_nearest(labels, size: tuple[int, int]) -> np.ndarray:
    """``(H, W, ...)`` -> ``(h, w, ...)`` for ``size = (h, w)`` by nearest neighbour, equal to PIL's
    ``Image.resize((w, h), NEAREST)``."""
    labels = np.asarray(labels)
    if labels.ndim < 2:
        raise ValueError(f"labels: expected (H, W, ...), got shape {labels.shape}")
    height, width = _check_size(size)
    return labels[_nearest_index(labels.shape[0], height)][:, _nearest_index(labels.shape[1], width)]


def _check_size(size) -> tuple[int, int]:
    if len(size) != 2 or any(isinstance(s, bool) or not isinstance(s, (int, np.integer)) or s < 1 for s in size):
        raise ValueError(f"size: expected (height, width) positive integers, got {size!r}")
    return int(size[0]), int(size[1])
