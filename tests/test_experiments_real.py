"""The bootstrap of the real-data experiments (experiments/stats.py) against scikit-learn:
binned metrics with one bin per distinct score are the exact ones, ties included, and a
replicate is the metric of the frames repeated by their multiplicities."""
import numpy as np
import pytest
from sklearn.metrics import average_precision_score, precision_recall_curve, roc_curve

from experiments.stats import binned_metrics, bootstrap, draws, frame_histograms, interval


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
