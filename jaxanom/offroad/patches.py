"""Six-channel image patches, their neighbours, augmentation and the sliding-window grid (docs/papers/offroad.md#patches).

A patch at centre ``c = (row, col)`` of side ``s`` is ``[fg, bg]`` along channels: ``fg`` the
``s x s`` crop whose rows are ``row - s // 2 .. row - s // 2 + s - 1`` (likewise columns), and
``bg`` the ``(context s)^2`` crop at the same centre, average-pooled by ``context``, so
the encoder sees the surface and what surrounds it. Images are reflect-padded, so any centre
inside the image is valid. Images are float in [0, 1], channels-last.
"""
from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from jaxanom._validate import check_integer, check_rank

GREY = (0.299, 0.587, 0.114)  # ITU-R 601 luma


@partial(jax.jit, static_argnames=("size", "context"))
def patch_sample(image: jax.Array, center: jax.Array, size: int, context: int = 2) -> jax.Array:
    """(H, W, C), (2,) int -> (size, size, 2C): the fg crop and the pooled context crop."""
    pad = context * size
    padded = jnp.pad(image, ((pad, pad), (pad, pad), (0, 0)), mode="reflect")
    c = image.shape[-1]
    fg = jax.lax.dynamic_slice(padded, (center[0] - size // 2 + pad, center[1] - size // 2 + pad, 0), (size, size, c))
    big = context * size
    bg = jax.lax.dynamic_slice(padded, (center[0] - big // 2 + pad, center[1] - big // 2 + pad, 0), (big, big, c))
    bg = bg.reshape(size, context, size, context, c).mean(axis=(1, 3))
    return jnp.concatenate([fg, bg.astype(fg.dtype)], axis=-1)


@partial(jax.jit, static_argnames=("size", "context"))
def _patches(image, centers, size: int, context: int):
    return jax.vmap(lambda c: patch_sample(image, c, size, context))(centers)


def patches(image, centers, size: int, context: int = 2) -> jax.Array:
    """(H, W, C) float, (P, 2) int -> (P, size, size, 2C): ``patch_sample`` at every centre."""
    check_rank("image", image, 3, "(H, W, C)")
    check_rank("centers", centers, 2, "(P, 2)")
    check_integer("centers", centers)
    if np.shape(centers)[1] != 2:
        raise ValueError(f"centers must be (P, 2) (row, col), got shape {np.shape(centers)}")
    return _patches(jnp.asarray(image), jnp.asarray(centers), int(size), int(context))


patches_batch = jax.jit(jax.vmap(_patches, in_axes=(0, 0, None, None)), static_argnums=(2, 3))
"""(B, H, W, C), (B, P, 2) -> (B, P, size, size, 2C), no checks."""


def neighbour_centers(key: jax.Array, centers: jax.Array, size: int, count: int, height: int, width: int) -> jax.Array:
    """(P, 2) -> (P, count, 2): ``c + U{-floor(s/2) .. ceil(s/2) - 1}^2`` clipped to the image.

    The offset keeps each neighbour's centre inside the original patch (Fig. 4a).
    """
    offsets = jax.random.randint(key, (centers.shape[0], count, 2), -(size // 2), (size + 1) // 2)
    moved = centers[:, None, :] + offsets
    return jnp.clip(moved, 0, jnp.array([height - 1, width - 1]))


def _grey(rgb: jax.Array) -> jax.Array:
    return rgb @ jnp.asarray(GREY, rgb.dtype)


def _colour_jitter(rgb, brightness, contrast, saturation, to_grey):
    x = jnp.clip(rgb * brightness, 0.0, 1.0)
    x = jnp.clip(contrast * x + (1 - contrast) * _grey(x).mean(), 0.0, 1.0)
    x = jnp.clip(saturation * x + (1 - saturation) * _grey(x)[..., None], 0.0, 1.0)
    return jnp.where(to_grey, jnp.repeat(_grey(x)[..., None], 3, axis=-1), x)


def augment(key: jax.Array, patch: jax.Array, strength: float = 0.4) -> jax.Array:
    """One random augmentation of a (s, s, 6) patch; fg and bg share its parameters, so the pair stays consistent.

    Horizontal flip with p = 0.5; brightness, contrast, saturation factors ~ U[1 - strength,
    1 + strength] (applied in that order, each clipped to [0, 1]; contrast blends with the mean
    grey of each half, saturation with each pixel's grey); greyscale (ITU-R 601) with p = 0.2.
    """
    k_flip, k_grey, k_factors = jax.random.split(key, 3)
    flip = jax.random.bernoulli(k_flip, 0.5)
    to_grey = jax.random.bernoulli(k_grey, 0.2)
    b, c, s = jax.random.uniform(k_factors, (3,), minval=1 - strength, maxval=1 + strength)
    x = jnp.where(flip, patch[:, ::-1], patch)
    return jnp.concatenate([_colour_jitter(x[..., :3], b, c, s, to_grey),
                            _colour_jitter(x[..., 3:], b, c, s, to_grey)], axis=-1)


def sliding_centers(height: int, width: int, size: int, stride: int) -> np.ndarray:
    """(P, 2) int32 centres of the sliding windows, row-major.

    Top-left corners at 0, stride, 2 stride, ... up to ``dim - size``, plus a last window flush
    with the border when the grid does not reach it, so every pixel is covered.
    """
    if min(height, width) < size or size < 1 or stride < 1:
        raise ValueError(f"height, width, size, stride: expected height, width >= size >= 1 and stride >= 1, "
                         f"got {height}, {width}, {size}, {stride}")

    def starts(dim):
        grid = list(range(0, dim - size + 1, stride))
        return grid + ([dim - size] if grid[-1] != dim - size else [])

    rows, cols = np.meshgrid(starts(height), starts(width), indexing="ij")
    return (np.stack([rows.ravel(), cols.ravel()], axis=1) + size // 2).astype(np.int32)
