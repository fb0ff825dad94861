"""Gaussian mixtures (jaxanom.mixture) against scipy and scikit-learn's GaussianMixture."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.stats import multivariate_normal
from sklearn.mixture import GaussianMixture as SklearnGMM

from jaxanom import mixture as mx
from compiles import compiled_during


def random_spd(rng, m, d, scale=1.0):
    a = rng.normal(size=(m, d, d))
    return scale * (a @ np.swapaxes(a, 1, 2) / d + 0.3 * np.eye(d))


def blobs(rng, m, d, n, spread=6.0):
    centres = rng.normal(size=(m, d)) * spread
    return np.concatenate([c + rng.normal(size=(n, d)) @ np.linalg.cholesky(random_spd(rng, 1, d)[0]).T for c in centres])


def test_log_gaussian_matches_scipy():
    rng = np.random.default_rng(0)
    z, means, cov = rng.normal(size=(37, 5)) * 3, rng.normal(size=(3, 5)), random_spd(rng, 3, 5)
    expected = np.stack([multivariate_normal(means[k], cov[k]).logpdf(z) for k in range(3)], axis=1)
    with jax.enable_x64(True):
        got = mx.log_gaussian(jnp.asarray(z), jnp.asarray(means), jnp.asarray(cov))
    assert got.dtype == jnp.float64
    np.testing.assert_allclose(got, expected, rtol=1e-12, atol=1e-10)
    got32 = mx.log_gaussian(jnp.asarray(z, jnp.float32), jnp.asarray(means, jnp.float32), jnp.asarray(cov, jnp.float32))
    np.testing.assert_allclose(got32, expected, rtol=1e-4, atol=1e-3)


@pytest.mark.parametrize("m, d, tol, max_iter", [(3, 2, 1e-3, 100), (4, 5, 1e-6, 300), (1, 3, 1e-3, 100), (5, 4, 1e-3, 3)])
def test_em_matches_sklearn_from_same_start(m, d, tol, max_iter):
    rng = np.random.default_rng(m * 10 + d)
    z = blobs(rng, max(m, 2), d, 60 + 7 * m, spread=2.5)
    w0 = rng.dirichlet(np.ones(m) * 3)
    mu0 = z[rng.choice(len(z), m, replace=False)]
    cov0 = random_spd(rng, m, d, scale=2.0)
    sk = SklearnGMM(m, covariance_type="full", weights_init=w0, means_init=mu0,
                    precisions_init=np.linalg.inv(cov0), tol=tol, max_iter=max_iter)
    if max_iter < 10:  # stopped before convergence: sklearn warns
        with pytest.warns(Warning, match="did not converge"):
            sk.fit(z)
    else:
        sk.fit(z)
    got = mx.em(z, w0, mu0, cov0, tol=tol, max_iter=max_iter)
    assert int(got.n_iter) == sk.n_iter_
    assert bool(got.converged) == sk.converged_
    np.testing.assert_allclose(got.mixture.weights, sk.weights_, rtol=0, atol=1e-10)
    np.testing.assert_allclose(got.mixture.means, sk.means_, rtol=0, atol=1e-8)
    np.testing.assert_allclose(got.mixture.covariances, sk.covariances_, rtol=0, atol=1e-8)
    np.testing.assert_allclose(float(got.lower_bound), sk.lower_bound_, rtol=1e-12)
    np.testing.assert_allclose(mx.bic(z, got.mixture), sk.bic(z), rtol=1e-12)
    with jax.enable_x64(True):
        _, log_resp = mx.log_responsibilities(jnp.asarray(z), got.mixture)
        log_l = mx.score_samples(jnp.asarray(z), got.mixture)
    np.testing.assert_allclose(np.exp(log_resp), sk.predict_proba(z), atol=1e-8)
    np.testing.assert_allclose(log_l, sk.score_samples(z), rtol=1e-10)


def test_n_parameters_is_sklearns_count():
    for m, d in [(1, 1), (3, 16), (12, 16), (5, 2)]:
        sk = SklearnGMM(m)
        sk.means_ = np.zeros((m, d))
        assert mx.n_parameters(m, d) == sk._n_parameters()


def test_fit_gmm_deterministic_and_not_worse_than_sklearn_kmeans_start():
    rng = np.random.default_rng(3)
    z = blobs(rng, 4, 3, 80)
    a = mx.fit_gmm(jax.random.key(7), z, 4)
    b = mx.fit_gmm(jax.random.key(7), z, 4)
    np.testing.assert_array_equal(a.mixture.means, b.mixture.means)
    sk = SklearnGMM(4, n_init=3, random_state=0).fit(z)
    assert float(a.lower_bound) >= sk.lower_bound_ - 1e-6  # well separated: both find the global optimum
    assert bool(a.converged)
    np.testing.assert_allclose(np.sort(a.mixture.weights), np.full(4, 0.25), atol=1e-6)


def test_select_components_recovers_separated_blobs():
    rng = np.random.default_rng(5)
    z = blobs(rng, 3, 2, 120, spread=8.0)
    m, fits, bics = mx.select_components(jax.random.key(0), z, range(2, 6))
    assert m == 3
    assert set(fits) == set(bics) == {2, 3, 4, 5}
    assert bics[3] == min(bics.values())


@pytest.mark.parametrize("curve, expected", [
    ([100, 80, 60, 75, 50], 4),        # first decisive local minimum, not the global one (6)
    ([100, 80, 60, 65, 50, 40], 7),    # a shallow dip (rise 5 < 10) is skipped; falls back to argmin
    ([50, 70, 40, 60], 2),             # the first candidate, rising by 20 after it
    ([100, 90, 80, 70], 5),            # monotone: argmin (the last)
    ([60, 60, 60, 60], 2),             # flat: argmin, first on ties
    ([100, 60, 60, 75], 4),            # equal to its left neighbour counts as a minimum
    ([100, 60, 69.9, 40], 5),          # rise just under the threshold
    ([100, 60, 70.0, 40], 3),          # rise exactly at the threshold
])
def test_decisive_minimum_on_hand_made_curves(curve, expected):
    assert mx.decisive_minimum(list(range(2, 2 + len(curve))), curve) == expected


def test_decisive_minimum_threshold_option():
    assert mx.decisive_minimum([2, 3, 4], [100, 60, 63], threshold=2.0) == 3
    assert mx.decisive_minimum([2, 3, 4], [100, 60, 63]) == 3  # argmin anyway
    assert mx.decisive_minimum([2, 3, 4, 5], [100, 60, 63, 20], threshold=2.0) == 3
    assert mx.decisive_minimum([2, 3, 4, 5], [100, 60, 63, 20]) == 5


def test_bad_input_raises_naming_the_argument():
    rng = np.random.default_rng(0)
    z = rng.normal(size=(5000, 2))
    w, mu, cov = np.full(2, 0.5), z[:2], np.stack([np.eye(2)] * 2)
    bad = z.copy()
    bad[4096, 1] = np.nan  # beyond the reach of a max-reduction's NaN detection on XLA:CPU
    with pytest.raises(ValueError, match="z must be finite"):
        mx.em(bad, w, mu, cov)
    with pytest.raises(ValueError, match="z must hold at least 1"):
        mx.em(np.zeros((0, 2)), w, mu, cov)
    with pytest.raises(ValueError, match="z must have rank 2"):
        mx.fit_gmm(jax.random.key(0), z[:, 0], 2)
    with pytest.raises(ValueError, match="means must have shape"):
        mx.em(z, w, mu[:, :1], cov)
    with pytest.raises(ValueError, match="weights must be > 0"):
        mx.em(z, np.array([1.0, 0.0]), mu, cov)
    with pytest.raises(ValueError, match="m must be >= 1"):
        mx.fit_gmm(jax.random.key(0), z, 0)
    with pytest.raises(ValueError, match="z must hold at least 3"):
        mx.fit_gmm(jax.random.key(0), z[:2], 3)
    with pytest.raises(ValueError, match="max_iter"):
        mx.em(z, w, mu, cov, max_iter=0)
    with pytest.raises(ValueError, match="counts must hold at least two"):
        mx.select_components(jax.random.key(0), z, [3])
    with pytest.raises(ValueError, match="consecutive"):
        mx.decisive_minimum([2, 4], [1.0, 2.0])
    with pytest.raises(ValueError, match="bics must be finite"):
        mx.decisive_minimum([2, 3], [1.0, np.nan])


def test_ill_defined_covariance_raises():
    z = np.repeat(np.array([[0.0, 0.0], [1.0, 1.0]]), 10, axis=0)  # every cluster is a single point
    with pytest.raises(ValueError, match="ill-defined covariance"):
        mx.em(z, np.full(2, 0.5), np.array([[0.0, 0.0], [1.0, 1.0]]), np.stack([np.eye(2)] * 2), reg_covar=0.0)


def test_kmeans_plus_plus_seeds_one_centre_in_each_far_apart_cluster():
    """D^2 seeding (no Lloyd step): a point of an already seeded tight cluster has probability
    ~(spread / separation)^2 = 1e-8 of being picked, so each cluster gets exactly one centre."""
    rng = np.random.default_rng(3)
    corners = np.array([[0.0, 0.0], [100.0, 0.0], [0.0, 100.0], [100.0, 100.0]])
    truth = np.repeat(np.arange(4), [5, 9, 7, 11])
    z = jnp.asarray(corners[truth] + rng.normal(size=(truth.size, 2)) * 0.01, jnp.float32)
    for seed in range(8):
        labels = np.asarray(mx._kmeans(jax.random.key(seed), z, jnp.ones(len(z), z.dtype), 4, 4, 0))
        assert [len(set(labels[truth == t])) for t in range(4)] == [1] * 4, (seed, labels)
        assert len(set(labels)) == 4, (seed, labels)


def test_fit_gmm_compiles_once_for_the_point_counts_of_one_padded_size():
    rng = np.random.default_rng(8)
    z = blobs(rng, 3, 5, 40)  # 120 points in 5-D (no other test fits 5-D); 100..112 all pad to 112
    fits, compiled = compiled_during(lambda: [mx.fit_gmm(jax.random.key(1), z[:n], 3) for n in (100, 105, 112)])
    assert compiled.count("jit(_fit_one)") == 1, compiled
    assert all(bool(f.converged) for f in fits)


@pytest.mark.parametrize("n", [97, 100, 112, 113])
def test_zero_weight_padding_leaves_the_fit_as_on_the_points_alone(n):
    """``fit_gmm`` pads the points with zero-weight rows; the same keys on the points alone (every
    weight 1, no padding) give the same fit within rounding (the sums' order differs)."""
    rng = np.random.default_rng(n)
    z = blobs(rng, 4, 3, 30, spread=3.0)[:n]
    fit = mx.fit_gmm(jax.random.key(2), z, 4, n_init=2)
    with jax.enable_x64(True):
        alone = mx._fit_many(jax.random.split(jax.random.key(2), 2), jnp.asarray(z), jnp.ones(n), jnp.int32(4), 4, 10,
                             jnp.float64(1e-6), jnp.float64(1e-3), jnp.int32(100))
    best = mx.best_init(np.asarray(alone.lower_bound))
    assert int(fit.n_iter) == int(alone.n_iter[best])
    np.testing.assert_allclose(fit.lower_bound, alone.lower_bound[best], rtol=1e-12)
    for a, b in zip(fit.mixture, alone.mixture):
        np.testing.assert_allclose(a, b[best], rtol=1e-9, atol=1e-12)


def _assert_same_fit(a, b):
    assert int(a.n_iter) == int(b.n_iter) and bool(a.converged) == bool(b.converged)
    np.testing.assert_allclose(a.lower_bound, b.lower_bound, rtol=1e-12)
    for x, y in zip(a.mixture, b.mixture):
        assert x.shape == y.shape
        np.testing.assert_allclose(x, y, rtol=1e-9, atol=1e-12)


def test_a_scan_fits_in_one_room_and_each_fit_equals_the_fit_in_a_room_of_its_own_size(monkeypatch):
    """``select_components`` fits 2..5 in a room of 5 components (one compile): the unused ones take no
    weight and no point, so each fit is ``fit_gmm``'s of that m alone (room m) within rounding."""
    z = blobs(np.random.default_rng(5), 3, 2, 120, spread=8.0)  # the data of the scan above: its compile is reused
    key, fit_gmm, rooms = jax.random.key(0), mx.fit_gmm, []
    monkeypatch.setattr(mx, "fit_gmm", lambda *args, **options: rooms.append(options["room"]) or fit_gmm(*args, **options))
    _, fits, _ = mx.select_components(key, z, range(2, 6))
    monkeypatch.undo()
    assert rooms == [5, 5, 5, 5]
    _, compiled = compiled_during(lambda: [mx.fit_gmm(key, z, m, room=5) for m in (1, 4)])
    assert "jit(_fit_one)" not in compiled, compiled  # any m in that room reuses the scan's compile
    for m in (2, 3):
        _assert_same_fit(fits[m], mx.fit_gmm(jax.random.fold_in(key, m), z, m))
        np.testing.assert_allclose(np.asarray(fits[m].mixture.weights).sum(), 1.0, rtol=1e-12)
    _assert_same_fit(mx.fit_gmm(key, z, 1, room=5), mx.fit_gmm(key, z, 1))  # no seeding step at all
    # without regularisation the unused components' covariances would be singular: they must stay out of it
    _assert_same_fit(mx.fit_gmm(key, z, 3, reg_covar=0.0, room=5), mx.fit_gmm(key, z, 3, reg_covar=0.0))
    # a point far from every cluster but at the unused components' mean (the origin) stays out of them too
    far = np.concatenate([z + 60.0, np.zeros((1, 2))])
    _assert_same_fit(mx.fit_gmm(key, far, 3, room=5), mx.fit_gmm(key, far, 3))
    with pytest.raises(ValueError, match="room must be >= 3"):
        mx.fit_gmm(key, z, 3, room=2)


def test_best_init_is_the_first_of_the_highest_bounds_within_rounding():
    assert mx.best_init(np.array([-3.0, -1.0, -2.0])) == 1
    assert mx.best_init(np.array([-4.1373, -4.1373 * (1 - 1e-15), -5.0])) == 0  # an ulp better: a tie
    assert mx.best_init(np.array([-4.1373, -4.1373 * (1 - 1e-6)])) == 1  # clearly better
    assert mx.best_init(np.array([np.nan, -7.0, np.nan])) == 1
    assert mx.best_init(np.array([2e-12, 1e-12])) == 0  # near 0: an absolute 1e-9
