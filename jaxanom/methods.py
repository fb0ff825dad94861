"""Anomaly-scoring methods by name: the rows of every results table.

``score_batch(name, logits, ...)`` maps a batch of logits ``(B, H, W, C)`` to scores
``(B, H, W)``, higher = more anomalous. Names:

- ``msp``, ``max_logit``, ``entropy``, ``energy``, ``softmax_distance``: ``jaxanom.scores``;
- ``sml``: standardized max logit alone (SML Eq. 5), needs ``stats = (mean, std)``;
- ``sml_suppress``, ``sml_smooth``, ``sml_post``: with boundary suppression, dilated
  smoothing, or both (SML Table 3);
- ``msp_post``, ``max_logit_post``: suppression + smoothing applied to MSP / max logit
  (SML Table 7), using the network's prediction for the boundaries;
- ``cudam``: the CuDAM ensemble (Eq. 10) of ``sml_post`` and the upsampled attention map.
"""
from __future__ import annotations

from typing import Callable

import jax
import jax.numpy as jnp

from jaxanom import scores, sml
from jaxanom.cudam_score import cudam_score

_PLAIN: dict[str, Callable] = {
    "msp": scores.msp_batch,
    "max_logit": scores.max_logit_batch,
    "entropy": scores.entropy_batch,
    "energy": scores.energy_batch,
    "softmax_distance": scores.softmax_distance_batch,
}
_SML_OPTIONS = {
    "sml": dict(suppress=False, smooth=False),
    "sml_suppress": dict(suppress=True, smooth=False),
    "sml_smooth": dict(suppress=False, smooth=True),
    "sml_post": dict(suppress=True, smooth=True),
}
_POSTPROCESSED = {"msp_post": "msp", "max_logit_post": "max_logit"}

METHODS: tuple[str, ...] = (*_PLAIN, *_SML_OPTIONS, *_POSTPROCESSED, "cudam")
NEEDS_STATS = frozenset({*_SML_OPTIONS, "cudam"})
NEEDS_ATTENTION = frozenset({"cudam"})


def check_methods(names, *, have_stats: bool, have_attention: bool) -> tuple[str, ...]:
    """Validate a list of method names against what is available; returns them as a tuple."""
    names = tuple(names)
    unknown = [n for n in names if n not in METHODS]
    if unknown or not names:
        raise ValueError(f"methods: expected names from {METHODS}, got {list(names)}")
    if not have_stats and (missing := [n for n in names if n in NEEDS_STATS]):
        raise ValueError(f"methods {missing} need SML class statistics (mean, std); none were given")
    if not have_attention and (missing := [n for n in names if n in NEEDS_ATTENTION]):
        raise ValueError(f"methods {missing} need an attention map; the model has no CuDAM module")
    return names


def score_batch(name: str, logits, *, stats=None, attention_up=None, cudam_sigma: float = 2e4) -> jax.Array:
    """Scores of method ``name`` for logits ``(B, H, W, C)`` -> float32 ``(B, H, W)``.

    ``stats``: ``(mean, std)`` each ``(C,)`` for the SML methods; ``attention_up``:
    ``(B, H, W)`` attention already upsampled to the logits' size, and ``cudam_sigma`` (Eq. 10),
    for ``cudam``.
    """
    check_methods([name], have_stats=stats is not None, have_attention=attention_up is not None)
    if name in _PLAIN:
        return _PLAIN[name](logits)
    if name in _SML_OPTIONS:
        return sml.sml_score_batch(logits, *stats, **_SML_OPTIONS[name])
    if name in _POSTPROCESSED:
        prediction = jnp.argmax(jnp.asarray(logits), axis=-1).astype(jnp.int32)
        return sml.postprocess_batch(_PLAIN[_POSTPROCESSED[name]](logits), prediction)
    return cudam_score(sml.sml_score_batch(logits, *stats), attention_up, cudam_sigma)
