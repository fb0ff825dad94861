"""SML's local post-processing of a score map: boundary suppression (Eqs. 6-7) and dilated
smoothing (Eq. 8). Both work on *any* score map ``(H, W)`` (SML, MSP, max logit: the paper's
Table 7) and both are linear in the scores, so they commute with negation.

The smoothing's ``sigma`` may be traced (``jax.jit`` / ``vmap`` over a grid of sigmas); the
options that set shapes or loop counts are static: ``kernel_size``, ``dilation``, ``width``,
``iterations`` and ``border`` (a traced one is refused in one line, ``InputError``).
"""
from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from jaxanom._validate import check_finite, check_rank, check_real, check_static, is_concrete, values_checked
from jaxanom.errors import InputError
from jaxanom.sml.boundaries import _boundary_distance, _find_boundaries, check_border, check_prediction


def _box3_sum(x: jax.Array) -> jax.Array:
    """3x3 sums with replication padding (the original's ReplicationPad2d(1) + ones conv)."""
    p = jnp.pad(x, 1, mode="edge")
    rows = p[:-2] + p[1:-1] + p[2:]
    return rows[:, :-2] + rows[:, 1:-1] + rows[:, 2:]


def _suppress(score, prediction, width: int, iterations: int, border: str):
    step = width // iterations
    max_radius = width - 1 if (iterations > 1 and width > 0) else 0
    distance = _boundary_distance(_find_boundaries(prediction, border), max_radius)

    def one_iteration(i, out):
        # radius W - i*(W/n) - 1, and 0 for the last iteration (3, 2, 1, 0 by default)
        radius = jnp.where((i == iterations - 1) | (width == 0), 0, width - step * i - 1)
        keep = distance > radius  # the non-boundary mask of Eq. 6
        kept = keep.astype(out.dtype)
        total, count = _box3_sum(out * kept), _box3_sum(kept)
        average = jnp.where(count == 0, out, total / jnp.maximum(count, 1.0))
        return jnp.where(keep, out, average)

    return jax.lax.fori_loop(0, iterations, one_iteration, score.astype(jnp.float32))


def gaussian_kernel_1d(kernel_size: int = 7, sigma: float = 1.0) -> np.ndarray:
    """Normalised 1-D Gaussian (float64); its outer product is the original's normalised 2-D kernel."""
    offsets = np.arange(kernel_size) - (kernel_size - 1) / 2
    g = np.exp(-(offsets**2) / (2 * sigma**2))
    return g / g.sum()


def smoothing_weights(kernel_size: int, sigma) -> jax.Array:
    """Eq. 8's separable kernel, float32 ``(kernel_size,)``: ``gaussian_kernel_1d`` rounded to
    float32 for a concrete ``sigma``; for a traced one the same formula in JAX (float32, float64
    in 64-bit mode), within a few float32 ulps of it (not always the same last bit)."""
    if is_concrete(sigma):
        return jnp.asarray(gaussian_kernel_1d(kernel_size, float(sigma)).astype(np.float32))
    offsets = jnp.arange(kernel_size) - (kernel_size - 1) / 2
    g = jnp.exp(-(offsets**2) / (2 * jnp.asarray(sigma, float) ** 2))
    return (g / g.sum()).astype(jnp.float32)


def _smooth(score, weights, dilation: int):
    kernel_size = weights.shape[0]
    reach = dilation * (kernel_size // 2)
    out = score.astype(jnp.float32)
    for axis in (0, 1):  # separable: rows, then columns
        size = out.shape[axis]
        p = jnp.pad(out, [(reach, reach) if a == axis else (0, 0) for a in range(2)], mode="edge")
        taps = (weights[k] * jax.lax.slice_in_dim(p, k * dilation, k * dilation + size, axis=axis)
                for k in range(kernel_size))
        out = functools.reduce(jnp.add, taps)
    return out


_STATIC = ("width", "iterations", "border")
_suppress_jit = jax.jit(_suppress, static_argnames=_STATIC)
_smooth_jit = jax.jit(_smooth, static_argnames="dilation")


def check_suppression(width: int, iterations: int, border: str) -> None:
    """``width`` int >= 0, a multiple of ``iterations`` int >= 1; static (they set the band's reach and the loop)."""
    check_static("iterations", iterations, "is the suppression's loop count")
    check_static("width", width, "sets the boundary band's reach (array padding)")
    check_static("border", border, "chooses the boundary padding")
    if not (isinstance(iterations, (int, np.integer)) and iterations >= 1):
        raise ValueError(f"iterations must be an int >= 1, got {iterations!r}")
    if not (isinstance(width, (int, np.integer)) and width >= 0):
        raise ValueError(f"width must be an int >= 0, got {width!r}")
    if width % iterations:
        raise ValueError(f"width must be a multiple of iterations, got width={width}, iterations={iterations}")
    check_border(border)


def check_smoothing(kernel_size: int, sigma, dilation: int) -> None:
    """``kernel_size`` odd int >= 1 and ``dilation`` int >= 1, both static (they set the kernel's
    shape and reach); ``sigma`` > 0, checked where its value is on the host (it may be traced)."""
    check_static("kernel_size", kernel_size, "sets the kernel's shape")
    check_static("dilation", dilation, "sets the kernel's reach (array padding)")
    if not (isinstance(kernel_size, (int, np.integer)) and kernel_size >= 1 and kernel_size % 2 == 1):
        raise ValueError(f"kernel_size must be an odd int >= 1, got {kernel_size!r}")
    if np.ndim(sigma) != 0:
        raise InputError("sigma", f"must be a scalar (vmap over a grid of sigmas), got shape {np.shape(sigma)}")
    if values_checked(sigma) and not float(np.asarray(sigma)) > 0:
        raise ValueError(f"sigma must be > 0, got {sigma!r}")
    if not (isinstance(dilation, (int, np.integer)) and dilation >= 1):
        raise ValueError(f"dilation must be an int >= 1, got {dilation!r}")


def check_score(score) -> None:
    check_rank("score", score, 2, "(H, W)")
    check_real("score", score)
    check_finite("score", score)


def suppress_boundaries(score, prediction, width: int = 4, iterations: int = 4, border: str = "geodesic") -> jax.Array:
    """Iterative boundary suppression (Eqs. 6-7) of ``score`` float ``(H, W)`` -> float32 ``(H, W)``.

    ``width``, ``iterations`` and ``border`` are static (not traced under jit / vmap).

    ``prediction`` int ``(H, W)`` gives the boundaries. Iteration i (``lax.fori_loop``) takes
    the band of pixels within L1 distance ``r_i = width - i*(width/iterations) - 1`` of a
    boundary (``r = 0`` on the last iteration), and replaces each band pixel by the mean of
    the non-band pixels of its 3x3 window (replication padding), keeping it where there are
    none. Pixels off the first band never change. ``width % iterations == 0``.
    """
    check_score(score)
    check_prediction(prediction, np.shape(score))
    check_suppression(width, iterations, border)
    return _suppress_jit(jnp.asarray(score), jnp.asarray(prediction), width=width, iterations=iterations, border=border)


def dilated_smoothing(score, kernel_size: int = 7, sigma: float = 1.0, dilation: int = 6) -> jax.Array:
    """Dilated Gaussian smoothing (Eq. 8) of ``score`` float ``(H, W)`` -> float32 ``(H, W)``.

    The normalised ``kernel_size`` Gaussian of std ``sigma`` with the given dilation, replication
    padding of ``dilation * (kernel_size // 2)`` (18 by default), computed as two 1-D passes.
    ``sigma`` may be traced (see ``smoothing_weights``); ``kernel_size`` and ``dilation`` are static.
    """
    check_score(score)
    check_smoothing(kernel_size, sigma, dilation)
    return _smooth_jit(jnp.asarray(score), smoothing_weights(kernel_size, sigma), dilation=dilation)
