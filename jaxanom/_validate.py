"""Input checks for the public, eager entry points.

Each check raises ``ValueError`` naming the argument, what was expected and what came.
Checks of *values* (finiteness, signs) run only on concrete arrays: under ``jax.jit`` or
``jax.vmap`` the inputs are tracers and the functions do math only, as DESIGN.md asks.
Shape checks run in both cases, since shapes are known while tracing.
"""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np


def is_concrete(x) -> bool:
    """True when ``x`` holds values (not a tracer inside jit / vmap / grad)."""
    return not isinstance(x, jax.core.Tracer)


def check_rank(name: str, x, rank: int, layout: str) -> None:
    """``x`` must have ``rank`` dimensions, described by ``layout`` such as ``"(H, W, C)"``."""
    if np.ndim(x) != rank:
        raise ValueError(f"{name} must have rank {rank} {layout}, got shape {np.shape(x)}")


@jax.jit
def _all_finite(x) -> jax.Array:
    # an all-reduction: XLA:CPU's vectorised max-reduction drops NaN above ~4096 entries
    return jnp.all(jnp.isfinite(x))


def check_finite(name: str, x) -> None:
    """No NaN or Inf in ``x`` (skipped for tracers); one compiled reduction, no host copy."""
    if not is_concrete(x):
        return
    with jax.ensure_compile_time_eval():  # concrete even inside a caller's jit (closed-over arrays)
        finite = bool(_all_finite(jnp.asarray(x)))
    if not finite:
        bad = int(np.size(x) - np.count_nonzero(np.isfinite(np.asarray(x))))
        raise ValueError(f"{name} must be finite, got {bad} NaN/Inf value(s)")


def check_positive(name: str, x) -> None:
    """Every entry of ``x`` finite and > 0 (skipped for tracers)."""
    if is_concrete(x):
        values = np.asarray(x)
        bad = ~(np.isfinite(values) & (values > 0))
        if bad.any():
            raise ValueError(
                f"{name} must be finite and > 0, got {values[bad][:5].tolist()} "
                f"at index {np.flatnonzero(bad)[:5].tolist()}"
            )


def dtype_of(x) -> np.dtype:
    """The dtype of an array, tracer, or array-like (without converting a tracer)."""
    return np.dtype(x.dtype) if hasattr(x, "dtype") else np.asarray(x).dtype


def check_integer(name: str, x) -> None:
    """``x`` must have an integer dtype (class indices)."""
    dtype = dtype_of(x)
    if not np.issubdtype(dtype, np.integer):
        raise ValueError(f"{name} must hold integer class indices, got dtype {dtype}")
