"""The bootstrap of the real-data experiments (experiments/stats.py) against scikit-learn:
binned metrics with one bin per distinct score are the exact ones, ties included, and a
replicate is the metric of the frames repeated by their multiplicities."""
import numpy as np
import pytest
from sklearn.metrics import average_precision_score, precision_recall_curve, roc_curve

from experiments.stats import (binned_metrics, bootstrap, difference_change, draws, frame_histograms, interval,
                               network_difference)


def sklearn_metrics(scores: np.ndarray, labels: np.ndarray) -> tuple[float, float]:
    """AP and the FPR of the first ROC point with TPR >= 0.95 (the "first" convention)."""
    fpr, tpr, _ = roc_curve(labels, scores)
    return average_precision_score(labels, scores), fpr[np.argmax(tpr >= 0.95)]


@pytest.fixture(scope="module")
def frames():
    """5 frames of integer scores (many ties), labels 0 / 1 / 255; one frame without anomaly."""
    rng = np.random.default_rng(3)
    out = []
    for f, size in enumerate((50, 80, 13, 200, 31)):
        labels = (rng.random(size) < (0.0 if f == 2 else 0.3)).astype(np.uint8)
        labels[rng.random(size) < 0.1] = 255
        scores = rng.integers(0, 12, size) + 3 * (labels == 1)  # anomalies score higher on average
        out.append((scores.astype(np.float32), labels))
    return out


def test_one_bin_per_distinct_score_gives_the_exact_metrics(frames):
    scores, labels = (list(x) for x in zip(*frames))
    edges = np.arange(0, 15) + 0.5  # every integer score alone in its bin
    histograms = frame_histograms(scores, labels, edges)
    keep = np.concatenate(labels) != 255
    want = sklearn_metrics(np.concatenate(scores)[keep], np.concatenate(labels)[keep])
    got = binned_metrics(histograms.sum(0))
    np.testing.assert_allclose([got["ap"], got["fpr_at_tpr"]], want, rtol=1e-12)
    assert histograms.sum() == keep.sum()


def envelope_ap(scores: np.ndarray, labels: np.ndarray) -> float:
    """VOC all-point AP (MMF Eq. 7) from scikit-learn's PR points: precision replaced by its
    maximum at equal or higher recall, summed over the recall steps from recall 0."""
    precision, recall, _ = precision_recall_curve(labels, scores)
    precision, recall = precision[:-1][::-1], recall[:-1][::-1]  # thresholds high to low, without (1, 0)
    best = np.array([precision[k:].max() for k in range(len(precision))])
    return float(np.sum(np.diff(recall, prepend=0.0) * best))


def test_binned_envelope_ap_with_one_bin_per_score_is_eq7(frames):
    scores, labels = (list(x) for x in zip(*frames))
    histograms = frame_histograms(scores, labels, np.arange(-3, 20) + 0.5)  # empty bins at both ends too
    keep = np.concatenate(labels) != 255
    got = binned_metrics(histograms.sum(0))
    want = envelope_ap(np.concatenate(scores)[keep], np.concatenate(labels)[keep])
    assert got["ap_envelope"] == pytest.approx(want, rel=1e-12)
    hand = binned_metrics(frame_histograms([np.array([3.0, 2.0, 1.0])], [np.array([0, 1, 1], np.uint8)],
                                           np.array([1.5, 2.5]))[0])  # precision 0, 1/2, 2/3 at recall 0, 1/2, 1
    assert (hand["ap"], hand["ap_envelope"]) == pytest.approx((0.5 / 2 + (2 / 3) / 2, 2 / 3), rel=1e-12)
    multiplicities = draws(len(frames), replicates=4, seed=2)
    for r, m in enumerate(multiplicities):
        s = np.concatenate([np.repeat(scores[f][None], k, 0).ravel() for f, k in enumerate(m)])
        l = np.concatenate([np.repeat(labels[f][None], k, 0).ravel() for f, k in enumerate(m)])
        if (l == 1).any():
            assert bootstrap(histograms, m[None])["ap_envelope"][0] == pytest.approx(
                envelope_ap(s[l != 255], l[l != 255]), rel=1e-12)


def test_a_replicate_pools_frames_by_their_multiplicities(frames):
    scores, labels = (list(x) for x in zip(*frames))
    histograms = frame_histograms(scores, labels, np.arange(0, 15) + 0.5)
    multiplicities = draws(len(frames), replicates=6, seed=1)
    assert (multiplicities.sum(1) == len(frames)).all()
    got = bootstrap(histograms, multiplicities)
    for r, m in enumerate(multiplicities):
        s = np.concatenate([np.repeat(scores[f][None], k, 0).ravel() for f, k in enumerate(m)])
        l = np.concatenate([np.repeat(labels[f][None], k, 0).ravel() for f, k in enumerate(m)])
        keep = l != 255
        if (l[keep] == 1).any():
            np.testing.assert_allclose([got["ap"][r], got["fpr_at_tpr"][r]], sklearn_metrics(s[keep], l[keep]),
                                       rtol=1e-12)
        else:
            assert np.isnan(got["ap"][r])


def test_two_networks_on_the_same_frames_are_paired_by_the_same_draws(frames):
    """Each replicate of a cross-network difference is computed on the same repeated frames for both
    networks: scikit-learn's AP and FPR95 of those pixels, per replicate, give the same intervals."""
    from experiments.real_common import same_frames

    scores, labels = (list(x) for x in zip(*frames))
    rng = np.random.default_rng(7)
    maps = {"first": {"a": scores, "b": [s + rng.integers(-4, 5, s.size) for s in scores]},
            "second": {"a": [np.round(s * 0.5 + rng.integers(0, 3, s.size)) for s in scores],
                       "b": [np.where(rng.random(s.size) < 0.5, s, 14 - s) for s in scores]}}
    multiplicities = draws(len(frames), replicates=20, seed=4)
    edges = np.arange(-4, 20) + 0.5  # one bin per integer score: the binned metrics are exact
    replicates = {net: {m: bootstrap(frame_histograms(v, labels, edges), multiplicities) for m, v in methods.items()}
                  for net, methods in maps.items()}
    want = {}  # (net, method) -> (R, 2) scikit-learn AP and FPR95 of each replicate's pooled pixels
    for net, methods in maps.items():
        for m, values in methods.items():
            rows = []
            for counts in multiplicities:
                s = np.concatenate([np.tile(values[f], k) for f, k in enumerate(counts)])
                l = np.concatenate([np.tile(labels[f], k) for f, k in enumerate(counts)])
                keep = l != 255
                rows.append(sklearn_metrics(s[keep], l[keep]) if (l[keep] == 1).any() else (np.nan, np.nan))
            want[net, m] = np.array(rows)
    for k, metric in enumerate(("ap", "fpr_at_tpr")):
        gap = want["first", "a"][:, k] - want["second", "a"][:, k]
        np.testing.assert_allclose(network_difference(replicates["first"], replicates["second"], "a", metric),
                                   np.nanpercentile(gap, [2.5, 97.5]), rtol=1e-9, atol=1e-12)
        change = (want["first", "a"][:, k] - want["first", "b"][:, k]) - (want["second", "a"][:, k] - want["second", "b"][:, k])
        np.testing.assert_allclose(difference_change(replicates["first"], replicates["second"], "a", "b", metric),
                                   np.nanpercentile(change, [2.5, 97.5]), rtol=1e-9, atol=1e-12)
    same_frames(labels, [l.copy() for l in labels], "track")
    with pytest.raises(RuntimeError, match="track: the networks were scored on different frames"):
        same_frames(labels, labels[:-1], "track")
    with pytest.raises(RuntimeError, match="different frames"):
        same_frames(labels, [labels[1], labels[0], *labels[2:]], "track")


def test_interval_is_the_central_95_percent_without_nan():
    values = np.concatenate([np.arange(1001.0), [np.nan]])
    assert interval(values) == pytest.approx((25.0, 975.0))


def test_fpr_is_taken_where_tpr_first_reaches_95_percent_exactly():
    scores = np.concatenate([np.arange(20.0) + 10, np.arange(40.0) / 2 + 5])  # 20 anomalies, 40 inliers
    labels = np.concatenate([np.ones(20, np.uint8), np.zeros(40, np.uint8)])
    histograms = frame_histograms([scores], [labels], np.unique(scores)[1:])  # one bin per score
    got = binned_metrics(histograms.sum(0))
    assert got["fpr_at_tpr"] == pytest.approx(sklearn_metrics(scores, labels)[1])
    assert got["fpr_at_tpr"] == pytest.approx(np.mean(scores[20:] >= 11))  # TPR 19/20 at the score 11


def test_results_file_ends_with_the_real_data_tables_one_level_down(tmp_path):
    from experiments.__main__ import write_results

    (tmp_path / "real_b.md").write_text("# B table\n\n| x |\n|---|\n\n## B on a track\n")
    (tmp_path / "real_a.md").write_text("# A table\n")
    (tmp_path / "other.md").write_text("# not real data\n")
    text = write_results(tmp_path).read_text()
    real = text[text.index("# Real data"):]
    assert real.index("## A table") < real.index("## B table") < real.index("### B on a track")
    assert "| x |" in real and "not real data" not in text


def test_int8_spread_draws_stay_within_half_a_step_and_leave_float_tensors_alone():
    from experiments.real_erfnet_int8_spread import draw_weights

    rng = np.random.default_rng(0)
    grid = {"conv.weight": rng.normal(size=(4, 3, 3, 3)).astype(np.float32),
            "bn.running_var": rng.uniform(1, 2, size=4).astype(np.float32)}
    steps = {"conv.weight": 0.02}
    assert draw_weights(grid, steps, 0) is grid
    moved = draw_weights(grid, steps, 3)
    shift = moved["conv.weight"] - grid["conv.weight"]
    assert np.all(np.abs(shift) <= 0.01 + 1e-7) and np.std(shift) > 0.02 / np.sqrt(12) * 0.8
    assert moved["conv.weight"].dtype == np.float32
    np.testing.assert_array_equal(moved["bn.running_var"], grid["bn.running_var"])
    assert not np.array_equal(draw_weights(grid, steps, 4)["conv.weight"], moved["conv.weight"])


def test_exact_metrics_of_the_frames_against_sklearn(frames):
    from experiments.real_common import exact_metrics

    scores, labels = (list(x) for x in zip(*frames))
    keep = np.concatenate(labels) != 255
    pooled = np.concatenate(scores)[keep], np.concatenate(labels)[keep]
    got = exact_metrics(scores, labels)
    np.testing.assert_allclose([got["ap"], got["fpr_at_tpr"]], sklearn_metrics(*pooled), rtol=1e-12)
    assert got["ap_envelope"] == pytest.approx(envelope_ap(*pooled), rel=1e-12)


def test_int8_spread_counts_a_gap_only_within_the_draws_shifts():
    from experiments.real_erfnet_int8_spread import within_shift

    draws = [{"T": {"msp": {"fpr95": 70.0}}}, {"T": {"msp": {"fpr95": 75.0}}}, {"T": {"msp": {"fpr95": 69.0}}}]
    assert within_shift(draws, "T", "msp", "fpr95", 66.0)  # gap +4 within shifts [-1, +5]
    assert not within_shift(draws, "T", "msp", "fpr95", 64.0)  # gap +6 beyond the largest shift
    assert within_shift(draws, "T", "msp", "fpr95", 71.0) and not within_shift(draws, "T", "msp", "fpr95", 71.5)
    assert not within_shift(draws[:1], "T", "msp", "fpr95", 70.0)  # no perturbed draw, no spread
