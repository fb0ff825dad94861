"""AnomalyMetricAccumulator: exact mode == metrics of the concatenation; binned within its bound."""
import numpy as np
import pytest

from jaxanom.metrics import AnomalyMetricAccumulator, anomaly_metrics

SHAPE = (20, 31)


def images(seed, count=4, levels=None):
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(count):
        scores = rng.random(SHAPE).astype(np.float32)
        if levels:
            scores = np.round(scores * levels) / levels
        labels = (rng.random(SHAPE) < 0.25).astype(np.uint8)
        labels[rng.random(SHAPE) < 0.1] = 255
        out.append((scores, labels))
    return out


def concatenated(batch):
    return np.concatenate([s.ravel() for s, _ in batch]), np.concatenate([l.ravel() for _, l in batch])


@pytest.mark.parametrize("levels", [None, 13])
def test_exact_accumulator_equals_metrics_of_the_concatenation(levels):
    batch = images(1, levels=levels)
    accumulator = AnomalyMetricAccumulator()
    for i, (scores, labels) in enumerate(batch):  # any integer label dtype
        accumulator.update(scores, labels.astype(np.int32) if i % 2 else labels)
    all_scores, all_labels = concatenated(batch)
    for fpr_convention in ("first", "interp", "nearest", "strict"):
        for ap_convention in ("step", "trapz", "envelope"):
            settings = dict(fpr_convention=fpr_convention, ap_convention=ap_convention, tpr=0.9)
            got, expected = accumulator.compute(**settings), anomaly_metrics(all_scores, all_labels, **settings)
            for key in ("ap", "auroc", "fpr_at_tpr"):
                np.testing.assert_allclose(got[key], expected[key], rtol=1e-12, err_msg=f"{key} {settings}")
            for key in ("threshold_at_tpr", "best_f1_threshold", "num_positives", "num_negatives",
                        "num_void", "num_thresholds"):
                assert got[key] == expected[key], key


def test_exact_mode_keeps_one_entry_per_distinct_score_per_image():
    batch = images(2, levels=5)
    accumulator = AnomalyMetricAccumulator()
    for scores, labels in batch:
        accumulator.update(scores, labels)
    for (keys, positives, negatives), (scores, labels) in zip(accumulator.images, batch):
        kept = labels != 255
        assert keys.size == np.unique(scores[kept]).size
        assert positives.sum() == np.sum(labels == 1) and negatives.sum() == np.sum(labels == 0)
        largest = np.unique(scores[kept], return_counts=True)[1].max()
        assert largest < 256 and positives.dtype == np.uint8  # ~110 pixels per score: one byte


def test_binned_within_the_stated_bound():
    batch = images(3, count=3)
    all_scores, all_labels = concatenated(batch)
    for num_bins in (8, 4096):
        accumulator = AnomalyMetricAccumulator("binned", score_range=(0.0, 1.0), num_bins=num_bins)
        for scores, labels in batch:
            accumulator.update(scores, labels)
        for fpr_convention in ("first", "interp", "strict"):
            for ap_convention in ("step", "trapz", "envelope"):
                settings = dict(fpr_convention=fpr_convention, ap_convention=ap_convention)
                got, exact = accumulator.compute(**settings), anomaly_metrics(all_scores, all_labels, **settings)
                assert abs(got["ap"] - exact["ap"]) <= got["ap_error_bound"] + 1e-12
                assert abs(got["auroc"] - exact["auroc"]) <= got["auroc_error_bound"] + 1e-12
                assert abs(got["fpr_at_tpr"] - exact["fpr_at_tpr"]) <= got["fpr_error_bound"] + 1e-12
        if num_bins == 4096:  # a fine histogram: the bounds are small, not vacuous
            assert got["ap_error_bound"] < 0.01 and got["auroc_error_bound"] < 1e-3
            assert got["fpr_error_bound"] < 0.01
        else:  # a coarse one really differs from the exact numbers
            assert got["auroc"] != exact["auroc"]


def test_binned_is_exact_for_scores_on_bin_lower_edges():
    batch = images(4, count=2, levels=16)  # scores k / 16, each in its own bin of 32
    accumulator = AnomalyMetricAccumulator("binned", score_range=(0.0, 1.0 + 1 / 16), num_bins=17)
    for scores, labels in batch:
        accumulator.update(scores, labels)
    got, exact = accumulator.compute(), anomaly_metrics(*concatenated(batch))
    for key in ("ap", "auroc", "fpr_at_tpr"):
        np.testing.assert_allclose(got[key], exact[key], rtol=1e-12)


def test_bad_use_raises():
    scores, labels = images(5, count=1)[0]
    with pytest.raises(ValueError, match="mode"):
        AnomalyMetricAccumulator("histogram")
    with pytest.raises(ValueError, match="score_range"):
        AnomalyMetricAccumulator("binned")
    binned = AnomalyMetricAccumulator("binned", score_range=(0.0, 0.5))
    with pytest.raises(ValueError, match="within score_range"):
        binned.update(scores, labels)
    binned = AnomalyMetricAccumulator("binned", score_range=(0.0, 1.0))
    binned.update(scores, labels)
    with pytest.raises(ValueError, match="nearest"):
        binned.compute(fpr_convention="nearest")
    exact = AnomalyMetricAccumulator()
    with pytest.raises(ValueError, match="no positive"):
        exact.compute()
    exact.update(scores, labels)
    with pytest.raises(ValueError, match="float32 or narrower"):
        exact.update(scores.astype(np.float64), labels)
    with pytest.raises(ValueError, match="labels: expected values"):
        exact.update(scores, np.full(SHAPE, 7, np.uint8))


def test_binned_histogram_matches_numpy_over_an_offset_range_edges_included():
    """np.histogram's bins (the last one closed) over score_range (-2, 3), both ends included."""
    low, high, num_bins = -2.0, 3.0, 10
    width = (high - low) / num_bins
    rng = np.random.default_rng(6)
    centres = low + (rng.integers(0, num_bins, SHAPE) + 0.5) * width
    scores = (centres + rng.uniform(-0.3, 0.3, SHAPE) * width).astype(np.float32)  # away from edges
    scores[0, :2] = low, high
    labels = (rng.random(SHAPE) < 0.3).astype(np.uint8)
    labels[rng.random(SHAPE) < 0.1] = 255
    labels[0, :2] = 0, 1
    accumulator = AnomalyMetricAccumulator("binned", score_range=(low, high), num_bins=num_bins)
    accumulator.update(scores, labels)
    for cls in (0, 1):
        expected, _ = np.histogram(scores[labels == cls], bins=num_bins, range=(low, high))
        np.testing.assert_array_equal(accumulator.histogram[:, cls], expected)


def test_cumulative_counts_widen_to_int64_past_int32():
    accumulator = AnomalyMetricAccumulator()
    last_int32 = int(np.iinfo(np.int32).max)
    for total, dtype in ((last_int32, np.int32), (last_int32 + 1, np.int64)):
        accumulator.counts.update(num_positives=1, num_negatives=total - 1)
        assert accumulator._count_dtype() is dtype
