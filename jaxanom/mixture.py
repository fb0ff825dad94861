"""Full-covariance Gaussian mixtures in JAX: densities, EM, k-means++ fitting and BIC.

The category model of the off-road paper (docs/papers/offroad.md#category-model, Eqs. 3-5). ``em`` follows scikit-learn's
``GaussianMixture`` step for step, so the same initial parameters give the same parameters,
lower bound and iteration count:

1. E-step: ``log r = log pi + log gamma - logsumexp``; the lower bound is the mean of the
   logsumexp (the log-likelihood per point of the parameters *before* this iteration's M-step);
2. M-step: ``n_k = sum_i r_ik + 10 eps``, means, centred covariances ``+ reg_covar I``,
   weights ``n_k / sum n_k``;
3. stop after the first iteration whose lower bound changed by less than ``tol`` (or at
   ``max_iter``).

``em``, ``fit_gmm`` and ``bic`` run in float64 under a local ``jax.enable_x64`` (inputs are
cast; results are float64 arrays). ``log_gaussian``, ``log_responsibilities`` and
``score_samples`` are pure and keep their inputs' dtype, so they work inside a caller's jit.
The choice of the component count (``select_components``) is host-side: ``fit_gmm`` compiles once per m
and per size of its zero-weight padded points (``shapes.padded_size``: four sizes per doubling of N); a
scan fits every count it tries in the room of its largest one (unused components take no weight and no
point), so it compiles once per size of points.
"""
from __future__ import annotations

import math
from typing import NamedTuple, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from jaxanom._validate import check_count, check_finite, check_rank
from jaxanom.shapes import padded_size


class GaussianMixture(NamedTuple):
    """Mixture parameters (a pytree): weights ``(m,)``, means ``(m, D)``, covariances ``(m, D, D)``."""

    weights: jax.Array
    means: jax.Array
    covariances: jax.Array


class EMResult(NamedTuple):
    """A fitted mixture, sklearn's ``lower_bound_`` and ``n_iter_``, and whether ``tol`` was met."""

    mixture: GaussianMixture
    lower_bound: jax.Array
    n_iter: jax.Array
    converged: jax.Array


# ---- pure functions (any float dtype) -------------------------------------------------------


def _precision_cholesky(covariances: jax.Array) -> jax.Array:
    """``inv(chol(Sigma_k)).T`` per component ``(m, D, D)``: ``z @ P`` whitens (NaN if not SPD)."""
    chol = jnp.linalg.cholesky(covariances)
    eye = jnp.broadcast_to(jnp.eye(covariances.shape[-1], dtype=covariances.dtype), covariances.shape)
    return jnp.swapaxes(jax.scipy.linalg.solve_triangular(chol, eye, lower=True), -1, -2)


def log_gaussian(z: jax.Array, means: jax.Array, covariances: jax.Array) -> jax.Array:
    """Eq. 3 in log form, ``log gamma(z_i; c_k)``: ``(N, D), (m, D), (m, D, D) -> (N, m)``.

    ``-1/2 (D log 2 pi + log|Sigma_k| + |L_k^-1 (z - mu_k)|^2)`` with ``L_k = chol(Sigma_k)``.
    """
    check_rank("z", z, 2, "(N, D)")
    check_rank("means", means, 2, "(m, D)")
    m, d = np.shape(means)
    if np.shape(z)[1] != d or np.shape(covariances) != (m, d, d):
        raise ValueError(f"z, means, covariances must have shapes (N, D), (m, D), (m, D, D) with one m and D, "
                         f"got {np.shape(z)}, {np.shape(means)}, {np.shape(covariances)}")
    prec = _precision_cholesky(covariances)
    log_det = jnp.sum(jnp.log(jnp.diagonal(prec, axis1=-2, axis2=-1)), axis=-1)  # -1/2 log|Sigma|
    y = jnp.einsum("nd,kde->nke", z, prec) - jnp.einsum("kd,kde->ke", means, prec)[None]
    return -0.5 * (z.shape[-1] * math.log(2 * math.pi) + jnp.sum(y * y, axis=-1)) + log_det


def log_responsibilities(z: jax.Array, mixture: GaussianMixture) -> tuple[jax.Array, jax.Array]:
    """``(log sum_k pi_k gamma_k (N,), log r (N, m))``: the E-step."""
    weighted = log_gaussian(z, mixture.means, mixture.covariances) + jnp.log(mixture.weights)
    norm = jax.nn.logsumexp(weighted, axis=-1)
    return norm, weighted - norm[:, None]


def score_samples(z: jax.Array, mixture: GaussianMixture) -> jax.Array:
    """Per-point log-likelihood ``log sum_k pi_k gamma(z_i; c_k)`` ``(N,)`` (Eq. 4 with the mixing weights the paper omits)."""
    return log_responsibilities(z, mixture)[0]


def _m_step(z: jax.Array, resp: jax.Array, reg_covar, active: jax.Array) -> GaussianMixture:
    """``active (room,)``: the components in use; the others get weight 0 (so no point in the next
    E-step) and the identity covariance (so their densities stay finite and add exp(-inf) = 0)."""
    nk = jnp.sum(resp, axis=0) + 10 * jnp.finfo(resp.dtype).eps
    means = resp.T @ z / nk[:, None]

    def covariance(r, mu, n):
        diff = z - mu
        return (r[:, None] * diff).T @ diff / n + reg_covar * jnp.eye(z.shape[-1], dtype=z.dtype)

    covariances = jnp.where(active[:, None, None], jax.vmap(covariance)(resp.T, means, nk), jnp.eye(z.shape[-1], dtype=z.dtype))
    nk = jnp.where(active, nk, 0.0)
    return GaussianMixture(nk / jnp.sum(nk), means, covariances)


def _em_loop(z, weight, mixture: GaussianMixture, reg_covar, tol, max_iter, active) -> EMResult:
    """EM over the points of weight 1 (``weight (N,)`` 1 or 0: 0 for the padding ``fit_gmm`` adds) and the
    ``active (room,)`` components (the others have weight 0)."""
    count = jnp.sum(weight)

    def body(state):
        mixture, bound, n_iter, _ = state
        norm, log_resp = log_responsibilities(z, mixture)
        new_bound = jnp.sum(norm * weight) / count
        resp = jnp.exp(log_resp) * weight[:, None]
        return _m_step(z, resp, reg_covar, active), new_bound, n_iter + 1, jnp.abs(new_bound - bound) < tol

    def cond(state):
        return (state[2] < max_iter) & ~state[3]

    start = (mixture, jnp.asarray(-jnp.inf, z.dtype), jnp.asarray(0, jnp.int32), jnp.asarray(False))
    return EMResult(*jax.lax.while_loop(cond, body, start))


_em_jit = jax.jit(_em_loop)


def _kmeans(key, z: jax.Array, weight: jax.Array, m, room: int, steps: int) -> jax.Array:
    """k-means++ seeding (D^2 sampling) then ``steps`` Lloyd steps over the points of weight 1
    (``weight (N,)`` 1 or 0; a point of weight 0 is never a centre and moves none): labels ``(N,)``
    in ``0 .. m - 1``. ``m`` may be traced; ``room >= m`` (static) sizes the centres."""
    first, rest = jax.random.split(key)
    count = jnp.sum(weight.astype(jnp.int32))
    centres = jnp.zeros((room, z.shape[-1]), z.dtype).at[0].set(z[jax.random.randint(first, (), 0, count)])
    dist = weight * jnp.sum((z - centres[0]) ** 2, axis=-1)

    def seed(k, carry):
        centres, dist = carry
        p = jnp.where(jnp.sum(dist) > 0, dist / jnp.sum(dist), weight / count)  # all points equal: uniform
        # at most the last point of weight 1: the padding's running sum may round an ulp above the points'
        pick = jnp.minimum(jax.random.choice(jax.random.fold_in(rest, k), z.shape[0], p=p), count - 1)
        centres = centres.at[k].set(z[pick])
        return centres, jnp.minimum(dist, weight * jnp.sum((z - z[pick]) ** 2, axis=-1))

    centres, _ = jax.lax.fori_loop(1, m, seed, (centres, dist))

    def assign(centres):  # nearest centre by |c|^2 - 2 z.c (|z|^2 is the same for every centre)
        distance = jnp.sum(centres**2, axis=-1)[None] - 2 * z @ centres.T
        return jnp.argmin(jnp.where(jnp.arange(room) < m, distance, jnp.inf), axis=-1)

    def lloyd(_, centres):
        onehot = jax.nn.one_hot(assign(centres), room, dtype=z.dtype) * weight[:, None]
        count = jnp.sum(onehot, axis=0)
        mean = onehot.T @ z / jnp.maximum(count, 1)[:, None]
        return jnp.where(count[:, None] > 0, mean, centres)  # an empty cluster keeps its centre

    return assign(jax.lax.fori_loop(0, steps, lloyd, centres))


def _fit_one(key, z, weight, m, room: int, lloyd_steps: int, reg_covar, tol, max_iter) -> EMResult:
    """One init of ``m`` (traced) components in a mixture of ``room`` (static); the rest stay unused."""
    active = jnp.arange(room) < m
    resp = jax.nn.one_hot(_kmeans(key, z, weight, m, room, lloyd_steps), room, dtype=z.dtype) * weight[:, None]
    return _em_loop(z, weight, _m_step(z, resp, reg_covar, active), reg_covar, tol, max_iter, active)


_fit_many = jax.jit(jax.vmap(_fit_one, in_axes=(0,) + (None,) * 8), static_argnums=(4, 5))


# ---- public, validated, float64 --------------------------------------------------------------


def _check_points(z, min_points: int = 1) -> np.ndarray:
    check_rank("z", z, 2, "(N, D)")
    if np.shape(z)[0] < min_points or np.shape(z)[1] < 1:
        raise ValueError(f"z must hold at least {min_points} point(s) of dimension >= 1, got shape {np.shape(z)}")
    check_finite("z", z)
    return np.asarray(z, np.float64)


def _check_mixture(weights, means, covariances, dim: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    check_rank("weights", weights, 1, "(m,)")
    m = np.shape(weights)[0]
    if m < 1:
        raise ValueError("weights must hold at least one component, got none")
    if np.shape(means) != (m, dim):
        raise ValueError(f"means must have shape (m, D) = {(m, dim)}, got {np.shape(means)}")
    if np.shape(covariances) != (m, dim, dim):
        raise ValueError(f"covariances must have shape (m, D, D) = {(m, dim, dim)}, got {np.shape(covariances)}")
    for name, x in (("weights", weights), ("means", means), ("covariances", covariances)):
        check_finite(name, x)
    w = np.asarray(weights, np.float64)
    if (w <= 0).any():
        raise ValueError(f"weights must be > 0, got {w.tolist()}")
    return w, np.asarray(means, np.float64), np.asarray(covariances, np.float64)


def _check_fit_options(reg_covar, tol, max_iter) -> None:
    if not reg_covar >= 0:
        raise ValueError(f"reg_covar must be >= 0, got {reg_covar}")
    if not tol >= 0:
        raise ValueError(f"tol must be >= 0, got {tol}")
    check_count("max_iter", max_iter)  # a loop counter in int32


def _checked_result(result: EMResult) -> EMResult:
    finite = np.isfinite(np.asarray(result.mixture.covariances)).all() and np.isfinite(np.asarray(result.lower_bound)).all()
    if not finite:
        raise ValueError("EM met an ill-defined covariance (not positive definite); increase reg_covar or give fewer components")
    return result


def em(z, weights, means, covariances, *, reg_covar: float = 1e-6, tol: float = 1e-3, max_iter: int = 100) -> EMResult:
    """EM from the given parameters, as sklearn's ``GaussianMixture(covariance_type="full")``.

    ``z (N, D)``; ``weights (m,)``, ``means (m, D)``, ``covariances (m, D, D)``: the initial
    parameters (sklearn's ``weights_init``, ``means_init`` and ``inv(precisions_init)``).
    Returns float64 ``EMResult``; ``lower_bound`` and ``n_iter`` are sklearn's ``lower_bound_``
    and ``n_iter_``. Host entry point (validates, switches on float64).
    """
    x = _check_points(z)
    start = _check_mixture(weights, means, covariances, x.shape[1])
    _check_fit_options(reg_covar, tol, max_iter)
    with jax.enable_x64(True):
        result = _em_jit(jnp.asarray(x), jnp.ones(len(x)), GaussianMixture(*map(jnp.asarray, start)),
                         jnp.float64(reg_covar), jnp.float64(tol), jnp.int32(max_iter), jnp.ones(len(start[0]), bool))
    return _checked_result(result)


def fit_gmm(key, z, m: int, *, n_init: int = 3, lloyd_steps: int = 10, reg_covar: float = 1e-6,
            tol: float = 1e-3, max_iter: int = 100, room: int | None = None) -> EMResult:
    """Fit ``m`` components: per init, k-means++ seeding + ``lloyd_steps`` Lloyd steps, then EM.

    The ``n_init`` initialisations (keys split from ``key``) run vmapped; the one with the
    highest lower bound is kept (the first on ties), as in sklearn. ``z (N, D)`` with N >= m.
    ``room`` (>= m, default m): the components compiled for; fits of any m up to one room share a
    compile, and give the fit of room m within rounding (the unused components' sums add zeros).
    """
    check_count("m", m)
    room = int(m) if room is None else check_count("room", room, minimum=int(m))
    x = _check_points(z, min_points=int(m))
    check_count("n_init", n_init)
    check_count("lloyd_steps", lloyd_steps, minimum=0)
    _check_fit_options(reg_covar, tol, max_iter)
    keys = jax.random.split(key, int(n_init))
    # the points padded with zero-weight rows to one of a few sizes per doubling (``padded_size``):
    # one compile serves every N of a bucket (a BIC scan's data sets, each frame set of a run)
    padded = np.zeros((padded_size(len(x)), x.shape[1]))
    padded[:len(x)] = x
    with jax.enable_x64(True):
        results = _fit_many(keys, jnp.asarray(padded), jnp.asarray(np.arange(len(padded)) < len(x), jnp.float64),
                            jnp.int32(m), room, int(lloyd_steps), jnp.float64(reg_covar), jnp.float64(tol),
                            jnp.int32(max_iter))
    best = best_init(np.asarray(results.lower_bound))
    result = jax.tree_util.tree_map(lambda a: a[best], results)
    return _checked_result(result._replace(mixture=GaussianMixture(*(a[:m] for a in result.mixture))))


def best_init(bounds: np.ndarray) -> int:
    """The index of the highest lower bound ``bounds (n_init,)``, the first on ties (as sklearn); NaN
    loses. Bounds within 1e-9 (relative) are ties: which of two equally good fits wins must not hang on
    the last bit, which another CPU or another order of summation can change."""
    bounds = np.where(np.isnan(bounds), -np.inf, bounds)
    return int(np.argmax(bounds >= bounds.max() - 1e-9 * max(1.0, abs(bounds.max()))))


def n_parameters(m: int, dim: int) -> int:
    """Free parameters of a full-covariance mixture: ``mD + mD(D+1)/2 + m - 1`` (sklearn's count)."""
    return m * dim + m * dim * (dim + 1) // 2 + m - 1


def bic(z, mixture: GaussianMixture) -> float:
    """Eq. 5: ``-2 log L + u log N``, with L including the mixing weights (as Eq. 4 here); sklearn's ``.bic``."""
    x = _check_points(z)
    w, mu, cov = _check_mixture(*mixture, x.shape[1])
    with jax.enable_x64(True):
        log_l = float(jnp.sum(jax.jit(score_samples)(jnp.asarray(x), GaussianMixture(*map(jnp.asarray, (w, mu, cov))))))
    return -2.0 * log_l + n_parameters(len(w), x.shape[1]) * math.log(x.shape[0])


def decisive_minimum(counts: Sequence[int], bics: Sequence[float], threshold: float = 10.0) -> int:
    """The component count at the first decisive local minimum of a BIC curve (docs/papers/offroad.md#component-count).

    ``counts`` ascending, consecutive candidates; ``bics`` their BIC values. The smallest m with
    ``BIC(m) <= BIC(m-1)`` (vacuous for the first candidate) and ``BIC(m+1) - BIC(m) >= threshold``
    (Kass-Raftery "very strong" evidence against the next count); if none, the argmin (first on ties).
    """
    counts, values = list(map(int, counts)), np.asarray(bics, np.float64)
    if len(counts) < 1 or values.shape != (len(counts),):
        raise ValueError(f"bics must be one value per count, got {values.shape} for {len(counts)} counts")
    if any(b - a != 1 for a, b in zip(counts, counts[1:])):
        raise ValueError(f"counts must be consecutive and ascending, got {counts}")
    if not np.isfinite(values).all():
        raise ValueError(f"bics must be finite, got {values.tolist()}")
    for i in range(len(counts) - 1):
        if (i == 0 or values[i] <= values[i - 1]) and values[i + 1] - values[i] >= threshold:
            return counts[i]
    return counts[int(np.argmin(values))]


def select_components(key, z, counts: Sequence[int] = tuple(range(2, 13)), *, threshold: float = 10.0,
                      max_count: int | None = None, **fit_options) -> tuple[int, dict[int, EMResult], dict[int, float]]:
    """Fit every count in ``counts`` (default 2..12: the paper found 9 at its finest level) and pick one by ``decisive_minimum``.

    While the pick is the last count scanned (the curve still falls at the top), the scan goes on
    one count at a time up to ``max_count`` (default: no extension) and while m <= N, so a
    minimum found is interior. Returns ``(m, {m: EMResult}, {m: BIC})``; ``fit_options`` go to
    ``fit_gmm``. Host-side. The counts given are fitted in the room of the largest, the extension in
    the room of the last it may reach: one compile for each, and every fit runs at the cost of its room.
    """
    counts = [int(c) for c in counts]
    if len(counts) < 2 or min(counts) < 1:
        raise ValueError(f"counts must hold at least two component counts >= 1, got {counts}")
    x = _check_points(z, min_points=max(counts))
    top = max(counts) if max_count is None else max(int(max_count), max(counts))
    fits, bics = {}, {}
    room = max(counts)
    while True:
        for m in counts:
            if m not in fits:
                fits[m] = fit_gmm(jax.random.fold_in(key, m), x, m, room=room, **fit_options)
                bics[m] = bic(x, fits[m].mixture)
        chosen = decisive_minimum(counts, [bics[m] for m in counts], threshold)
        if chosen < counts[-1] or counts[-1] >= min(top, x.shape[0]):
            return chosen, fits, bics
        counts.append(counts[-1] + 1)
        room = min(top, x.shape[0])
