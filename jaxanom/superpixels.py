"""SLIC superpixels (MMF Algorithm 1) and sRGB -> CIE Lab, in pure JAX.

``slic(lab, step)`` segments one image ``(H, W, 3)`` into ``K = num_superpixels((H, W), step)``
clusters and returns int32 labels ``(H, W)`` in ``[0, K)``, one per pixel (docs/papers/mmf.md#slic-superpixels):

1. grid: centres on the pixels ``(S//2 + a S, S//2 + b S)`` inside the image;
2. perturbation: each centre moves to the pixel of least gradient
   ``G = |I(y, x+1) - I(y, x-1)|^2 + |I(y+1, x) - I(y-1, x)|^2`` (edge-replicated) in its 3x3
   neighbourhood (clipped to the image), ties to the first offset in row-major order;
3. distance ``D = d_lab^2 + (m / S)^2 d_xy^2``;
4. assignment: centres in index order, each over the ``2S x 2S`` window
   ``[round(y_k) - S, round(y_k) + S) x [round(x_k) - S, round(x_k) + S)`` setting a pixel's
   label where ``D < d(i)``. Done as a scatter-min of ``D``, then a scatter-min of ``k`` over
   the pixels attaining it (ties -> smallest k, as the sequential strict ``<``). ``d`` restarts
   at infinity every iteration; a pixel no window covers takes its initial grid cell;
5. update: centre = mean ``[l, a, b, y, x]`` of its pixels; an empty cluster keeps its centre;
6. stop after ``iterations`` updates, or earlier once the residual E <= ``tol``; a last
   assignment to the final centres gives the labels.

``round`` is half-to-even (NumPy's). Connectivity enforcement (not in Algorithm 1) is an option.
The input has 3 channels (Lab) or one (an anomaly map; Algorithm 1 with a scalar feature).
The work dtype is float32, or float64 for float64 input under ``jax.enable_x64``.
"""
from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np

from jaxanom._batching import over_images
from jaxanom._validate import check_count, check_finite, check_rank, dtype_of, values_checked

# sRGB (D65) -> XYZ and the D65 white point, as scikit-image's ``rgb2lab`` uses them.
_XYZ_FROM_RGB = np.array([[0.412453, 0.357580, 0.180423],
                          [0.212671, 0.715160, 0.072169],
                          [0.019334, 0.119193, 0.950227]])
_D65_WHITE = np.array([0.95047, 1.0, 1.08883])


def _rgb_to_lab(rgb: jax.Array) -> jax.Array:
    # powers as exp(log) (XLA:CPU's cbrt and pow are 10x and 6x slower; the arguments are >= 0)
    linear = jnp.where(rgb > 0.04045, jnp.exp(2.4 * jnp.log((rgb + 0.055) / 1.055)), rgb / 12.92)
    matrix = (_XYZ_FROM_RGB.T / _D65_WHITE).astype(rgb.dtype)  # rows: r, g, b; columns: X/Xn, Y/Yn, Z/Zn
    xyz = sum(linear[..., k, None] * matrix[k] for k in range(3))  # a 3x3 matmul is slow on XLA:CPU
    f = jnp.where(xyz > 0.008856, jnp.exp(jnp.log(xyz) / 3.0), 7.787 * xyz + 16.0 / 116.0)
    fx, fy, fz = f[..., 0], f[..., 1], f[..., 2]
    return jnp.stack([116.0 * fy - 16.0, 500.0 * (fx - fy), 200.0 * (fy - fz)], axis=-1)


def _work_dtype(x) -> jnp.dtype:
    return jnp.float64 if dtype_of(x) == np.float64 and jax.config.jax_enable_x64 else jnp.float32


def rgb_to_lab(image) -> jax.Array:
    """sRGB ``(..., 3)`` (uint8, or float in [0, 1]) -> CIE Lab ``(..., 3)`` (D65, 2-degree observer).

    The formulas of scikit-image's ``rgb2lab``: L in [0, 100], a and b roughly in [-128, 128].
    """
    if np.ndim(image) < 1 or np.shape(image)[-1] != 3:
        raise ValueError(f"image must have 3 channels in its last axis (..., 3), got shape {np.shape(image)}")
    dtype = dtype_of(image)
    if dtype == np.uint8:
        return _rgb_to_lab_jit(jnp.asarray(image, jnp.float32) / 255.0)
    if not np.issubdtype(dtype, np.floating):
        raise ValueError(f"image must be uint8 or float in [0, 1], got dtype {dtype}")
    if values_checked(image):
        values = np.asarray(image)
        nan, outside = np.isnan(values), (values < 0) | (values > 1)
        if nan.any() or outside.any():
            raise ValueError(f"image must hold floats in [0, 1], got {nan.sum()} NaN and "
                             f"{outside.sum()} value(s) outside, such as {values[outside][:3].tolist()}")
    return _rgb_to_lab_jit(jnp.asarray(image, _work_dtype(image)))


def grid_shape(shape: tuple[int, int], step: int) -> tuple[int, int]:
    """Rows and columns of the initial SLIC grid (centres at ``S//2 + a S`` inside the image)."""
    return tuple(len(range(step // 2, size, step)) for size in shape)


def num_superpixels(shape: tuple[int, int], step: int) -> int:
    """K, the number of SLIC clusters (and label values) for an image of ``shape`` (H, W) at grid step S."""
    check_count("step", step)
    rows, cols = grid_shape(shape, step)
    return rows * cols


def scaled_step(shape: tuple[int, int], step: int = 8, reference: tuple[int, int] = (256, 512)) -> int:
    """SLIC step S for an (H, W) frame: ``step`` at ``reference`` scaled by sqrt(H W / area of
    reference), rounded, in [1, min(H, W)] (docs/papers/mmf.md#superpixel-step): K stays near
    ``num_superpixels(reference, step)`` (2048 by default), e.g. S = 2 at 64x128, 32 at 1080x1920."""
    scale = math.sqrt(shape[0] * shape[1] / (reference[0] * reference[1]))
    return int(min(max(1, round(step * scale)), min(shape)))


def _shift(x: jax.Array, dy: int, dx: int, fill) -> jax.Array:
    """``x[y + dy, x + dx]`` (``fill`` outside the image) for dy, dx in {-1, 0, 1}."""
    padded = jnp.pad(x, 1, constant_values=fill)
    return padded[1 + dy:1 + dy + x.shape[0], 1 + dx:1 + dx + x.shape[1]]


_NEIGHBOURS = ((0, 1), (1, 0), (0, -1), (-1, 0))  # 4-connectivity


def _components(labels: jax.Array) -> jax.Array:
    """(H, W) int32: for each pixel, the least flat index of its 4-connected piece of equal labels
    (min-label propagation with pointer jumping, until nothing changes)."""
    height, width = labels.shape
    size = height * width

    def spread(state):
        comp, _ = state
        least = comp
        for dy, dx in _NEIGHBOURS:
            same = _shift(labels, dy, dx, -1) == labels
            least = jnp.minimum(least, jnp.where(same, _shift(comp, dy, dx, size), size))
        jumped = least.ravel()[least.ravel()].reshape(least.shape)  # the least index's own (smaller or equal) root
        jumped = jumped.ravel()[jumped.ravel()].reshape(least.shape)
        return jumped, jnp.any(jumped != comp)

    start = jnp.arange(size, dtype=jnp.int32).reshape(height, width)
    comp, _ = jax.lax.while_loop(lambda state: state[1], spread, (start, jnp.asarray(True)))
    return comp


def _enforce_connectivity(labels: jax.Array, num_segments: int) -> jax.Array:
    """Labels (H, W) whose every superpixel is 4-connected: each label keeps its largest piece
    (ties: the piece with the least flat index); every other piece joins the least label among the
    kept pixels next to it, repeated until every pixel is kept. Labels stay in [0, K)."""
    height, width = labels.shape
    size = height * width
    comp = _components(labels).ravel()
    flat = labels.ravel()
    piece_size = jax.ops.segment_sum(jnp.ones(size, jnp.int32), comp, size)[comp]
    largest = jax.ops.segment_max(piece_size, flat, num_segments)[flat] == piece_size
    first = jax.ops.segment_min(jnp.where(largest, comp, size), flat, num_segments)[flat]
    kept = (largest & (comp == first)).reshape(height, width)
    comp = comp.reshape(height, width)

    def absorb(state):
        final, kept = state
        offer = jnp.full((height, width), num_segments, jnp.int32)
        for dy, dx in _NEIGHBOURS:
            neighbour = jnp.where(_shift(kept, dy, dx, False), _shift(final, dy, dx, num_segments), num_segments)
            offer = jnp.minimum(offer, neighbour)
        piece_offer = jax.ops.segment_min(jnp.where(kept, num_segments, offer).ravel(), comp.ravel(), size)[comp]
        joins = ~kept & (piece_offer < num_segments)
        return jnp.where(joins, piece_offer, final), kept | joins

    final, _ = jax.lax.while_loop(lambda state: ~jnp.all(state[1]), absorb, (labels, kept))
    return final


def _sum_last(x: jax.Array) -> jax.Array:
    """Sum over a short last axis, left to right (XLA:CPU reduces a 3-long axis slowly)."""
    return sum(x[..., c] for c in range(x.shape[-1]))


def _gradient_energy(lab: jax.Array) -> jax.Array:
    """Step 2's ``G`` (H, W): squared central differences with edge replication."""
    p = jnp.pad(lab, ((1, 1), (1, 1), (0, 0)), mode="edge")
    dx = p[1:-1, 2:] - p[1:-1, :-2]
    dy = p[2:, 1:-1] - p[:-2, 1:-1]
    return _sum_last(dx * dx) + _sum_last(dy * dy)


def _initial_centres(lab: jax.Array, step: int) -> jax.Array:
    """Steps 1-2: (K, C + 2) centres ``[features..., y, x]`` on the grid, moved to the 3x3 gradient minimum."""
    height, width = lab.shape[:2]
    rows, cols = grid_shape((height, width), step)
    ys, xs = jnp.meshgrid(step // 2 + step * jnp.arange(rows), step // 2 + step * jnp.arange(cols), indexing="ij")
    ys, xs = ys.ravel(), xs.ravel()
    offsets = jnp.array([(dy, dx) for dy in (-1, 0, 1) for dx in (-1, 0, 1)])  # row-major order
    cand_y = jnp.clip(ys[:, None] + offsets[:, 0], 0, height - 1)
    cand_x = jnp.clip(xs[:, None] + offsets[:, 1], 0, width - 1)
    best = jnp.argmin(_gradient_energy(lab)[cand_y, cand_x], axis=1)  # first minimum on ties
    y = jnp.take_along_axis(cand_y, best[:, None], 1)[:, 0]
    x = jnp.take_along_axis(cand_x, best[:, None], 1)[:, 0]
    return jnp.concatenate([lab[y, x], jnp.stack([y, x], axis=1).astype(lab.dtype)], axis=1)  # (K, C + 2)


def _grid_cells(height: int, width: int, step: int) -> jax.Array:
    """(H, W) index of the grid cell holding each pixel: the label of a pixel no window covers."""
    rows, cols = grid_shape((height, width), step)
    row = jnp.minimum(jnp.arange(height) // step, rows - 1)
    col = jnp.minimum(jnp.arange(width) // step, cols - 1)
    return (row[:, None] * cols + col[None, :]).astype(jnp.int32)


def _assign(lab: jax.Array, centres: jax.Array, step: int, compactness) -> jax.Array:
    """Step 4: labels (H, W) int32 from centres (K, C + 2)."""
    height, width, c = lab.shape
    k = centres.shape[0]
    window = jnp.arange(-step, step)
    top = jnp.round(centres[:, c]).astype(jnp.int32)
    left = jnp.round(centres[:, c + 1]).astype(jnp.int32)
    y = top[:, None, None] + window[None, :, None]  # (K, 2S, 1)
    x = left[:, None, None] + window[None, None, :]  # (K, 1, 2S)
    inside = (y >= 0) & (y < height) & (x >= 0) & (x < width)
    pixel = jnp.where(inside, y * width + x, height * width)  # out of the image: dropped
    colour = lab[jnp.clip(y, 0, height - 1), jnp.clip(x, 0, width - 1)]  # (K, 2S, 2S, C)
    d_lab = _sum_last((colour - centres[:, None, None, :c]) ** 2)
    d_xy = (y - centres[:, c, None, None]) ** 2 + (x - centres[:, c + 1, None, None]) ** 2
    distance = d_lab + (compactness / step) ** 2 * d_xy
    best = jnp.full(height * width, jnp.inf, distance.dtype).at[pixel].min(distance, mode="drop")
    winner = jnp.where(distance == best.at[pixel].get(mode="fill", fill_value=-1.0),
                       jnp.arange(k, dtype=jnp.int32)[:, None, None], k)
    label = jnp.full(height * width, k, jnp.int32).at[pixel].min(winner, mode="drop")
    label = jnp.where(label == k, _grid_cells(height, width, step).ravel(), label)
    return label.reshape(height, width)


def _update(lab: jax.Array, labels: jax.Array, centres: jax.Array) -> jax.Array:
    """Step 5: (K, C + 2) mean ``[features..., y, x]`` per cluster; an empty cluster keeps its centre."""
    height, width = labels.shape
    c = lab.shape[-1] + 2
    ys, xs = jnp.meshgrid(jnp.arange(height), jnp.arange(width), indexing="ij")
    ones = jnp.ones((height, width, 1), lab.dtype)  # a last column counts the pixels: one scatter
    features = jnp.concatenate([lab, jnp.stack([ys, xs], -1).astype(lab.dtype), ones], -1).reshape(-1, c + 1)
    sums = jax.ops.segment_sum(features, labels.ravel(), centres.shape[0])
    counts = sums[:, c:]
    return jnp.where(counts > 0, sums[:, :c] / jnp.maximum(counts, 1), centres)


def _slic(lab: jax.Array, compactness, tol, step: int, iterations: int, connectivity: bool = False) -> jax.Array:
    """Steps 1-6: at most ``iterations`` updates, stopping once E = sum_k |dy_k| + |dx_k| <= tol."""

    def going_on(state):
        count, _, residual = state
        return (count < iterations) & (residual > tol)

    def one_iteration(state):
        count, centres, _ = state
        moved = _update(lab, _assign(lab, centres, step, compactness), centres)
        return count + 1, moved, jnp.sum(jnp.abs(moved[:, -2:] - centres[:, -2:]))

    start = (0, _initial_centres(lab, step), jnp.asarray(jnp.inf, lab.dtype))
    _, centres, _ = jax.lax.while_loop(going_on, one_iteration, start)
    labels = _assign(lab, centres, step, compactness)
    return _enforce_connectivity(labels, centres.shape[0]) if connectivity else labels


_rgb_to_lab_jit = jax.jit(_rgb_to_lab)
_SLIC_STATIC = ("step", "iterations", "connectivity")
_slic_jit = jax.jit(_slic, static_argnames=_SLIC_STATIC)


@functools.partial(jax.jit, static_argnames=_SLIC_STATIC)
def _slic_batch(lab: jax.Array, compactness, tol, step: int, iterations: int, connectivity: bool = False) -> jax.Array:
    return over_images(lambda image: _slic(image, compactness, tol, step, iterations, connectivity), lab)


def _check_slic(lab, step, compactness, iterations, tol, batched: bool):
    check_rank("lab", lab, 4 if batched else 3, "(B, H, W, C)" if batched else "(H, W, C)")
    if np.shape(lab)[-1] not in (1, 3):
        raise ValueError(f"lab must have 3 channels (L, a, b) or 1 in its last axis, got shape {np.shape(lab)}")
    if not np.issubdtype(dtype_of(lab), np.floating):
        raise ValueError(f"lab must be a float array (from rgb_to_lab), got dtype {dtype_of(lab)}")
    height, width = np.shape(lab)[-3:-1]
    if not isinstance(step, (int, np.integer)) or not 1 <= step <= min(height, width):
        raise ValueError(f"step must be an integer in [1, min(H, W)] = [1, {min(height, width)}], got {step!r}")
    if not isinstance(iterations, (int, np.integer)) or iterations < 0:
        raise ValueError(f"iterations must be an integer >= 0, got {iterations!r}")
    if values_checked(compactness) and not (np.isfinite(compactness) and compactness > 0):
        raise ValueError(f"compactness must be finite and > 0, got {compactness}")
    if tol is not None and values_checked(tol) and not (np.isfinite(tol) and tol >= 0):
        raise ValueError(f"tol must be None or finite and >= 0, got {tol}")
    check_finite("lab", lab)
    dtype = _work_dtype(lab)
    tol = jnp.asarray(-1.0 if tol is None else tol, dtype)  # -1: E >= 0 never stops the loop early
    return jnp.asarray(lab, dtype), jnp.asarray(compactness, dtype), tol, int(step), int(iterations)


def slic(lab, step: int, compactness: float = 10.0, iterations: int = 10, tol: float | None = None,
         connectivity: bool = False) -> jax.Array:
    """SLIC (MMF Algorithm 1) of one image: lab ``(H, W, 3)`` float, or one channel ``(H, W, 1)``
    (e.g. an anomaly map, MMF Sec. III-B; scale it like L, to [0, 100]) -> labels ``(H, W)`` int32.

    Labels lie in ``[0, num_superpixels((H, W), step))``; every pixel has one. ``step`` S (grid
    step in pixels, 1 <= S <= min(H, W)) and ``iterations`` are static; ``compactness`` m weighs
    the spatial distance (``D = d_lab^2 + (m/S)^2 d_xy^2``). ``tol``: stop before ``iterations``
    once the centres move by ``E = sum_k |dy_k| + |dx_k| <= tol`` (Algorithm 1's residual error);
    None runs every iteration. ``connectivity`` (static; not in Algorithm 1): afterwards each
    superpixel keeps its largest 4-connected piece and the other pieces join a neighbouring
    superpixel, so every superpixel is connected and K is unchanged.
    """
    *args, step, iterations = _check_slic(lab, step, compactness, iterations, tol, batched=False)
    return _slic_jit(*args, step=step, iterations=iterations, connectivity=bool(connectivity))


def slic_batch(lab, step: int, compactness: float = 10.0, iterations: int = 10,
               tol: float | None = None, connectivity: bool = False) -> jax.Array:
    """``slic`` over a batch: lab ``(B, H, W, C)`` -> labels ``(B, H, W)`` int32 (each image stops on its own)."""
    *args, step, iterations = _check_slic(lab, step, compactness, iterations, tol, batched=True)
    return _slic_batch(*args, step=step, iterations=iterations, connectivity=bool(connectivity))


__all__ = ["grid_shape", "num_superpixels", "rgb_to_lab", "scaled_step", "slic", "slic_batch"]
