"""Class boundaries of a prediction map and their distance-based expansion (SML Sec. 3.3).

A pixel is a boundary pixel where the dilation of the prediction with the 3x3 cross differs
from its erosion with the 3x3 square (a band about 2 px wide). Border modes:

- ``"geodesic"`` (default): pixels outside the image are ignored by both operations
  (replicating the edge is the same thing for a max / min over a window that holds its centre).
- ``"sml_official"``: the original code's pinned kornia, whose dilation pads with 0 and whose
  erosion pads with 1.0; image-edge pixels of classes >= 2 then count as boundary.
"""
from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from jaxanom._validate import check_integer, check_rank

BORDERS = ("geodesic", "sml_official")


def _padded(x: jax.Array, pad_value) -> jax.Array:
    """``x`` padded by one pixel: replicated edge (``pad_value=None``) or a constant."""
    if pad_value is None:
        return jnp.pad(x, 1, mode="edge")
    return jnp.pad(x, 1, constant_values=pad_value)


def _dilate_cross(x: jax.Array, pad_value) -> jax.Array:
    p = _padded(x, pad_value)
    return jnp.maximum(jnp.maximum(jnp.maximum(p[1:-1, 1:-1], p[:-2, 1:-1]), jnp.maximum(p[2:, 1:-1], p[1:-1, :-2])), p[1:-1, 2:])


def _erode_square(x: jax.Array, pad_value) -> jax.Array:
    p = _padded(x, pad_value)
    rows = jnp.minimum(jnp.minimum(p[:-2], p[1:-1]), p[2:])
    return jnp.minimum(jnp.minimum(rows[:, :-2], rows[:, 1:-1]), rows[:, 2:])


def _find_boundaries(prediction: jax.Array, border: str = "geodesic") -> jax.Array:
    dilation_pad, erosion_pad = (None, None) if border == "geodesic" else (0, 1)
    return _dilate_cross(prediction, dilation_pad) != _erode_square(prediction, erosion_pad)


def check_border(border: str) -> None:
    if border not in BORDERS:
        raise ValueError(f"border must be one of {BORDERS}, got {border!r}")


def check_prediction(prediction, shape: tuple[int, ...] | None = None) -> None:
    """``prediction`` must be an integer ``(H, W)`` map, of ``shape`` when given."""
    check_rank("prediction", prediction, 2, "(H, W)")
    check_integer("prediction", prediction)
    if shape is not None and np.shape(prediction) != shape:
        raise ValueError(f"prediction must have the score's shape {shape}, got {np.shape(prediction)}")


def find_boundaries(prediction, border: str = "geodesic") -> jax.Array:
    """Boundary mask bool ``(H, W)`` of an integer prediction map ``(H, W)``."""
    check_prediction(prediction)
    check_border(border)
    return _find_boundaries_jit(jnp.asarray(prediction), border)


def boundary_distance(boundaries, max_radius: int) -> jax.Array:
    """L1 (diamond) distance int32 ``(H, W)`` of every pixel to the nearest boundary pixel.

    Exact up to ``max_radius``; farther pixels (and every pixel of a map without boundary)
    get ``max_radius + 1``. Thresholding it, ``distance <= r`` is the boundary dilated by the
    diamond of radius r (the original ``expand_boundaries``), for any traced r <= max_radius.
    The L1 distance separates into a row pass and a column pass.
    """
    check_rank("boundaries", boundaries, 2, "(H, W)")
    if not (isinstance(max_radius, (int, np.integer)) and max_radius >= 0):
        raise ValueError(f"max_radius must be an int >= 0, got {max_radius!r}")
    return _boundary_distance_jit(jnp.asarray(boundaries, bool), int(max_radius))


def _boundary_distance(boundaries: jax.Array, max_radius: int) -> jax.Array:
    far = max_radius + 1
    d = jnp.where(boundaries, 0, far).astype(jnp.int32)
    for axis in (1, 0):
        size = d.shape[axis]
        p = jnp.pad(d, [(max_radius, max_radius) if a == axis else (0, 0) for a in range(2)], constant_values=far)
        shifted = (abs(k - max_radius) + jax.lax.slice_in_dim(p, k, k + size, axis=axis) for k in range(2 * max_radius + 1))
        d = jnp.minimum(far, functools.reduce(jnp.minimum, shifted))
    return d


_find_boundaries_jit = jax.jit(_find_boundaries, static_argnames="border")
_boundary_distance_jit = jax.jit(_boundary_distance, static_argnames="max_radius")
