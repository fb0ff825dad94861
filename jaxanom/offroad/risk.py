"""Patch risk, the unknown label, the risk bound, voting and frame/sequence risk (Eqs. 6-15).

Per patch embedding z (off-road paper, Section III-C):

- Eq. 6: ``k* = argmax_k gamma(z; c_k)`` (densities without mixing weights, as printed);
- Eq. 7: the risk. ``risk="literal"`` gives ``1 - gamma(z; c_k*)``; the default
  ``"calibrated"`` (docs/papers/offroad.md#risk) gives ``F_train(-log gamma(z; c_k*))``, the fraction of training
  patches whose raw risk ``-log gamma`` is at most this one, in [0, 1]. Both are increasing in
  ``-gamma``; the calibrated label compares the raw risk with the raw order statistic behind
  ``r_sigma`` (``r_sigma N``-th smallest training raw risk), so the two give the same labels;
- Eq. 10: ``y = k*`` if ``r <= r_sigma`` else the unknown label ``phi = m``;
- Eq. 11: ``r_sigma`` = the smallest bound leaving at most ``1 - delta`` of the training risks
  above it (``risk_bound``);
- Eqs. 12-15: frame-level risk ``FLR = |{y = phi}| / N_t``, sequence risk
  ``Phi^s = |{t: FLR_t > eps}| / T``, mFLR = mean FLR, scene coverage ``Sc = 1 - Phi^s``.

``vote`` turns sliding-window patch labels into a dense label map with centre-weighted
(Gaussian) votes (docs/papers/offroad.md#voting). Single-frame functions have ``_batch`` twins (jit(vmap), built once).
"""
from __future__ import annotations

import math
from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxanom._validate import (check_finite, check_integer, check_labels, check_number, check_rank, is_concrete,
                               values_checked)
from jaxanom.mixture import GaussianMixture, log_gaussian
from jaxanom.shapes import padded_size

VOID = 255  # label of pixels that no window covers
RISKS = ("calibrated", "literal")  # classify's risk: calibrated on the training patches, or Eq. 9 as printed


class Classification(NamedTuple):
    """Per patch: the label ``y`` (int32, ``m`` = unknown), the risk (float32) and ``k*`` (int32)."""

    labels: jax.Array
    risk: jax.Array
    cluster: jax.Array


# ---- pure functions ----------------------------------------------------------------------------


def raw_risk(z: jax.Array, means: jax.Array, covariances: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Eq. 6 and the log form of Eq. 7: ``(k* (N,) int32, -log gamma(z; c_k*) (N,))``."""
    log_density = log_gaussian(z, means, covariances)
    best = jnp.argmax(log_density, axis=-1)
    return best.astype(jnp.int32), -jnp.take_along_axis(log_density, best[:, None], axis=-1)[:, 0]


def calibrate(raw: jax.Array, train_raw: jax.Array, count=None) -> jax.Array:
    """Empirical CDF of the training raw risks at ``raw``: ``|{train_raw <= raw}| / N_train``.
    ``count``: N_train when ``train_raw`` holds the training risks followed by +inf padding (default:
    all of it); the padding sorts last, and a raw risk of +inf still gets 1."""
    count = train_raw.shape[0] if count is None else count
    ranks = jnp.minimum(jnp.searchsorted(jnp.sort(train_raw), raw, side="right"), count)
    return ranks.astype(raw.dtype) / jnp.asarray(count, raw.dtype)


def _classify(z, means, covariances, r_sigma, train_raw, train_count, literal: bool) -> Classification:
    cluster, raw = raw_risk(z, means, covariances)
    if literal:
        risk = -jnp.expm1(-raw)  # 1 - gamma
        known = risk <= r_sigma
    else:
        risk = calibrate(raw, train_raw, train_count)  # F_train, reported; train_raw ends in +inf padding
        # Eq. 10 on the raw risks: raw <= r_(j) with j = r_sigma N (r_sigma = j / N from risk_bound), i.e. fewer
        # than j training risks lie strictly below; F_train <= r_sigma would also admit (r_(j), r_(j+1))
        below = jnp.searchsorted(jnp.sort(train_raw), raw, side="left")  # the padding is above every raw risk
        known = below < jnp.floor(r_sigma * train_count + 1e-6)
    labels = jnp.where(known, cluster, means.shape[0])
    return Classification(labels.astype(jnp.int32), risk.astype(jnp.float32), cluster)


_classify_jit = jax.jit(_classify, static_argnums=6)
_classify_batch = jax.jit(jax.vmap(_classify, in_axes=(0, None, None, None, None, None, None)), static_argnums=6)


def window_weights(patch_size: int, sigma: float) -> np.ndarray:
    """Centre weights of one window ``(s_p, s_p)``: ``exp(-|p - c|^2 / 2 sigma^2)``, c its geometric centre."""
    offset = np.arange(patch_size) - (patch_size - 1) / 2
    g = np.exp(-(offset**2) / (2 * sigma**2))
    return np.outer(g, g).astype(np.float32)


def _vote(centers, labels, risks, patch_size: int, height: int, width: int, num_labels: int, sigma: float):
    weights = jnp.asarray(window_weights(patch_size, sigma))
    top = centers - patch_size // 2  # window rows/cols: c - floor(s/2) ... c + ceil(s/2) - 1
    offsets = jnp.arange(patch_size)
    rows = top[:, 0, None, None] + offsets[None, :, None]
    cols = top[:, 1, None, None] + offsets[None, None, :]
    rows, cols = jnp.broadcast_arrays(rows, cols)
    inside = (rows >= 0) & (rows < height) & (cols >= 0) & (cols < width)
    w = jnp.where(inside, weights[None], 0.0)
    label_idx = jnp.broadcast_to(labels[:, None, None], rows.shape)
    votes = jnp.zeros((height, width, num_labels), jnp.float32).at[rows, cols, label_idx].add(w, mode="drop")
    total = jnp.zeros((height, width), jnp.float32).at[rows, cols].add(w, mode="drop")
    weighted_risk = jnp.zeros((height, width), jnp.float32).at[rows, cols].add(w * risks[:, None, None], mode="drop")
    covered = total > 0
    label_map = jnp.where(covered, jnp.argmax(votes, axis=-1), VOID).astype(jnp.int32)
    risk_map = jnp.where(covered, weighted_risk / jnp.where(covered, total, 1.0), 0.0)
    return VoteResult(label_map, votes, risk_map)


class VoteResult(NamedTuple):
    """Dense maps: labels ``(H, W)`` int32 (argmax of votes, lowest id on ties, 255 where no
    window reaches), votes ``(H, W, L)`` float32, risk ``(H, W)`` float32 (weighted mean, 0 if uncovered)."""

    labels: jax.Array
    votes: jax.Array
    risk: jax.Array


_STATIC = ("patch_size", "height", "width", "num_labels", "sigma")
_vote_jit = jax.jit(_vote, static_argnames=_STATIC)


def _vote_frames(centers, labels, risks, patch_size, height, width, num_labels, sigma):
    one = partial(_vote, patch_size=patch_size, height=height, width=width, num_labels=num_labels, sigma=sigma)
    return jax.vmap(one, in_axes=(None, 0, 0))(centers, labels, risks)


_vote_batch = jax.jit(_vote_frames, static_argnames=_STATIC)


def _frame_risk(labels, unknown: int):
    return jnp.mean((labels == unknown).astype(jnp.float32))


_frame_risk_jit = jax.jit(_frame_risk, static_argnums=1)
_frame_risk_batch = jax.jit(jax.vmap(_frame_risk, in_axes=(0, None)), static_argnums=1)


# ---- public, validated -----------------------------------------------------------------------


def _check_embeddings(z, batched: bool, dim: int | None = None) -> None:
    if batched:
        check_rank("z", z, 3, "(B, N, D)")
    else:
        check_rank("z", z, 2, "(N, D)")
    if np.shape(z)[-2] < 1:
        raise ValueError(f"z must hold at least one patch embedding, got shape {np.shape(z)}")
    if dim is not None and np.shape(z)[-1] != dim:
        raise ValueError(f"z must have D = {dim} features (the mixture's), got shape {np.shape(z)}")
    check_finite("z", z)


def _check_classify_args(z, mixture, r_sigma, train_raw, risk, batched):
    if risk not in RISKS:
        raise ValueError(f"risk must be 'calibrated' or 'literal', got {risk!r}")
    check_rank("mixture.means", mixture.means, 2, "(m, D)")
    _check_embeddings(z, batched, np.shape(mixture.means)[1])
    if risk == "calibrated":
        if train_raw is None:
            raise ValueError("train_raw (the training patches' raw risks) is required for risk='calibrated'")
        check_rank("train_raw", train_raw, 1, "(N_train,)")
        if np.shape(train_raw)[0] < 1:
            raise ValueError("train_raw must hold at least one training risk, got none")
        check_finite("train_raw", train_raw)
    check_finite("r_sigma", r_sigma)


def _run_classify(fn, z, mixture, r_sigma, train_raw, risk):
    train_raw = np.zeros(1) if train_raw is None else train_raw
    count, literal = np.shape(train_raw)[0], risk == "literal"
    args = (z, mixture.means, mixture.covariances, r_sigma)
    if all(is_concrete(a) for a in (*args, train_raw)):  # eager: float64 densities, float32 risks
        with jax.enable_x64(True):
            x64 = [jnp.asarray(np.asarray(a, np.float64)) for a in args]
            out = fn(*x64, jnp.asarray(_padded(np.asarray(train_raw, np.float64), np)), jnp.asarray(count), literal)
            return Classification(*(jnp.asarray(np.asarray(o)) for o in out))
    return fn(*map(jnp.asarray, args), _padded(jnp.asarray(train_raw), jnp), jnp.asarray(count), literal)


def _padded(train_raw, xp):
    """``train_raw`` with +inf appended up to ``shapes.padded_size``: one compile of ``_classify``
    serves every training set of a bucket of sizes. Below 256 risks, one bucket (sorting a few
    hundred values costs nothing; the off-road smoke runs' sets of 21-57 took three)."""
    count = train_raw.shape[0]
    return xp.concatenate([train_raw, xp.full(padded_size(count, min_step=256) - count, xp.inf, train_raw.dtype)])


def classify(z, mixture: GaussianMixture, r_sigma, train_raw=None, *, risk: str = "calibrated") -> Classification:
    """Eqs. 6, 7 and 10 for one frame's patches ``z (N, D)``.

    ``mixture``: the category model (only means and covariances enter Eq. 6). ``train_raw``:
    the training patches' ``-log gamma(z; c_k*)`` (``raw_risk(...)[1]`` on P^train), needed for
    the calibrated risk. ``r_sigma``: the bound from ``risk_bound`` on the training risks of
    the same kind. Labels are ``k*`` or ``m`` (unknown). Computed in float64 when eager.
    """
    _check_classify_args(z, mixture, r_sigma, train_raw, risk, batched=False)
    return _run_classify(_classify_jit, z, mixture, r_sigma, train_raw, risk)


def classify_batch(z, mixture: GaussianMixture, r_sigma, train_raw=None, *, risk: str = "calibrated") -> Classification:
    """``classify`` over frames: ``z (B, N, D)`` -> fields ``(B, N)``."""
    _check_classify_args(z, mixture, r_sigma, train_raw, risk, batched=True)
    return _run_classify(_classify_batch, z, mixture, r_sigma, train_raw, risk)


def training_risks(z_train, mixture: GaussianMixture, *, risk: str = "calibrated") -> tuple[np.ndarray, np.ndarray]:
    """``(raw, r)`` float64 on the training patches P^train: the raw risks (pass as ``train_raw``)
    and the risks of kind ``risk`` (pass to ``risk_bound``). Host-side."""
    if risk not in RISKS:
        raise ValueError(f"risk must be 'calibrated' or 'literal', got {risk!r}")
    _check_classify_args(z_train, mixture, 0.0, None, "literal", batched=False)
    with jax.enable_x64(True):
        args = (jnp.asarray(np.asarray(a, np.float64)) for a in (z_train, mixture.means, mixture.covariances))
        _, raw = jax.jit(raw_risk)(*args)
        r = -jnp.expm1(-raw) if risk == "literal" else calibrate(raw, raw)
        return np.asarray(raw), np.asarray(r)


def risk_bound(train_risks, delta: float = 0.95, *, bins: int | None = None) -> float:
    """Eq. 11: the smallest ``r_sigma`` with ``|{r_i > r_sigma}| / N <= 1 - delta``.

    Exact form (default): the order statistic ``r_(ceil(delta N))`` (1-based). With ``bins``,
    the paper's histogram solution: the smallest right edge of ``bins`` equal bins over
    [min, max] with at most ``1 - delta`` of the mass above it. Host-side.
    """
    r = np.asarray(train_risks, np.float64)
    if r.ndim != 1 or r.size == 0:
        raise ValueError(f"train_risks must be a non-empty 1-D array of training risks, got shape {r.shape}")
    if not np.isfinite(r).all():
        raise ValueError(f"train_risks must be finite, got {int(np.size(r) - np.isfinite(r).sum())} NaN/Inf value(s)")
    if not 0 < delta <= 1:
        raise ValueError(f"delta must be in (0, 1], got {delta}")
    n = r.size
    if bins is None:
        k = max(1, math.ceil(round(delta * n, 9)))  # round: 0.7 * 10 must give 7, not 8
        return float(np.sort(r)[k - 1])
    if int(bins) < 1:
        raise ValueError(f"bins must be >= 1, got {bins}")
    counts, edges = np.histogram(r, bins=int(bins))
    above = n - np.cumsum(counts)  # risks in later bins than each right edge
    ok = above <= round((1 - delta) * n, 9)
    return float(edges[1:][np.argmax(ok)])


def vote(centers, labels, risks=None, *, patch_size: int, height: int, width: int, num_labels: int,
         sigma: float | None = None) -> VoteResult:
    """Centre-weighted voting of sliding-window patch labels into a dense map (docs/papers/offroad.md#voting).

    ``centers (P, 2)`` int (row, col) window centres (the window spans ``c - floor(s/2)`` to
    ``c + ceil(s/2) - 1``, clipped to the image); ``labels (P,)`` in [0, num_labels) (the
    unknown label votes too); ``risks (P,)`` optional. Each window adds
    ``exp(-|p - c|^2 / 2 sigma^2)`` (sigma = s_p / 4 by default) to its label at each pixel p.
    """
    _check_vote_args(centers, labels, risks, patch_size, height, width, num_labels, batched=False)
    sigma = patch_size / 4 if sigma is None else float(sigma)
    risks = jnp.zeros(np.shape(labels), jnp.float32) if risks is None else jnp.asarray(risks, jnp.float32)
    return _vote_jit(jnp.asarray(centers, jnp.int32), jnp.asarray(labels, jnp.int32), risks, patch_size=int(patch_size),
                     height=int(height), width=int(width), num_labels=int(num_labels), sigma=sigma)


def vote_batch(centers, labels, risks=None, *, patch_size: int, height: int, width: int, num_labels: int,
               sigma: float | None = None) -> VoteResult:
    """``vote`` over frames sharing one window grid: ``centers (P, 2)``, ``labels``/``risks (B, P)``."""
    _check_vote_args(centers, labels, risks, patch_size, height, width, num_labels, batched=True)
    sigma = patch_size / 4 if sigma is None else float(sigma)
    risks = jnp.zeros(np.shape(labels), jnp.float32) if risks is None else jnp.asarray(risks, jnp.float32)
    return _vote_batch(jnp.asarray(centers, jnp.int32), jnp.asarray(labels, jnp.int32), risks, patch_size=int(patch_size),
                       height=int(height), width=int(width), num_labels=int(num_labels), sigma=sigma)


def _check_vote_args(centers, labels, risks, patch_size, height, width, num_labels, batched):
    check_rank("centers", centers, 2, "(P, 2)")
    check_integer("centers", centers)
    p = np.shape(centers)[0]
    if np.shape(centers)[1] != 2 or p < 1:
        raise ValueError(f"centers must have shape (P, 2) with P >= 1, got {np.shape(centers)}")
    expected = (np.shape(labels)[0], p) if batched and np.ndim(labels) == 2 else (p,)
    if np.shape(labels) != expected:
        raise ValueError(f"labels must have shape {'(B, P)' if batched else '(P,)'} with P = {p}, got {np.shape(labels)}")
    check_integer("labels", labels)
    if risks is not None:
        if np.shape(risks) != np.shape(labels):
            raise ValueError(f"risks must have the shape of labels {np.shape(labels)}, got {np.shape(risks)}")
        check_finite("risks", risks)
    for name, value in (("patch_size", patch_size), ("height", height), ("width", width), ("num_labels", num_labels)):
        if int(value) < 1:
            raise ValueError(f"{name} must be >= 1, got {value}")
    if values_checked(labels):
        values = np.asarray(labels)
        if values.size and (values.min() < 0 or values.max() >= num_labels):
            raise ValueError(f"labels must lie in [0, {num_labels}), got range [{values.min()}, {values.max()}]")


def frame_risk(labels, num_clusters: int) -> jax.Array:
    """Eqs. 12-13, the FLR: fraction of one frame's patch labels ``(P,)`` equal to the unknown label ``m``."""
    check_rank("labels", labels, 1, "(P,)")
    return _checked_frame_risk(_frame_risk_jit, labels, num_clusters)


def frame_risk_batch(labels, num_clusters: int) -> jax.Array:
    """FLR per frame: ``(T, P) -> (T,)``."""
    check_rank("labels", labels, 2, "(T, P)")
    return _checked_frame_risk(_frame_risk_batch, labels, num_clusters)


def _checked_frame_risk(fn, labels, num_clusters):
    check_integer("labels", labels)
    if np.shape(labels)[-1] < 1:
        raise ValueError(f"labels must hold at least one patch per frame, got shape {np.shape(labels)}")
    if int(num_clusters) < 1:
        raise ValueError(f"num_clusters must be >= 1, got {num_clusters}")
    check_labels("labels", labels, int(num_clusters) + 1)  # 0..m-1 clusters, m unknown
    return fn(jnp.asarray(labels), int(num_clusters))


def _check_flr(flr) -> np.ndarray:
    values = np.asarray(flr, np.float64)
    if values.ndim != 1 or values.size == 0:
        raise ValueError(f"flr must be a non-empty 1-D array of frame-level risks, got shape {values.shape}")
    if not (np.isfinite(values).all() and (values >= 0).all() and (values <= 1).all()):
        raise ValueError("flr must hold frame-level risks in [0, 1]")
    return values


def sequence_risk(flr, epsilon: float = 0.5) -> float:
    """Eqs. 14-15: ``Phi^s``, the fraction of frames whose FLR exceeds ``epsilon``."""
    check_number("epsilon", epsilon, 0.0, 1.0)
    return float(np.mean(_check_flr(flr) > epsilon))


def mean_frame_risk(flr) -> float:
    """mFLR: the mean frame-level risk of a sequence."""
    return float(np.mean(_check_flr(flr)))


def scene_coverage(flr, epsilon: float = 0.5) -> float:
    """Sc = 1 - Phi^s: the fraction of frames that are not risky."""
    return 1.0 - sequence_risk(flr, epsilon)
