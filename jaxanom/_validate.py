"""Input checks for the public, eager entry points.

Each check raises ``ValueError`` naming the argument, what was expected and what came (the
count and number checks an ``InputError``, whose argument a caller can spell as its own).
Shapes, ranks and dtypes are checked always: they are known without the data, even while tracing.
Values (finiteness, signs, ranges, class indices) are checked where the data already is on the
host: a NumPy array, a list or a Python number is read by NumPy, which copies nothing. A
``jax.Array`` is not read back (on an accelerator every read is a blocking device-to-host copy,
so a batch loop would wait for each batch's computation before sending the next), unless the
caller asks for it with ``validate_values()``; a tracer (inside ``jit`` / ``vmap`` / ``grad``)
has no value to check. Inside a traced function, ``jax.experimental.checkify`` finds the NaN
the math produces.
"""
from __future__ import annotations

import contextlib
import contextvars

import jax
import jax.numpy as jnp
import numpy as np

from jaxanom.errors import InputError

_READ_DEVICE_ARRAYS = contextvars.ContextVar("jaxanom_validate_values", default=False)


@contextlib.contextmanager
def validate_values(enabled: bool = True):
    """Inside this block, the value checks of jaxanom's functions read ``jax.Array`` inputs too
    (a device-to-host read per check: for debugging, not for batch loops)."""
    token = _READ_DEVICE_ARRAYS.set(bool(enabled))
    try:
        yield
    finally:
        _READ_DEVICE_ARRAYS.reset(token)


def is_concrete(x) -> bool:
    """True when ``x`` holds values (not a tracer inside jit / vmap / grad)."""
    return not isinstance(x, jax.core.Tracer)


def values_checked(x) -> bool:
    """Whether value checks read ``x``: it is on the host (not a ``jax.Array``), or it is a
    concrete ``jax.Array`` inside ``validate_values()``; never a tracer."""
    if not isinstance(x, jax.Array):
        return True
    return is_concrete(x) and _READ_DEVICE_ARRAYS.get()


def check_static(name: str, value, why: str) -> None:
    """An option that must be a Python value, not traced (inside jit / vmap / grad), because ``why``
    (e.g. "sets the kernel's shape"): a one-line ``InputError`` instead of a tracer error."""
    if not is_concrete(value):
        raise InputError(name, f"must be static (a Python value, not traced under jit / vmap / grad): it {why}")


def check_rank(name: str, x, rank: int, layout: str) -> None:
    """``x`` must have ``rank`` dimensions, described by ``layout`` such as ``"(H, W, C)"``."""
    if np.ndim(x) != rank:
        raise ValueError(f"{name} must have rank {rank} {layout}, got shape {np.shape(x)}")


@jax.jit
def _all_finite(x) -> jax.Array:
    # an all-reduction of isfinite: a float max-reduction would miss NaN (XLA:CPU drops NaN
    # from max-reductions of 4096 elements or more)
    return jnp.all(jnp.isfinite(x))


def in_host_memory(x) -> bool:
    """Whether NumPy reads ``x`` where it lies: a host array, or a JAX array on CPU devices only."""
    return not isinstance(x, jax.Array) or all(device.platform == "cpu" for device in x.devices())


def check_image_batch(images, multiple: int, scaling: str) -> None:
    """A network's input: ``(B, H, W, 3)`` float with H and W multiples of ``multiple`` (its total
    stride); ``scaling`` says how its float values are expected to be scaled."""
    if images.ndim != 4 or images.shape[-1] != 3:
        raise ValueError(f"images: expected (B, H, W, 3), got shape {images.shape}")
    if images.shape[1] % multiple or images.shape[2] % multiple:
        raise ValueError(f"images: expected H and W multiples of {multiple}, got {images.shape[1]}x{images.shape[2]}")
    if not jnp.issubdtype(images.dtype, jnp.floating):
        raise ValueError(f"images: expected a float dtype ({scaling}), got {images.dtype}")


def check_finite(name: str, x) -> None:
    """No NaN or Inf in ``x`` when ``values_checked(x)``: NumPy checks a host array; a
    ``jax.Array`` (inside ``validate_values()``) is checked by one compiled reduction where it
    lies, and one bool is read back. A concrete array closed over by a caller's ``jax.jit`` /
    ``vmap`` / ``grad`` is reduced eagerly (``ensure_compile_time_eval``) instead of traced."""
    if not values_checked(x) or not jnp.issubdtype(dtype_of(x), jnp.inexact):
        return
    if isinstance(x, jax.Array):
        with jax.ensure_compile_time_eval():
            finite = bool(_all_finite(x))
    else:
        finite = bool(np.isfinite(np.asarray(x)).all())
    if not finite:
        bad = int(np.size(x) - np.count_nonzero(np.isfinite(np.asarray(x))))
        raise ValueError(f"{name} must be finite, got {bad} NaN/Inf value(s)")


def check_positive(name: str, x) -> None:
    """Every entry of ``x`` finite and > 0 (when ``values_checked(x)``)."""
    if values_checked(x):
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


def check_real(name: str, x) -> None:
    """``x`` must hold real numbers: an integer or floating dtype, not bool or complex."""
    dtype = dtype_of(x)
    if dtype == bool or not (jnp.issubdtype(dtype, jnp.integer) or jnp.issubdtype(dtype, jnp.floating)):
        raise ValueError(f"{name} must have a real (integer or floating) dtype, got {dtype}")


def check_range(name: str, x, low: float, high: float, hint: str = "") -> None:
    """Every entry of ``x`` in ``[low, high]`` and not NaN (when ``values_checked(x)``); ``hint`` ends the message."""
    if not values_checked(x):
        return
    values = np.asarray(x)
    bad = ~((values >= low) & (values <= high))
    if bad.any():
        raise ValueError(f"{name} must lie in [{low}, {high}]{hint}, got {int(bad.sum())} value(s) outside "
                         f"(such as {values[bad][:3].tolist()})")


def check_count(name: str, value, minimum: int = 1, maximum: int = 2**31 - 1) -> int:
    """A whole number (int, or an integer NumPy scalar; not bool, not float) in ``[minimum, maximum]``;
    never traced (a count sets a shape or a loop: ``check_static``)."""
    check_static(name, value, "is a count (it sets a shape or a loop)")
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise InputError(name, f"must be an integer >= {minimum}, got {value!r} ({type(value).__name__})")
    if value < minimum:
        raise InputError(name, f"must be >= {minimum}, got {value}")
    if value > maximum:
        raise InputError(name, f"must be <= {maximum}, got {value}")
    return int(value)


def check_number(name: str, value, low: float = -np.inf, high: float = np.inf, *, open_low: bool = False) -> float:
    """A finite real number (int or float; not bool, not str) in ``[low, high]`` (``(low, high]`` with ``open_low``)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise InputError(name, f"must be a number, got {value!r} ({type(value).__name__})")
    inside = (value > low if open_low else value >= low) and value <= high
    if not (np.isfinite(value) and inside):
        raise InputError(name, f"must be a finite number in {'(' if open_low else '['}{low}, {high}], got {value!r}")
    return float(value)


def check_labels(name: str, x, count: int, void: int | None = None) -> None:
    """Integer labels in ``[0, count)`` (or equal to ``void``); values checked when ``values_checked(x)``."""
    check_integer(name, x)
    if not values_checked(x) or np.size(x) == 0:
        return
    values = np.asarray(x)
    bad = ((values < 0) | (values >= count)) & (values != void if void is not None else True)
    if bad.any():
        allowed = f"[0, {count - 1}]" + (f" or {void}" if void is not None else "")
        raise ValueError(f"{name} must hold values in {allowed}, got {int(bad.sum())} outside "
                         f"(such as {np.unique(values[bad])[:5].tolist()})")


def memory_bytes() -> int:
    """This machine's physical memory in bytes (0 where the system does not say)."""
    import os

    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return 0


def check_fits_memory(name: str, count: int, item_bytes: int, what: str) -> None:
    """``count`` items of ``item_bytes`` each (a batch's inputs, a lower bound of what it takes)
    must fit in this machine's memory; refused before anything is allocated."""
    total, memory = int(count) * int(item_bytes), memory_bytes()
    if memory and total > memory:
        raise ValueError(f"{name}: {count} {what} take at least {total / 2**30:.1f} GiB, more than this machine's "
                         f"{memory / 2**30:.1f} GiB of memory")
