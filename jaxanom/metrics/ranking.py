"""Pixels ordered from the highest anomaly score to the lowest, with their class.

Scores become unsigned integer keys whose ascending order is the descending order of the
scores (IEEE-754 bit trick, -0.0 merged with +0.0), so that a float32 score and its 2-bit class
pack into one uint64 and a single-operand sort orders both. XLA sorts one integer operand much
faster than several operands (on CPU about 1.6 s against 10 s for 20M pixels). float64 scores
need all 64 bits and take the slower two-operand sort.

Everything here needs 64-bit types: call it inside ``jax.enable_x64(True)``.
"""
from __future__ import annotations

import jax.numpy as jnp
import numpy as np
from jax import lax

NEGATIVE, POSITIVE, VOID = 0, 1, 3  # class codes; label 255 becomes VOID


def descending_keys(scores: jnp.ndarray) -> jnp.ndarray:
    """Float scores (any shape) -> uint32 keys (uint64 for float64) sorted ascending = scores descending."""
    if scores.dtype == jnp.float64:
        uint, sign = jnp.uint64, np.uint64(1 << 63)
    else:
        scores, uint, sign = scores.astype(jnp.float32), jnp.uint32, np.uint32(1 << 31)
    scores = jnp.where(scores == 0, jnp.zeros_like(scores), scores)  # -0.0 ties with +0.0
    bits = lax.bitcast_convert_type(scores, uint)
    ascending = jnp.where(bits & sign, ~bits, bits | sign)
    return ~ascending


def keys_to_scores(keys, float64: bool) -> np.ndarray:
    """Inverse of ``descending_keys`` on the host: keys -> float64 scores (float32 values unless ``float64``)."""
    keys = np.asarray(keys)
    uint, flt = (np.uint64, np.float64) if float64 else (np.uint32, np.float32)
    sign = uint(1) << uint(8 * np.dtype(uint).itemsize - 1)
    ascending = ~keys.astype(uint)
    bits = np.where(ascending & sign, ascending ^ sign, ~ascending).astype(uint)
    return bits.view(flt).astype(np.float64)


def class_codes(labels: jnp.ndarray) -> jnp.ndarray:
    """Labels {0, 1, 255} -> codes {NEGATIVE, POSITIVE, VOID} as uint8."""
    return jnp.where(labels == 255, VOID, labels).astype(jnp.uint8)


def sort_pixels(scores: jnp.ndarray, labels: jnp.ndarray) -> tuple[jnp.ndarray, jnp.ndarray]:
    """Flat scores (N,) float and labels (N,) {0,1,255} -> (keys, codes), both (N,), sorted.

    Keys ascend (scores descend); void pixels come last and never share a key with a real
    score. Keys are uint64 (holding the 32-bit key unless the scores are float64).
    """
    keys, codes = descending_keys(scores), class_codes(labels)
    void = codes == VOID
    if keys.dtype == jnp.uint32:
        packed = (keys.astype(jnp.uint64) << 2) | codes.astype(jnp.uint64)
        packed = lax.sort(jnp.where(void, jnp.uint64(2**64 - 1), packed))
        return packed >> 2, (packed & 3).astype(jnp.uint8)
    keys = jnp.where(void, jnp.uint64(2**64 - 1), keys)
    return lax.sort((keys, codes), num_keys=1)
