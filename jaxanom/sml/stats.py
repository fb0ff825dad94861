"""Per-class statistics of the max logit (SML Eqs. 3-4), streamed and mergeable.

For every class c: the count, mean and sum of squared deviations (M2) of the max logit
``L = max_c F_c`` over the pixels *predicted* as c (ground truth is not used).

Accuracy over 10^9+ pixels in float32: nothing is ever summed over more than one image row.
An image's statistics are computed per row (two-pass: mean, then squared deviations), rows
are pooled, and images/batches are merged with the parallel formula of Chan, Golub & LeVeque
(1979) for k groups: ``n = sum n_k``, ``mean = sum (n_k / n) mean_k``,
``M2 = sum (M2_k + n_k (mean_k - mean)^2)``. Each merge rounds at the float32 level of the
*result* (relative ~6e-8), so errors grow like sqrt(#merges), not with the pixel count; the
naive running sums would stop growing after 2^24 pixels. Counts are float32 too: exact up to
2^24 per class, and beyond that within the same relative rounding, which only perturbs the
merge weights at that level.

Policy for a class that was never predicted (or has fewer than 2 pixels, or zero variance):
``stats_finalize`` raises ``ValueError`` naming those classes by default; with
``missing="pooled"`` it gives them the mean and std of the max logit over all counted pixels
(documented fallback). It never returns NaN. Scarce classes: ``policy=`` (``jaxanom.sml.policy``).
"""
from __future__ import annotations

import io
import json
import os
import zipfile
from typing import Iterable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxanom._validate import check_finite, check_rank, check_real, dtype_of
from jaxanom.io import write_bytes_atomic
from jaxanom.sml.policy import DEFAULT_POLICY, DEFAULT_STRENGTH, FinalizedStats, check_policy, finalize


class ClassStats(NamedTuple):
    """Running statistics (a pytree); every field is float32 ``(C,)``."""

    count: jax.Array
    mean: jax.Array
    m2: jax.Array


def stats_init(num_classes: int) -> ClassStats:
    """Empty statistics for ``num_classes`` classes."""
    if int(num_classes) < 1:
        raise ValueError(f"num_classes must be >= 1, got {num_classes}")
    zeros = jnp.zeros((int(num_classes),), jnp.float32)
    return ClassStats(zeros, zeros, zeros)


def _pool(count: jax.Array, mean: jax.Array, m2: jax.Array, axis: int = 0) -> ClassStats:
    """Combine groups along ``axis`` with Chan et al.'s parallel formula."""
    n = jnp.sum(count, axis=axis)
    weight = count / jnp.expand_dims(jnp.where(n > 0, n, 1.0), axis)
    pooled_mean = jnp.sum(weight * mean, axis=axis)
    spread = count * jnp.square(mean - jnp.expand_dims(pooled_mean, axis))
    return ClassStats(n, pooled_mean, jnp.sum(m2 + spread, axis=axis))


def stats_merge(a: ClassStats, b: ClassStats) -> ClassStats:
    """Statistics of the union of the pixels behind ``a`` and ``b`` (jit-compatible)."""
    return _pool(*(jnp.stack([x, y]) for x, y in zip(a, b)))


def _image_stats(logits: jax.Array, valid: jax.Array) -> ClassStats:
    """Statistics of one image: logits ``(H, W, C)``, valid bool ``(H, W)``."""
    num_classes = logits.shape[-1]
    max_logit = jnp.max(logits, axis=-1)[..., None]  # (H, W, 1)
    member = (jnp.argmax(logits, axis=-1)[..., None] == jnp.arange(num_classes)) & valid[..., None]
    row_count = jnp.sum(member, axis=1, dtype=jnp.float32)  # (H, C)
    row_sum = jnp.sum(jnp.where(member, max_logit, 0.0), axis=1)
    row_mean = row_sum / jnp.maximum(row_count, 1.0)
    row_m2 = jnp.sum(jnp.where(member, jnp.square(max_logit - row_mean[:, None, :]), 0.0), axis=1)
    return _pool(row_count, row_mean, row_m2)


def _update(stats: ClassStats, logits: jax.Array, valid: jax.Array) -> ClassStats:
    return stats_merge(stats, _image_stats(logits.astype(jnp.float32), valid))


def _update_batch(stats: ClassStats, logits: jax.Array, valid: jax.Array) -> ClassStats:
    per_image = jax.vmap(_image_stats)(logits.astype(jnp.float32), valid)
    return stats_merge(stats, _pool(*per_image))


_update_jit = jax.jit(_update)
_update_batch_jit = jax.jit(_update_batch)


def _checked_valid(valid, shape: tuple[int, ...]) -> jax.Array:
    if valid is None:
        return jnp.ones(shape, bool)
    if np.shape(valid) != shape:
        raise ValueError(f"valid must have shape {shape} (the logits' pixels), got {np.shape(valid)}")
    if dtype_of(valid) != bool:
        raise ValueError(f"valid must be a bool mask, got dtype {dtype_of(valid)}")
    return jnp.asarray(valid)


def _check_logits_for(stats: ClassStats, logits, rank: int, layout: str) -> None:
    check_rank("logits", logits, rank, layout)
    num_classes = stats.count.shape[0]
    if np.shape(logits)[-1] != num_classes:
        raise ValueError(f"logits must have C={num_classes} classes (as the statistics), got C={np.shape(logits)[-1]}")
    check_real("logits", logits)
    check_finite("logits", logits)


def stats_update(stats: ClassStats, logits, valid=None) -> ClassStats:
    """Add one image: logits ``(H, W, C)``, optional bool ``valid`` ``(H, W)`` of pixels to count."""
    _check_logits_for(stats, logits, 3, "(H, W, C)")
    return _update_jit(stats, jnp.asarray(logits), _checked_valid(valid, np.shape(logits)[:2]))


def stats_update_batch(stats: ClassStats, logits, valid=None) -> ClassStats:
    """Add a batch: logits ``(B, H, W, C)``, optional bool ``valid`` ``(B, H, W)``."""
    _check_logits_for(stats, logits, 4, "(B, H, W, C)")
    return _update_batch_jit(stats, jnp.asarray(logits), _checked_valid(valid, np.shape(logits)[:3]))


def fit_stats(batches: Iterable, num_classes: int | None = None) -> ClassStats:
    """Stream statistics over ``batches`` without holding them.

    Each item is logits ``(H, W, C)`` or ``(B, H, W, C)``, or a pair ``(logits, valid)`` with a
    bool mask of the matching ``(H, W)`` / ``(B, H, W)`` shape. ``num_classes`` defaults to the
    first item's C.
    """
    stats = None if num_classes is None else stats_init(num_classes)
    for item in batches:
        logits, valid = item if isinstance(item, tuple) else (item, None)
        if stats is None:
            stats = stats_init(np.shape(logits)[-1])
        update = stats_update_batch if np.ndim(logits) == 4 else stats_update
        stats = update(stats, logits, valid)
    if stats is None:
        raise ValueError("batches must yield at least one logits array, got an empty iterable")
    return stats


def stats_finalize(stats: ClassStats, *, missing: str = "error", policy: str = DEFAULT_POLICY,
                   min_count: float = 10_000, strength: float = DEFAULT_STRENGTH) -> tuple[jax.Array, jax.Array]:
    """Per-class ``(mean, std)``, float32 ``(C,)``, std from the unbiased variance (as the original code).

    ``policy`` (``jaxanom.sml.policy``; default ``"shrink"`` with ``strength`` 1e6, chosen on real
    frames, see ``DEFAULT_POLICY``): ``"none"`` the original's estimate; ``"min_count"`` pools
    classes with fewer than ``min_count`` pixels; ``"shrink"`` shrinks every class toward the
    pooled statistics with a prior worth ``strength`` pixels. A class with fewer than 2 counted
    pixels or zero variance is *degenerate*: under ``"none"``, ``missing="error"`` raises
    ``ValueError`` naming them and ``missing="pooled"`` gives them the mean and std over all
    counted pixels of all classes; ``"min_count"`` pools them too. ``stats_finalize_report``
    also says what happened to each class.
    """
    return stats_finalize_report(stats, missing=missing, policy=policy, min_count=min_count,
                                 strength=strength)[:2]


def stats_finalize_report(stats: ClassStats, *, missing: str = "error", policy: str = DEFAULT_POLICY,
                          min_count: float = 10_000, strength: float = DEFAULT_STRENGTH) -> FinalizedStats:
    """``stats_finalize`` with, per class, its pixel count and whether it was fitted, pooled or shrunk."""
    if missing not in ("error", "pooled"):
        raise ValueError(f'missing must be "error" or "pooled", got {missing!r}')
    check_policy(policy, min_count, strength)
    count, mean, m2 = (np.asarray(x, np.float64) for x in stats)
    if not all(np.isfinite(x).all() for x in (count, mean, m2)):
        raise ValueError("stats hold NaN/Inf: NaN or Inf logits were counted (stats_update checks its input; "
                         "statistics merged or built by hand do not)")
    return finalize(count, mean, m2, policy=policy, min_count=min_count, strength=strength, missing=missing)


def save_stats(path, mean, std, counts, *, status=None, policy: dict | None = None,
               channels: dict | None = None, frames: dict | None = None) -> None:
    """Write ``mean``, ``std``, ``counts`` (each ``(C,)``) to an ``.npz`` file, atomically.

    Optional: ``status`` ``(C,)`` strings (``FinalizedStats.status``), ``policy`` (a JSON-able
    dict, e.g. ``{"policy": "shrink", "strength": 1e4}``), ``channels`` (a JSON-able dict: which
    of the network's outputs the C classes are, e.g. ``{"network_outputs": 20, "void_dropped":
    true}``) and ``frames`` (a JSON-able dict: the frames the statistics were fitted on, e.g.
    ``{"set": "cityscapes train", "folder": ..., "count": 200, "size": [512, 1024]}``);
    ``load_stats_info`` reads them back.
    """
    arrays = {"mean": np.asarray(mean, np.float32), "std": np.asarray(std, np.float32),
              "counts": np.rint(np.asarray(counts, np.float64)).astype(np.int64)}
    if status is not None:
        arrays["status"] = np.asarray(status, dtype=str)
    shapes = {k: v.shape for k, v in arrays.items()}
    if len(set(shapes.values())) != 1 or arrays["mean"].ndim != 1:
        raise ValueError(f"mean, std and counts must all have shape (C,), got {shapes}")
    if not os.path.isdir(os.path.dirname(os.path.abspath(path))):
        raise ValueError(f"path must be in an existing folder, got {str(path)!r}")
    _check_saved_stats(f"statistics for {str(path)!r}", arrays["mean"], arrays["std"], arrays["counts"])
    for name, record in (("policy", policy), ("channels", channels), ("frames", frames)):
        if record is not None:
            arrays[name] = np.asarray(json.dumps(record))
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    write_bytes_atomic(path, buffer.getvalue())


def load_stats(path) -> tuple[jax.Array, jax.Array, np.ndarray]:
    """Read ``(mean, std, counts)`` written by ``save_stats``; mean/std float32 ``(C,)``, counts int64."""
    if not os.path.isfile(path):
        raise ValueError(f"path must be an existing .npz statistics file, got {str(path)!r}")
    with open(path, "rb") as f:
        start = f.read(6)
    if start[:4] != b"PK\x03\x04" and start != b"\x93NUMPY":  # neither .npz (a zip) nor .npy
        raise ValueError(f"path {str(path)!r} is not a readable .npz file (it starts with {start!r}); expected the "
                         "statistics .npz that jaxanom fit-stats (or sml.save_stats) writes")
    try:
        loaded = np.load(path, allow_pickle=False)
        arrays = None
        if isinstance(loaded, np.lib.npyio.NpzFile):
            with loaded as data:
                arrays = {name: data[name] for name in data.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as error:
        raise ValueError(f"path {str(path)!r} is not a readable .npz file: {type(error).__name__}: {error}") from None
    if arrays is None:
        raise ValueError(f"path {str(path)!r} holds a single array (an .npy file); expected an .npz file with arrays "
                         "mean, std, counts (from save_stats / jaxanom fit-stats)")
    absent = {"mean", "std", "counts"} - set(arrays)
    if absent:
        raise ValueError(f"{str(path)!r} must hold arrays mean, std, counts; missing {sorted(absent)}")
    _check_saved_stats(repr(str(path)), **{name: arrays[name] for name in ("mean", "std", "counts")})
    return jnp.asarray(arrays["mean"], jnp.float32), jnp.asarray(arrays["std"], jnp.float32), arrays["counts"]


def load_stats_info(path) -> dict:
    """How, of which outputs and on what frames the statistics in ``path`` were fitted:
    ``{"status": [C strings] | None, "policy": dict | None, "channels": dict | None, "frames":
    dict | None}`` (``save_stats``).

    Files written without that information (older ones, or ``save_stats`` without it) give None.
    """
    load_stats(path)  # the same checks
    with np.load(path, allow_pickle=False) as data:
        status = data["status"].tolist() if "status" in data.files else None
        records = {name: json.loads(str(data[name])) if name in data.files else None
                   for name in ("policy", "channels", "frames")}
    return {"status": status, **records}


def _check_saved_stats(path: str, mean, std, counts) -> None:
    """What ``save_stats`` writes: three (C,) arrays, real numbers, mean finite, std > 0, counts >= 0
    (ValueError naming the classes that break a rule); ``path``: how messages name the file."""
    shapes = {"mean": mean.shape, "std": std.shape, "counts": counts.shape}
    if len(set(shapes.values())) != 1 or mean.ndim != 1 or mean.size == 0:
        raise ValueError(f"{path}: mean, std and counts must all have one shape (C,), got {shapes}")
    for name, values, kind in (("mean", mean, "f"), ("std", std, "f"), ("counts", counts, "iu")):
        if values.dtype.kind not in kind:
            raise ValueError(f"{path}: {name} must be {'floating' if kind == 'f' else 'integer'}, got dtype {values.dtype}")
    for name, values, good, rule in (("mean", mean, np.isfinite(mean), "finite"),
                                     ("std", std, np.isfinite(std) & (std > 0), "finite and > 0"),
                                     ("counts", counts, counts >= 0, ">= 0")):
        bad = np.flatnonzero(~good)
        if bad.size:
            raise ValueError(f"{path}: {name} must be {rule}; classes {bad.tolist()} have {values[bad].tolist()}")
