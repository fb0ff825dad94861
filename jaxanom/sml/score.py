"""Standardized Max Logits (Eq. 5) and the full SML anomaly score."""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxanom._validate import check_finite, check_integer, check_positive, check_rank, check_real, check_static
from jaxanom.sml.boundaries import check_prediction
from jaxanom.sml.postprocessing import (
    _smooth,
    _suppress,
    check_score,
    check_smoothing,
    check_suppression,
    smoothing_weights,
)


def _standardized_max_logit(logits, mean, std):
    logits = logits.astype(jnp.float32)
    prediction = jnp.argmax(logits, axis=-1).astype(jnp.int32)
    sml = (jnp.max(logits, axis=-1) - mean[prediction]) / std[prediction]
    return sml, prediction


def _postprocess(score, prediction, weights, *, suppress, smooth, width, iterations, border, dilation):
    out = score.astype(jnp.float32)
    if suppress:
        out = _suppress(out, prediction, width, iterations, border)
    if smooth:
        out = _smooth(out, weights, dilation)
    return out


def _sml_score(logits, mean, std, weights, **options):
    sml, prediction = _standardized_max_logit(logits, mean, std)
    return -_postprocess(sml, prediction, weights, **options)


_OPTIONS = ("suppress", "smooth", "width", "iterations", "border", "dilation")


def _sml_score_batch_impl(logits, mean, std, weights, **options):
    return jax.vmap(lambda one: _sml_score(one, mean, std, weights, **options))(logits)


def _postprocess_batch_impl(score, prediction, weights, **options):
    return jax.vmap(lambda s, p: _postprocess(s, p, weights, **options))(score, prediction)


# Built once at import; the options that set shapes and loops are static, so each (shape,
# options) pair compiles once; the smoothing's weights (from sigma) are an argument.
_standardized_max_logit_jit = jax.jit(_standardized_max_logit)
_postprocess_jit = jax.jit(_postprocess, static_argnames=_OPTIONS)
_postprocess_batch = jax.jit(_postprocess_batch_impl, static_argnames=_OPTIONS)
_sml_score_jit = jax.jit(_sml_score, static_argnames=_OPTIONS)
_sml_score_batch = jax.jit(_sml_score_batch_impl, static_argnames=_OPTIONS)


def _checked_options(suppress, smooth, width, iterations, border, kernel_size, sigma, dilation) -> tuple:
    """(the smoothing's weights, the static options); ValueError / InputError on bad ones."""
    check_static("suppress", suppress, "chooses whether the suppression runs")
    check_static("smooth", smooth, "chooses whether the smoothing runs")
    check_suppression(width, iterations, border)
    check_smoothing(kernel_size, sigma, dilation)
    return smoothing_weights(int(kernel_size), sigma), dict(
        suppress=bool(suppress), smooth=bool(smooth), width=int(width), iterations=int(iterations), border=border,
        dilation=int(dilation))


def _check_logits_stats(logits, mean, std, batched: bool) -> None:
    check_rank("logits", logits, 4 if batched else 3, "(B, H, W, C)" if batched else "(H, W, C)")
    for name, x in (("mean", mean), ("std", std)):
        if np.shape(x) != (np.shape(logits)[-1],):
            raise ValueError(f"{name} must have shape (C,) = ({np.shape(logits)[-1]},) like the logits' classes, got {np.shape(x)}")
    for name, x in (("logits", logits), ("mean", mean), ("std", std)):
        check_real(name, x)
    check_finite("logits", logits)
    check_finite("mean", mean)
    check_positive("std", std)


def standardized_max_logit(logits, mean, std) -> tuple[jax.Array, jax.Array]:
    """Eq. 5: ``S = (L - mu_Y) / sigma_Y`` with ``L``, ``Y`` the max logit and argmax.

    logits float ``(H, W, C)``, mean/std float ``(C,)`` (std > 0) ->
    ``(sml float32 (H, W), prediction int32 (H, W))``. Higher SML = *less* anomalous.
    """
    _check_logits_stats(logits, mean, std, batched=False)
    return _standardized_max_logit_jit(jnp.asarray(logits), jnp.asarray(mean, jnp.float32), jnp.asarray(std, jnp.float32))


def postprocess(score, prediction, *, suppress=True, smooth=True, width=4, iterations=4, border="geodesic",
                kernel_size=7, sigma=1.0, dilation=6) -> jax.Array:
    """Boundary suppression then dilated smoothing of any score map float ``(H, W)`` -> float32 ``(H, W)``.

    ``prediction`` int ``(H, W)`` gives the class boundaries. ``suppress`` / ``smooth`` toggle
    the two steps (the paper's Tables 3 and 7); the other options are those of
    ``suppress_boundaries`` and ``dilated_smoothing``. Turning both off returns the score.
    ``sigma`` may be traced (jit / vmap over a grid); every other option is static.
    """
    check_score(score)
    check_prediction(prediction, np.shape(score))
    weights, options = _checked_options(suppress, smooth, width, iterations, border, kernel_size, sigma, dilation)
    return _postprocess_jit(jnp.asarray(score), jnp.asarray(prediction), weights, **options)


def postprocess_batch(score, prediction, *, suppress=True, smooth=True, width=4, iterations=4, border="geodesic",
                      kernel_size=7, sigma=1.0, dilation=6) -> jax.Array:
    """``postprocess`` over a batch: score float ``(B, H, W)``, prediction int ``(B, H, W)``."""
    check_rank("score", score, 3, "(B, H, W)")
    check_real("score", score)
    check_finite("score", score)
    check_rank("prediction", prediction, 3, "(B, H, W)")
    check_integer("prediction", prediction)
    if np.shape(prediction) != np.shape(score):
        raise ValueError(f"prediction must have the score's shape {np.shape(score)}, got {np.shape(prediction)}")
    weights, options = _checked_options(suppress, smooth, width, iterations, border, kernel_size, sigma, dilation)
    return _postprocess_batch(jnp.asarray(score), jnp.asarray(prediction), weights, **options)


def sml_score(logits, mean, std, *, suppress=True, smooth=True, width=4, iterations=4, border="geodesic",
              kernel_size=7, sigma=1.0, dilation=6) -> jax.Array:
    """The SML anomaly score ``-postprocess(SML)``: logits ``(H, W, C)`` -> float32 ``(H, W)``.

    mean/std float ``(C,)`` from ``stats_finalize``; options as in ``postprocess``.
    """
    _check_logits_stats(logits, mean, std, batched=False)
    weights, options = _checked_options(suppress, smooth, width, iterations, border, kernel_size, sigma, dilation)
    return _sml_score_jit(jnp.asarray(logits), jnp.asarray(mean, jnp.float32), jnp.asarray(std, jnp.float32), weights, **options)


def sml_score_batch(logits, mean, std, *, suppress=True, smooth=True, width=4, iterations=4, border="geodesic",
                    kernel_size=7, sigma=1.0, dilation=6) -> jax.Array:
    """``sml_score`` over a batch: logits ``(B, H, W, C)`` -> float32 ``(B, H, W)``; one compile per shape and options."""
    _check_logits_stats(logits, mean, std, batched=True)
    weights, options = _checked_options(suppress, smooth, width, iterations, border, kernel_size, sigma, dilation)
    return _sml_score_batch(jnp.asarray(logits), jnp.asarray(mean, jnp.float32), jnp.asarray(std, jnp.float32), weights, **options)
