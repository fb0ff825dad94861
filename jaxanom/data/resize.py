"""Resizing frames as torchvision's ``Resize`` (PIL) does, for reproducing published protocols.

Published road-anomaly tables (e.g. the community's ERFNet evaluations) resize images with PIL's
``BILINEAR`` (a triangle filter widened by the scale when shrinking, so it antialiases) and
labels with PIL's ``NEAREST``.

- ``resize_image_antialiased``: PIL's ``BILINEAR`` itself, one band at a time. PIL computes in
  22-bit fixed point and rounds to uint8 between its two one-dimensional passes; the same
  triangle filter in floating point (``jax.image.resize(..., "linear", antialias=True)``, rounded
  once) differs from it by one grey level on 13-17% of the pixels of a real frame, with no bias,
  and that alone moved the ERFNet protocol's AP by +0.2 points (docs/decisions/erfnet.md).
- ``resize_labels_nearest``: PIL's nearest neighbour exactly. PIL walks the source by repeated
  addition of the scale in double precision, which picks another pixel than
  ``floor((x + 0.5) * scale)`` (``jax.image.resize``'s rule) for about a third of size pairs.
"""
from __future__ import annotations

import numpy as np


def resize_image_antialiased(image, size: tuple[int, int]) -> np.ndarray:
    """uint8 ``(H, W, C)`` -> uint8 ``(h, w, C)`` for ``size = (h, w)``: PIL's ``BILINEAR`` (a
    triangle filter, antialiased when shrinking), equal to ``Image.resize((w, h), BILINEAR)`` of
    an RGB image. Each band is resized as a greyscale image: PIL would premultiply an RGBA image
    by its alpha."""
    from PIL import Image

    image = np.asarray(image)
    if image.dtype != np.uint8 or image.ndim != 3:
        raise ValueError(f"image: expected uint8 (H, W, C), got {image.dtype} {image.shape}")
    height, width = _check_size(size)
    return np.stack([np.asarray(Image.fromarray(np.ascontiguousarray(image[..., band])).resize(
        (width, height), Image.BILINEAR)) for band in range(image.shape[2])], axis=-1)


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
