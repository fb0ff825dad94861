"""Statistics policies for scarce classes (min_count pooling, shrinkage) against float64 NumPy."""
import numpy as np
import pytest

from jaxanom import sml


def max_logits_per_class(logits, num_classes):
    """Raw max-logit values of the pixels predicted as each class (float64)."""
    flat = logits.reshape(-1, num_classes).astype(np.float64)
    prediction, value = flat.argmax(-1), flat.max(-1)
    return [value[prediction == c] for c in range(num_classes)]


def scarce_logits(rng, counts, num_classes, size=(40, 50)):
    """Logits whose class c wins on about ``counts[c]`` pixels (rest class 0), levels differ per class."""
    logits = rng.normal(size=size + (num_classes,)).astype(np.float32)
    cls = np.zeros(size[0] * size[1], int)
    index = rng.permutation(cls.size)
    start = 0
    for c, n in enumerate(counts):
        cls[index[start:start + n]] = c
        start += n
    flat = logits.reshape(-1, num_classes)
    flat[np.arange(cls.size), cls] = 6 + 2 * cls + rng.normal(size=cls.size) * (1 + 0.3 * cls)
    return logits


def shrink_reference(values, k):
    """Shrinkage as k pseudo-pixels of the pooled distribution appended to the class's pixels.

    The pseudo-pixels are m0 +- s0 (k even): their mean is m0 and their sum of squared
    deviations k s0^2; the result's variance divides the merged sum of squared deviations by
    (n - 1) + k degrees of freedom (k when n = 0).
    """
    pooled = np.concatenate(values)
    m0, s0 = pooled.mean(), pooled.std(ddof=1)
    means, stds = [], []
    for v in values:
        pseudo = m0 + s0 * np.tile([1.0, -1.0], k // 2)
        merged = np.concatenate([v, pseudo])
        mean = merged.mean()
        means.append(mean)
        stds.append(np.sqrt(np.sum((merged - mean) ** 2) / (max(len(v) - 1, 0) + k)))
    return np.array(means), np.array(stds)


@pytest.mark.parametrize("k", [2, 50, 1000])
def test_shrinkage_matches_pseudo_pixel_reference(k):
    rng = np.random.default_rng(0)
    counts = [0, 1, 3, 40, 300]  # the rest of the 2000 pixels go to class 0
    logits = scarce_logits(rng, counts, 6)
    stats = sml.stats_update(sml.stats_init(6), logits)
    got = sml.stats_finalize_report(stats, policy="shrink", strength=k)
    values = max_logits_per_class(logits, 6)
    mean, std = shrink_reference(values, k)
    np.testing.assert_allclose(np.asarray(got.mean), mean, rtol=2e-5, atol=1e-5)
    np.testing.assert_allclose(np.asarray(got.std), std, rtol=2e-5)
    np.testing.assert_array_equal(got.count, [len(v) for v in values])
    assert got.status == ("shrunk",) * 6
    np.testing.assert_allclose(got.prior_weight, k / (np.array([len(v) for v in values]) + k))


def test_shrinkage_limits_pooled_at_zero_pixels_own_estimate_at_many():
    rng = np.random.default_rng(1)
    logits = scarce_logits(rng, [0, 0, 5], 4, size=(300, 300))  # class 2 on 5 pixels
    logits[..., 3] = -100.0  # class 3 never predicted
    stats = sml.stats_update(sml.stats_init(4), logits)
    values = max_logits_per_class(logits, 4)
    pooled = np.concatenate(values)
    got = sml.stats_finalize_report(stats, policy="shrink", strength=10)
    assert len(values[3]) == 0
    np.testing.assert_allclose([got.mean[3], got.std[3]], [pooled.mean(), pooled.std(ddof=1)], rtol=1e-5)
    big = values[0]
    assert len(big) > 80_000
    np.testing.assert_allclose([got.mean[0], got.std[0]], [big.mean(), big.std(ddof=1)], rtol=1e-3)


@pytest.mark.parametrize("min_count", [120, 0])
def test_min_count_pools_exactly_the_classes_below_it(min_count):
    """Below min_count, or below 2 pixels (no variance) whatever it is: 0 pools only the empty class."""
    rng = np.random.default_rng(2)
    logits = scarce_logits(rng, [0, 7, 30, 120, 400], 5)
    stats = sml.stats_update(sml.stats_init(5), logits)
    values = max_logits_per_class(logits, 5)
    pooled = np.concatenate(values)
    got = sml.stats_finalize_report(stats, policy="min_count", min_count=min_count)
    scarce = np.array([len(v) < max(min_count, 2) for v in values])
    assert got.status == tuple("pooled" if s else "fitted" for s in scarce)
    for c, v in enumerate(values):
        want = (pooled.mean(), pooled.std(ddof=1)) if scarce[c] else (v.mean(), v.std(ddof=1))
        np.testing.assert_allclose([got.mean[c], got.std[c]], want, rtol=1e-5)
    np.testing.assert_array_equal(got.prior_weight, scarce.astype(float))


def test_all_classes_scarce_pool_to_one_distribution():
    rng = np.random.default_rng(3)
    logits = scarce_logits(rng, [0, 10, 10], 3, size=(6, 7))
    stats = sml.stats_update(sml.stats_init(3), logits)
    pooled = np.concatenate(max_logits_per_class(logits, 3))
    got = sml.stats_finalize_report(stats, policy="min_count", min_count=1e6)
    assert got.status == ("pooled",) * 3
    np.testing.assert_allclose(np.asarray(got.mean), pooled.mean(), rtol=1e-5)
    np.testing.assert_allclose(np.asarray(got.std), pooled.std(ddof=1), rtol=1e-5)


@pytest.mark.parametrize("policy", ["none", "min_count", "shrink"])
def test_single_class(policy):
    logits = np.random.default_rng(4).normal(size=(5, 7, 1)).astype(np.float32)
    stats = sml.stats_update(sml.stats_init(1), logits)
    got = sml.stats_finalize_report(stats, policy=policy, min_count=100)
    v = logits.ravel().astype(np.float64)
    # one class is its own pool: every policy gives the class's own estimate
    np.testing.assert_allclose([got.mean[0], got.std[0]], [v.mean(), v.std(ddof=1)], rtol=1e-5)
    assert got.status == ({"none": "fitted", "min_count": "pooled", "shrink": "shrunk"}[policy],)


def test_policy_none_is_the_original_and_stats_finalize_returns_mean_std():
    rng = np.random.default_rng(5)
    logits = scarce_logits(rng, [0, 3, 50], 3)
    stats = sml.stats_update(sml.stats_init(3), logits)
    got = sml.stats_finalize_report(stats, policy="none")
    values = max_logits_per_class(logits, 3)
    np.testing.assert_allclose(np.asarray(got.std), [v.std(ddof=1) for v in values], rtol=1e-5)
    assert got.status == ("fitted",) * 3 and not got.prior_weight.any()
    mean, std = sml.stats_finalize(stats, policy="shrink", strength=20)
    report = sml.stats_finalize_report(stats, policy="shrink", strength=20)
    np.testing.assert_array_equal(np.asarray(mean), np.asarray(report.mean))
    np.testing.assert_array_equal(np.asarray(std), np.asarray(report.std))


def test_the_default_is_shrinkage_with_a_million_pixel_prior():
    """Chosen on real frames (experiments/real_sml.md); the reference is the shrinkage formula in NumPy."""
    rng = np.random.default_rng(9)
    logits = scarce_logits(rng, [0, 3, 50], 3)
    stats = sml.stats_update(sml.stats_init(3), logits)
    got = sml.stats_finalize_report(stats)
    values = max_logits_per_class(logits, 3)
    pooled = np.concatenate(values).astype(np.float64)
    m0, v0, k = pooled.mean(), pooled.var(ddof=1), 1e6
    for c, v in enumerate(values):
        n, m = len(v), (v.mean() if len(v) else 0.0)
        m2 = ((v - m) ** 2).sum() if len(v) else 0.0
        want_mean = (n * m + k * m0) / (n + k)
        want_var = (m2 + k * v0 + n * k / (n + k) * (m - m0) ** 2) / (max(n - 1, 0) + k)
        np.testing.assert_allclose([got.mean[c], got.std[c]], [want_mean, np.sqrt(want_var)], rtol=1e-5)
    assert got.status == ("shrunk",) * 3


def test_degenerate_class_under_none_is_reported_pooled():
    logits = np.zeros((4, 5, 3), np.float32)
    logits[..., 0] = np.arange(20).reshape(4, 5)
    stats = sml.stats_update(sml.stats_init(3), logits)
    got = sml.stats_finalize_report(stats, missing="pooled", policy="none")
    assert got.status == ("fitted", "pooled", "pooled")
    np.testing.assert_array_equal(got.count, [20, 0, 0])


def test_nothing_to_pool_is_an_error():
    logits = np.zeros((2, 2, 2), np.float32)
    logits[..., 0] = 1.0  # one constant class: no spread anywhere
    stats = sml.stats_update(sml.stats_init(2), logits)
    for policy in ("min_count", "shrink"):
        with pytest.raises(ValueError, match="cannot pool or shrink"):
            sml.stats_finalize_report(stats, policy=policy)


@pytest.mark.parametrize("kwargs,match", [
    (dict(policy="js"), "policy must be one of"),
    (dict(policy="shrink", strength=0), "strength must be"),
    (dict(policy="shrink", strength=np.inf), "strength must be"),
    (dict(policy="min_count", min_count=-1), "min_count must be"),
])
def test_bad_policy_arguments(kwargs, match):
    with pytest.raises(ValueError, match=match):
        sml.stats_finalize(sml.stats_init(2), **kwargs)


def test_status_policy_channels_and_frames_round_trip_through_the_file(tmp_path):
    path = tmp_path / "stats.npz"
    frames = {"set": "cityscapes train", "folder": "/data/cityscapes", "count": 2, "size": [32, 64]}
    sml.save_stats(path, [1.0, 2.0], [0.5, 0.7], [10, 3], status=("fitted", "pooled"),
                   policy={"policy": "min_count", "min_count": 5}, channels={"network_outputs": 3, "void_dropped": True},
                   frames=frames)
    assert sml.load_stats_info(path) == {"status": ["fitted", "pooled"],
                                         "policy": {"policy": "min_count", "min_count": 5},
                                         "channels": {"network_outputs": 3, "void_dropped": True}, "frames": frames}
    sml.save_stats(path, [1.0], [0.5], [10])
    assert sml.load_stats_info(path) == {"status": None, "policy": None, "channels": None, "frames": None}
    assert len(sml.load_stats(path)) == 3
