"""Off-road risk (Eqs. 6-15) and voting against NumPy loops."""
import math

import jax
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.stats import multivariate_normal

from jaxanom.mixture import GaussianMixture
from jaxanom.offroad import risk as rk


def random_mixture(rng, m, d):
    a = rng.normal(size=(m, d, d))
    cov = a @ np.swapaxes(a, 1, 2) / d + 0.2 * np.eye(d)
    return GaussianMixture(rng.dirichlet(np.ones(m)), rng.normal(size=(m, d)) * 3, cov)


def numpy_log_density(z, mixture):
    return np.stack([multivariate_normal(mixture.means[k], mixture.covariances[k]).logpdf(z).reshape(len(z))
                     for k in range(len(mixture.weights))], axis=1)


@pytest.mark.parametrize("m, d", [(4, 3), (1, 2), (6, 16)])
def test_classify_matches_numpy(m, d):
    rng = np.random.default_rng(m + d)
    mixture = random_mixture(rng, m, d)
    z_train = rng.normal(size=(200, d)) * 3
    z = rng.normal(size=(57, d)) * 4
    train_raw, train_r = rk.training_risks(z_train, mixture)
    ref_train_raw = -numpy_log_density(z_train, mixture).max(axis=1)
    np.testing.assert_allclose(train_raw, ref_train_raw, rtol=1e-10)
    r_sigma = rk.risk_bound(train_r, 0.9)
    got = rk.classify(z, mixture, r_sigma, train_raw)

    log_density = numpy_log_density(z, mixture)
    k_star = log_density.argmax(axis=1)
    raw = -log_density.max(axis=1)
    risk = np.array([np.mean(ref_train_raw <= v) for v in raw])
    labels = np.where(raw <= np.sort(ref_train_raw)[math.ceil(0.9 * 200) - 1], k_star, m)  # Eq. 10 on raw risks
    np.testing.assert_array_equal(got.cluster, k_star)
    np.testing.assert_array_equal(got.labels, labels)
    np.testing.assert_allclose(got.risk, risk, rtol=1e-6)
    assert got.labels.dtype == np.int32 and got.risk.dtype == np.float32

    literal = rk.classify(z, mixture, 0.99, risk="literal")
    np.testing.assert_allclose(literal.risk, 1 - np.exp(log_density.max(axis=1)), rtol=1e-6, atol=1e-7)
    np.testing.assert_array_equal(literal.labels, np.where(1 - np.exp(-raw) <= 0.99, k_star, m))

    batch = rk.classify_batch(np.stack([z, z[::-1]]), mixture, r_sigma, train_raw)
    np.testing.assert_array_equal(batch.labels[0], got.labels)
    np.testing.assert_array_equal(batch.labels[1], got.labels[::-1])


def test_training_sets_of_one_size_bucket_share_one_compile_and_keep_their_own_calibration():
    from compiles import compiled_during

    rng = np.random.default_rng(5)
    mixture = random_mixture(rng, 3, 2)
    z = rng.normal(size=(40, 2)) * 4
    z[0] = 1e200  # its density underflows: raw risk +inf, F_train = 1 (the padding sorts with it)
    with np.errstate(over="ignore"):
        raw = -numpy_log_density(z, mixture).max(axis=1)
    for n_train in (100, 105, 112):  # one bucket of shapes.padded_size
        train_raw, train_r = rk.training_risks(rng.normal(size=(n_train, 2)) * 3, mixture)
        r_sigma = rk.risk_bound(train_r, 0.9)
        got, compiled = compiled_during(lambda: rk.classify(z, mixture, r_sigma, train_raw))
        assert n_train == 100 or "jit(_classify)" not in compiled, (n_train, compiled)  # (100's may be cached)
        np.testing.assert_allclose(got.risk, [np.mean(train_raw <= v) for v in raw], rtol=1e-6)
        known = raw <= np.sort(train_raw)[math.ceil(0.9 * n_train) - 1]
        np.testing.assert_array_equal(got.labels, np.where(known, got.cluster, 3))
        assert got.risk[0] == 1 and got.labels[0] == 3


@pytest.mark.parametrize("n_train", [7, 20, 61])
def test_calibrated_labels_are_eq10_on_the_raw_order_statistic(n_train):
    # F_train is flat between order statistics, so F_train <= r_sigma called points in
    # (r_(k), r_(k+1)) known, and with delta = 1 it never gave unknown (a point 70 sigma away was known)
    rng = np.random.default_rng(n_train)
    mixture = random_mixture(rng, 3, 2)
    z_train = mixture.means[rng.integers(0, 3, n_train)] + rng.normal(size=(n_train, 2))
    z = np.concatenate([rng.normal(size=(2000, 2)) * 4, mixture.means[:1] + 70 * np.sqrt(mixture.covariances[0, 0, 0])])
    log_density = numpy_log_density(z, mixture)
    raw, k_star = -log_density.max(axis=1), log_density.argmax(axis=1)
    train_sorted = np.sort(-numpy_log_density(z_train, mixture).max(axis=1))
    for delta in (0.5, 0.8, 0.95, 1.0):
        k = math.ceil(round(delta * n_train, 9))
        bound = train_sorted[k - 1]
        between = (raw > bound) & (raw < train_sorted[min(k, n_train - 1)])
        assert k == n_train or between.any()  # points between the order statistics are exercised
        train_raw, train_r = rk.training_risks(z_train, mixture)
        got = rk.classify(z, mixture, rk.risk_bound(train_r, delta), train_raw)
        np.testing.assert_array_equal(got.labels, np.where(raw <= bound, k_star, 3))
        _, r_lit = rk.training_risks(z_train, mixture, risk="literal")
        literal = rk.classify(z, mixture, rk.risk_bound(r_lit, delta), risk="literal")
        np.testing.assert_array_equal(got.labels, literal.labels)
    assert got.labels[-1] == 3  # delta = 1: the point 70 sigma away is unknown


def test_literal_and_calibrated_labels_agree_in_2d():
    rng = np.random.default_rng(11)
    mixture = random_mixture(rng, 3, 2)
    z_train = np.concatenate([rng.multivariate_normal(mixture.means[k], mixture.covariances[k], 100) for k in range(3)])
    z = rng.normal(size=(300, 2)) * 5
    for delta in (0.8, 0.95):
        raw, r_cal = rk.training_risks(z_train, mixture)
        _, r_lit = rk.training_risks(z_train, mixture, risk="literal")
        calibrated = rk.classify(z, mixture, rk.risk_bound(r_cal, delta), raw)
        literal = rk.classify(z, mixture, rk.risk_bound(r_lit, delta), risk="literal")
        np.testing.assert_array_equal(calibrated.labels, literal.labels)
        assert 0 < np.mean(calibrated.labels == 3) < 1  # both kinds of label occur


def test_risk_bound_hand_examples():
    r = np.array([0.5, 0.1, 0.9, 0.3, 0.7, 0.2, 0.8, 0.4, 0.6, 1.0])
    assert rk.risk_bound(r, 0.8) == 0.8  # the 8th smallest of 10
    assert rk.risk_bound(r, 0.7) == 0.7  # 0.7 * 10 rounds to 7, not 8
    assert rk.risk_bound(r, 1.0) == 1.0
    assert rk.risk_bound(r, 0.01) == 0.1
    assert rk.risk_bound([3.0], 0.5) == 3.0


@settings(max_examples=60, deadline=None)
@given(st.lists(st.integers(0, 20), min_size=1, max_size=40), st.floats(0.01, 1.0))
def test_risk_bound_is_the_minimal_feasible_value(values, delta):
    r = np.asarray(values, np.float64) / 20  # ties are common
    bound = rk.risk_bound(r, delta)
    feasible = lambda b: np.sum(r > b) / r.size <= 1 - delta + 1e-9  # noqa: E731
    assert feasible(bound)
    assert not any(feasible(b) for b in r[r < bound])  # no smaller candidate satisfies Eq. 11


def test_risk_bound_histogram_option_matches_numpy_loop():
    rng = np.random.default_rng(4)
    r = rng.random(500) ** 2
    for bins, delta in [(10, 0.95), (50, 0.8), (1, 0.5)]:
        counts, edges = np.histogram(r, bins=bins)
        expected = next(edges[i + 1] for i in range(bins) if counts[i + 1:].sum() / r.size <= 1 - delta + 1e-12)
        assert rk.risk_bound(r, delta, bins=bins) == expected


def test_frame_and_sequence_risk_hand_examples():
    labels = np.array([[0, 3, 1, 3], [3, 3, 3, 2], [0, 1, 2, 0]])
    np.testing.assert_allclose(rk.frame_risk_batch(labels, 3), [0.5, 0.75, 0.0])
    np.testing.assert_allclose(rk.frame_risk(labels[1], 3), 0.75)
    flr = [0.5, 0.75, 0.0, 0.9]
    assert rk.sequence_risk(flr, 0.5) == 0.5  # 0.5 is not > 0.5
    assert rk.scene_coverage(flr, 0.5) == 0.5
    assert rk.scene_coverage(flr, 0.8) == 0.75
    assert math.isclose(rk.mean_frame_risk(flr), 0.5375)


def numpy_vote(centers, labels, risks, s, h, w, num_labels, sigma):
    votes = np.zeros((h, w, num_labels))
    total, weighted = np.zeros((h, w)), np.zeros((h, w))
    c = (s - 1) / 2
    for (cy, cx), label, r in zip(centers, labels, risks):
        top, left = cy - s // 2, cx - s // 2
        for i in range(s):
            for j in range(s):
                y, x = top + i, left + j
                if 0 <= y < h and 0 <= x < w:
                    weight = math.exp(-((i - c) ** 2 + (j - c) ** 2) / (2 * sigma**2))
                    votes[y, x, label] += weight
                    total[y, x] += weight
                    weighted[y, x] += weight * r
    label_map = np.where(total > 0, votes.argmax(axis=-1), 255)
    return label_map, votes, np.where(total > 0, weighted / np.where(total > 0, total, 1), 0)


@pytest.mark.parametrize("s, h, w, stride", [(8, 20, 27, 3), (5, 13, 9, 2), (4, 16, 16, 4)])
def test_vote_matches_numpy_loop(s, h, w, stride):
    rng = np.random.default_rng(s * h)
    centers = np.array([(y, x) for y in range(0, h + 2, stride) for x in range(-1, w, stride)])  # some hang over
    labels = rng.integers(0, 5, len(centers))
    risks = rng.random(len(centers))
    got = rk.vote(centers, labels, risks, patch_size=s, height=h, width=w, num_labels=5)
    ref_labels, ref_votes, ref_risk = numpy_vote(centers, labels, risks, s, h, w, 5, s / 4)
    np.testing.assert_allclose(got.votes, ref_votes, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(got.risk, ref_risk, rtol=1e-5, atol=1e-6)
    close = np.sort(ref_votes, axis=-1)[..., -1] - np.sort(ref_votes, axis=-1)[..., -2] < 1e-5
    np.testing.assert_array_equal(np.asarray(got.labels)[~close], ref_labels[~close])  # near-ties: float order
    batch = rk.vote_batch(centers, np.stack([labels, labels[::-1]]), np.stack([risks, risks]), patch_size=s,
                          height=h, width=w, num_labels=5)
    np.testing.assert_array_equal(batch.labels[0], got.labels)
    np.testing.assert_allclose(batch.votes[1], numpy_vote(centers, labels[::-1], risks, s, h, w, 5, s / 4)[1], rtol=1e-5, atol=1e-6)


def test_vote_single_patch_ties_and_uncovered_pixels():
    one = rk.vote(np.array([[5, 6]]), np.array([2]), patch_size=4, height=12, width=12, num_labels=3)
    expected = np.full((12, 12), 255)
    expected[3:7, 4:8] = 2  # rows c - 2 .. c + 1
    np.testing.assert_array_equal(one.labels, expected)
    tie = rk.vote(np.array([[4, 4], [4, 4]]), np.array([2, 1]), patch_size=5, height=9, width=9, num_labels=3)
    assert (np.asarray(tie.labels)[2:7, 2:7] == 1).all()  # equal votes: the lowest id
    assert (np.asarray(tie.risk) == 0).all()


def test_bad_input_raises_naming_the_argument():
    rng = np.random.default_rng(0)
    mixture = random_mixture(rng, 2, 3)
    z = rng.normal(size=(5000, 3))
    z[4500, 2] = np.nan
    with pytest.raises(ValueError, match="z must be finite"):
        rk.classify(z, mixture, 0.5, np.ones(3))
    with pytest.raises(ValueError, match="z must have D = 3"):
        rk.classify(np.zeros((4, 2)), mixture, 0.5, np.ones(3))
    with pytest.raises(ValueError, match="train_raw .* is required"):
        rk.classify(np.zeros((4, 3)), mixture, 0.5)
    with pytest.raises(ValueError, match="train_raw must hold at least one"):
        rk.classify(np.zeros((4, 3)), mixture, 0.5, np.zeros(0))
    with pytest.raises(ValueError, match="z must hold at least one"):
        rk.classify(np.zeros((0, 3)), mixture, 0.5, np.ones(3))
    with pytest.raises(ValueError, match="risk must be"):
        rk.classify(np.zeros((4, 3)), mixture, 0.5, np.ones(3), risk="density")
    with pytest.raises(ValueError, match="train_risks must be a non-empty"):
        rk.risk_bound([], 0.9)
    for delta in (1.5, 0.0, -0.1):  # (0, 1]: delta = 0 would bound nothing
        with pytest.raises(ValueError, match=r"delta must be in \(0, 1\]"):
            rk.risk_bound([0.1], delta)
    with pytest.raises(ValueError, match="labels must lie in"):
        rk.vote(np.array([[1, 1]]), np.array([3]), patch_size=2, height=4, width=4, num_labels=3)
    with pytest.raises(ValueError, match="centers must hold integer"):
        rk.vote(np.array([[1.0, 1.0]]), np.array([0]), patch_size=2, height=4, width=4, num_labels=3)
    with pytest.raises(ValueError, match="flr must be a non-empty"):
        rk.sequence_risk([])
    with pytest.raises(ValueError, match="labels must hold at least one patch"):
        rk.frame_risk_batch(np.zeros((3, 0), int), 2)


def test_classify_inside_a_callers_jit():
    rng = np.random.default_rng(2)
    mixture = random_mixture(rng, 3, 2)
    z = rng.normal(size=(20, 2)).astype(np.float32)
    raw, r = rk.training_risks(z, mixture)
    m32 = GaussianMixture(*(np.asarray(a, np.float32) for a in mixture))
    bound = rk.risk_bound(r, 0.9)
    traced = jax.jit(lambda x: rk.classify(x, m32, bound, raw.astype(np.float32)).labels)(z)
    eager = rk.classify(z, mixture, bound, raw).labels
    assert np.mean(np.asarray(traced) == np.asarray(eager)) >= 0.9  # float32 vs float64 at the boundary
