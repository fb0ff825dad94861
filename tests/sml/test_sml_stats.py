"""Class statistics: streaming, merging, finalising, files, against float64 NumPy."""
import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

import sml_reference as ref
from jaxanom import sml


def random_logits(rng, shape, num_classes, scale=4.0, offset=0.0):
    bias = rng.normal(size=num_classes) * 2  # classes with different max-logit levels
    return (rng.normal(size=shape + (num_classes,)) * scale + bias + offset).astype(np.float32)


def test_one_image_with_valid_mask_matches_numpy():
    rng = np.random.default_rng(0)
    logits = random_logits(rng, (13, 17), 5)
    valid = rng.random((13, 17)) > 0.3
    stats = sml.stats_update(sml.stats_init(5), logits, valid)
    count, mean, var = ref.class_stats([logits], [valid])
    np.testing.assert_array_equal(np.asarray(stats.count), count)
    np.testing.assert_allclose(np.asarray(stats.mean), mean, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(np.asarray(stats.m2) / (count - 1), var, rtol=1e-5)


def test_all_void_mask_counts_nothing():
    logits = random_logits(np.random.default_rng(1), (4, 6), 3)
    stats = sml.stats_update(sml.stats_init(3), logits, np.zeros((4, 6), bool))
    np.testing.assert_array_equal(np.asarray(stats.count), 0)
    assert np.isfinite(np.asarray(stats.mean)).all() and np.isfinite(np.asarray(stats.m2)).all()


def test_streamed_batches_match_float64_numpy():
    rng = np.random.default_rng(2)
    batches = [random_logits(rng, (3, 9, 11), 6, offset=30.0) for _ in range(25)]
    items = [b if i % 3 else (b, rng.random(b.shape[:-1]) > 0.1) for i, b in enumerate(batches)]
    stats = sml.fit_stats(iter(items))
    images = [img for b in batches for img in b]
    masks = [m for it, b in zip(items, batches) for m in (it[1] if isinstance(it, tuple) else np.ones(b.shape[:-1], bool))]
    count, mean, var = ref.class_stats(images, masks)
    got_mean, got_std = sml.stats_finalize(stats, policy="none")
    np.testing.assert_array_equal(np.asarray(stats.count), count)
    np.testing.assert_allclose(np.asarray(got_mean), mean, rtol=2e-6)
    np.testing.assert_allclose(np.asarray(got_std), np.sqrt(var), rtol=2e-5)


def test_fit_stats_accepts_single_images_and_batches_alike():
    rng = np.random.default_rng(3)
    batch = random_logits(rng, (4, 5, 6), 3)
    a = sml.fit_stats([batch])
    b = sml.fit_stats(list(batch), num_classes=3)
    chex.assert_trees_all_close(a, b, rtol=1e-6, atol=1e-6)


def test_merge_accuracy_over_a_billion_pixels_in_float32():
    # 1000 batches of 10^6 pixels (10^9 in all), given by their summaries: the float32 merge
    # must match the float64 pooled statistics. Each merge rounds the running mean once
    # (half an ulp of 50, ~2e-6), so the error is a random walk of ~sqrt(1000) such steps.
    # A float32 sum of squares (M2 = S2 - n mean^2) would lose ~eps * 2500 / 1.5 ~ 1e-4 here.
    rng = np.random.default_rng(4)
    k, n = 1000, 1e6
    means = 50.0 + rng.normal(size=(k, 2))
    variances = 1.0 + rng.random((k, 2))
    stats = sml.stats_init(2)
    merge = jax.jit(sml.stats_merge)
    for m, v in zip(means, variances):
        stats = merge(stats, sml.ClassStats(jnp.full(2, n, jnp.float32), jnp.asarray(m, jnp.float32), jnp.asarray(v * n, jnp.float32)))
    total_mean = means.mean(0)
    total_m2 = (variances * n).sum(0) + (n * (means - total_mean) ** 2).sum(0)
    np.testing.assert_allclose(np.asarray(stats.count), k * n, rtol=1e-7)
    np.testing.assert_allclose(np.asarray(stats.mean), total_mean, rtol=5e-6)
    np.testing.assert_allclose(np.asarray(stats.m2), total_m2, rtol=1e-5)


IMAGES = hnp.arrays(np.float32, (2, 6, 7, 3), elements=st.floats(-50, 50, width=32, allow_subnormal=False))


@settings(max_examples=25, deadline=None)
@given(logits=IMAGES)
def test_merged_halves_equal_the_whole(logits):
    whole = sml.stats_update_batch(sml.stats_init(3), logits)
    halves = sml.stats_merge(sml.stats_update(sml.stats_init(3), logits[0]), sml.stats_update(sml.stats_init(3), logits[1]))
    np.testing.assert_array_equal(np.asarray(whole.count), np.asarray(halves.count))
    chex.assert_trees_all_close(whole, halves, rtol=1e-5, atol=1e-3)
    count, mean, _ = ref.class_stats(list(logits))
    np.testing.assert_allclose(np.asarray(whole.mean), mean, rtol=1e-5, atol=1e-4)


def test_never_predicted_class_is_an_error_or_pooled():
    logits = np.zeros((4, 5, 3), np.float32)
    logits[..., 0] = np.arange(20).reshape(4, 5)  # class 0 everywhere, classes 1, 2 never predicted
    logits[0, 0] = [0, 1, 0]  # class 1 once: still too few for a variance
    stats = sml.stats_update(sml.stats_init(3), logits)
    with pytest.raises(ValueError, match=r"classes \[1, 2\] with counts \[1, 0\]"):
        sml.stats_finalize(stats, policy="none")
    mean, std = sml.stats_finalize(stats, missing="pooled", policy="none")
    values = np.max(logits, -1).ravel().astype(np.float64)
    np.testing.assert_allclose(np.asarray(mean)[1:], values.mean(), rtol=1e-6)
    np.testing.assert_allclose(np.asarray(std)[1:], values.std(ddof=1), rtol=1e-6)
    class0 = np.max(logits, -1)[np.argmax(logits, -1) == 0]
    np.testing.assert_allclose([mean[0], std[0]], [class0.mean(), class0.std(ddof=1)], rtol=1e-6)


def test_constant_class_has_no_spread_and_is_degenerate():
    logits = np.zeros((3, 3, 2), np.float32)
    logits[..., 0] = 2.0
    with pytest.raises(ValueError, match=r"classes \[0, 1\]"):
        sml.stats_finalize(sml.stats_update(sml.stats_init(2), logits), policy="none")


def test_save_load_round_trip(tmp_path):
    mean, std, counts = np.array([1.5, -2.0], np.float32), np.array([0.5, 3.0], np.float32), np.array([3e9, 7.0])
    path = tmp_path / "stats.npz"
    sml.save_stats(path, mean, std, counts)
    got_mean, got_std, got_counts = sml.load_stats(path)
    np.testing.assert_array_equal(np.asarray(got_mean), mean)
    np.testing.assert_array_equal(np.asarray(got_std), std)
    np.testing.assert_array_equal(got_counts, [3_000_000_000, 7])
    assert [p.name for p in tmp_path.iterdir()] == ["stats.npz"]  # no temporary left behind


def test_file_errors(tmp_path):
    with pytest.raises(ValueError, match="path must be an existing .npz"):
        sml.load_stats(tmp_path / "absent.npz")
    with pytest.raises(ValueError, match="path must be in an existing folder"):
        sml.save_stats(tmp_path / "no" / "s.npz", [1.0], [1.0], [2])
    with pytest.raises(ValueError, match=r"must all have shape \(C,\)"):
        sml.save_stats(tmp_path / "s.npz", [1.0, 2.0], [1.0], [2])
    np.savez(tmp_path / "other.npz", mean=np.zeros(2))
    with pytest.raises(ValueError, match=r"missing \['counts', 'std'\]"):
        sml.load_stats(tmp_path / "other.npz")
    (tmp_path / "corrupt.npz").write_bytes(b"not a zip file")
    with pytest.raises(ValueError, match="not a readable .npz"):
        sml.load_stats(tmp_path / "corrupt.npz")


STATS3 = sml.stats_init(3)


@pytest.mark.parametrize(
    "call,match",
    [
        (lambda: sml.stats_update(STATS3, np.zeros((4, 3))), r"logits must have rank 3 \(H, W, C\)"),
        (lambda: sml.stats_update(STATS3, np.zeros((2, 4, 4))), "logits must have C=3 classes"),
        (lambda: sml.stats_update(STATS3, np.full((2, 2, 3), np.nan)), "logits must be finite"),
        (lambda: sml.stats_update(STATS3, np.zeros((2, 2, 3)), np.ones((2, 3), bool)), r"valid must have shape \(2, 2\)"),
        (lambda: sml.stats_update(STATS3, np.zeros((2, 2, 3)), np.ones((2, 2))), "valid must be a bool mask"),
        (lambda: sml.stats_update_batch(STATS3, np.zeros((2, 2, 3))), r"logits must have rank 4"),
        (lambda: sml.fit_stats([]), "batches must yield at least one"),
        (lambda: sml.stats_init(0), "num_classes must be >= 1"),
        (lambda: sml.stats_finalize(STATS3, missing="zero"), "missing must be"),
    ],
)
def test_bad_input_raises_value_error(call, match):
    with pytest.raises(ValueError, match=match):
        call()


def test_stats_update_works_inside_jit():
    logits = random_logits(np.random.default_rng(5), (5, 6), 3)
    valid = np.random.default_rng(6).random((5, 6)) > 0.5
    jitted = jax.jit(sml.stats_update)(sml.stats_init(3), logits, valid)
    chex.assert_trees_all_close(jitted, sml.stats_update(sml.stats_init(3), logits, valid), rtol=1e-6)
