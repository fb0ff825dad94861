"""Pixel AP / AUROC / FPR@TPR against scikit-learn and hand-worked examples."""
import ml_dtypes
import numpy as np
import pytest
from sklearn import metrics as sk

from jaxanom.metrics import anomaly_metrics, pr_curve, roc_curve, threshold_at_tpr


def random_case(rng, size, levels, void_fraction=0.1, positive_fraction=0.3):
    """Quantised scores (many ties), labels with void; at least one pixel of each class."""
    scores = rng.integers(-levels, levels + 1, size) / 7.0
    labels = (rng.random(size) < positive_fraction).astype(np.uint8)
    labels[rng.random(size) < void_fraction] = 255
    labels[:2] = (0, 1)
    return scores, labels


# Few distinct sizes: each new shape compiles once.
CASES = [(2, 1), (17, 2), (1000, 5), (1000, 100000), (4099, 40)]


@pytest.mark.parametrize("size,levels", CASES)
def test_ap_and_auroc_match_sklearn(size, levels):
    rng = np.random.default_rng(size)
    scores, labels = random_case(rng, size, levels)
    kept = labels != 255
    result = anomaly_metrics(scores, labels)
    np.testing.assert_allclose(result["ap"], sk.average_precision_score(labels[kept], scores[kept]), rtol=1e-9)
    np.testing.assert_allclose(result["auroc"], sk.roc_auc_score(labels[kept], scores[kept]), rtol=1e-9)
    assert result["num_positives"] == np.sum(labels == 1)
    assert result["num_negatives"] == np.sum(labels == 0)
    assert result["num_void"] == np.sum(labels == 255)
    assert result["num_thresholds"] == np.unique(scores[kept]).size


@pytest.mark.parametrize("size,levels", CASES)
def test_curves_match_sklearn(size, levels):
    rng = np.random.default_rng(size + 1)
    scores, labels = random_case(rng, size, levels)
    kept = labels != 255
    fpr, tpr, thresholds = roc_curve(scores, labels)
    ref_fpr, ref_tpr, ref_thresholds = sk.roc_curve(labels[kept], scores[kept], drop_intermediate=False)
    np.testing.assert_allclose(fpr, ref_fpr, rtol=1e-12)
    np.testing.assert_allclose(tpr, ref_tpr, rtol=1e-12)
    np.testing.assert_array_equal(thresholds, ref_thresholds)
    precision, recall, pr_thresholds = pr_curve(scores, labels)
    ref_precision, ref_recall, ref_pr_thresholds = sk.precision_recall_curve(
        labels[kept], scores[kept], drop_intermediate=False)
    # scikit-learn: increasing thresholds plus a final (recall 0, precision 1) point.
    np.testing.assert_allclose(precision, ref_precision[:-1][::-1], rtol=1e-12)
    np.testing.assert_allclose(recall, ref_recall[:-1][::-1], rtol=1e-12)
    np.testing.assert_array_equal(pr_thresholds, ref_pr_thresholds[::-1])


@pytest.mark.parametrize("size,levels", CASES[2:])
def test_trapz_ap_is_numpy_trapezoid_over_the_pr_points(size, levels):
    rng = np.random.default_rng(size + 2)
    scores, labels = random_case(rng, size, levels)
    kept = labels != 255
    ref_precision, ref_recall, _ = sk.precision_recall_curve(labels[kept], scores[kept], drop_intermediate=False)
    expected = np.trapezoid(ref_precision[:-1][::-1], ref_recall[:-1][::-1])
    np.testing.assert_allclose(anomaly_metrics(scores, labels, ap_convention="trapz")["ap"], expected, rtol=1e-9)


def reference_fpr_first(labels, scores, tpr):
    fpr, tpr_curve, _ = sk.roc_curve(labels, scores, drop_intermediate=False)
    return fpr[np.searchsorted(tpr_curve, tpr)]


@pytest.mark.parametrize("size,levels", CASES)
def test_fpr_first_matches_searchsorted_on_sklearn_roc(size, levels):
    rng = np.random.default_rng(size + 3)
    scores, labels = random_case(rng, size, levels)
    kept = labels != 255
    for tpr in (0.95, 0.5, 1.0):
        expected = reference_fpr_first(labels[kept], scores[kept], tpr)
        assert anomaly_metrics(scores, labels, tpr=tpr)["fpr_at_tpr"] == pytest.approx(expected, rel=1e-12)


@pytest.mark.parametrize("size,levels", CASES[2:])
def test_fpr_interp_and_nearest_match_their_reference_recipes(size, levels):
    rng = np.random.default_rng(size + 4)
    scores, labels = random_case(rng, size, levels)
    y, s = labels[labels != 255], scores[labels != 255]
    tpr = 0.9137  # no ROC point sits exactly on it
    # ood-metrics (SML, Mask2Anomaly): np.interp over scikit-learn's (dropped-intermediate) ROC.
    fpr_curve, tpr_curve, _ = sk.roc_curve(y, s)
    expected = np.interp(tpr, tpr_curve, fpr_curve)
    got = anomaly_metrics(scores, labels, fpr_convention="interp", tpr=tpr)["fpr_at_tpr"]
    np.testing.assert_allclose(got, expected, rtol=1e-12)
    # PEBAL: nearest TPR among the origin and the points up to full recall, ties to the last.
    fpr_curve, tpr_curve, _ = sk.roc_curve(y, s, drop_intermediate=False)
    candidates = tpr_curve[: np.argmax(tpr_curve == 1.0) + 1]
    distance = np.abs(candidates - tpr)
    expected = fpr_curve[np.flatnonzero(distance == distance.min()).max()]
    got = anomaly_metrics(scores, labels, fpr_convention="nearest", tpr=tpr)["fpr_at_tpr"]
    assert got == pytest.approx(expected, rel=1e-12)


# Hand-worked example. Scores high -> low with classes (p positive, n negative):
# 0.9p 0.8n 0.7p 0.6p+0.6n (tie) 0.5n 0.4p 0.3n 0.2p 0.1n 0.05n; P = 5, N = 6.
# ROC points (TPR, FPR): origin (0,0); 0.9 (.2,0); 0.8 (.2,1/6); 0.7 (.4,1/6); 0.6 (.6,2/6);
# 0.5 (.6,3/6); 0.4 (.8,3/6); 0.3 (.8,4/6); 0.2 (1,4/6); 0.1 (1,5/6); 0.05 (1,1).
HAND_SCORES = np.array([0.9, 0.8, 0.7, 0.6, 0.6, 0.5, 0.4, 0.3, 0.2, 0.1, 0.05])
HAND_LABELS = np.array([1, 0, 1, 1, 0, 0, 1, 0, 1, 0, 0], np.uint8)
HAND_FPR = [
    # tpr, first, interp, nearest, strict
    # 0.5: first/strict at the 0.6 point; interp between (.4,1/6) and (.6,2/6) -> 1/4; nearest:
    #      TPR .4 and .6 are equally far, the largest FPR among them is the 0.5 point's 3/6.
    (0.5, 1 / 3, 1 / 4, 1 / 2, 1 / 3),
    # 0.6: exact hit at the 0.6 point; strict goes on to the 0.4 point (TPR .8, FPR 3/6);
    #      nearest: the 0.6 and 0.5 points both have TPR .6, the largest FPR wins.
    (0.6, 1 / 3, 1 / 3, 1 / 2, 1 / 2),
    # 0.55: interp 1/6 + (.15/.2)(1/6) = 7/24; nearest: TPR .6 (distance .05), largest FPR 3/6.
    (0.55, 1 / 3, 7 / 24, 1 / 2, 1 / 3),
    # 0.05: the origin (distance .05) is nearer than TPR .2 (distance .15).
    (0.05, 0.0, 0.0, 0.0, 0.0),
    # 1.0: first reaches TPR 1 at 0.2 (FPR 4/6); nearest only looks up to that point;
    #      strict has no point with TPR > 1.
    (1.0, 2 / 3, 2 / 3, 2 / 3, np.nan),
]


@pytest.mark.parametrize("tpr,first,interp,nearest,strict", HAND_FPR)
def test_fpr_conventions_on_a_hand_worked_example(tpr, first, interp, nearest, strict):
    for convention, expected in (("first", first), ("interp", interp), ("nearest", nearest), ("strict", strict)):
        got = anomaly_metrics(HAND_SCORES, HAND_LABELS, fpr_convention=convention, tpr=tpr)["fpr_at_tpr"]
        np.testing.assert_allclose(got, expected, rtol=1e-12, err_msg=convention)


def test_ap_auroc_on_the_hand_worked_example():
    # Step AP: recall steps of .2 at the positives' thresholds, precision 1, 2/3, 3/5, 4/7, 5/9.
    step = 0.2 * (1 + 2 / 3 + 3 / 5 + 4 / 7 + 5 / 9)
    # Trapezoid over the PR points (R, P): (.2,1) (.2,1/2) (.4,2/3) (.6,3/5) (.6,1/2) (.8,4/7)
    # (.8,1/2) (1,5/9) (1,1/2) (1,5/11): only the four rises in recall count.
    trapz = 0.2 * ((1 / 2 + 2 / 3) + (2 / 3 + 3 / 5) + (1 / 2 + 4 / 7) + (1 / 2 + 5 / 9)) / 2
    # AUROC = P(positive > negative) + P(tie) / 2: (6 + 5 + 4.5 + 3 + 2) / 30.
    auroc = 20.5 / 30
    result = anomaly_metrics(HAND_SCORES, HAND_LABELS)
    np.testing.assert_allclose(result["ap"], step, rtol=1e-12)
    np.testing.assert_allclose(result["auroc"], auroc, rtol=1e-12)
    np.testing.assert_allclose(anomaly_metrics(HAND_SCORES, HAND_LABELS, ap_convention="trapz")["ap"], trapz, rtol=1e-12)
    assert threshold_at_tpr(HAND_SCORES, HAND_LABELS, tpr=0.5) == 0.6
    assert threshold_at_tpr(HAND_SCORES, HAND_LABELS, tpr=0.95) == 0.2
    # Best pixel F1 = 2 TP / (TP + FP + P): 0.7 -> 4/8, 0.6 -> 6/10, 0.4 -> 8/12, 0.2 -> 10/14 (best).
    assert result["best_f1_threshold"] == 0.2
    np.testing.assert_allclose(result["best_f1"], 10 / 14, rtol=1e-12)


def test_input_dtypes_and_leading_shapes():
    rng = np.random.default_rng(7)
    scores, labels = random_case(rng, 1000, 30)
    kept = labels != 255
    expected = sk.average_precision_score(labels[kept], scores[kept].astype(np.float16))
    for dtype in (np.float16, ml_dtypes.bfloat16):
        quantised = scores.astype(dtype)
        ref = sk.average_precision_score(labels[kept], quantised[kept].astype(np.float64))
        np.testing.assert_allclose(anomaly_metrics(quantised, labels)["ap"], ref, rtol=1e-9)
    got = anomaly_metrics(scores.astype(np.float16).reshape(4, 10, 25), labels.reshape(4, 10, 25))["ap"]
    np.testing.assert_allclose(got, expected, rtol=1e-9)


def test_a_new_host_frame_size_compiles_the_audit_and_the_flattening_only():
    import jax

    from compiles import compiled_during
    from jaxanom.metrics.anomaly import check_scores_labels

    rng = np.random.default_rng(8)
    scores, labels = random_case(rng, 1003, 30)  # a size no other test uses
    scores, labels = scores.astype(np.float32).reshape(17, 59), labels.reshape(17, 59)
    with jax.enable_x64(True):
        (flat_scores, flat_labels, counts), names = compiled_during(lambda: check_scores_labels(scores, labels))
    assert sorted(names) == ["jit(_audit)", "jit(_flat_padded)"]  # no eager copy or pad per shape
    assert flat_scores.shape == flat_labels.shape == (1024,) and flat_scores.dtype == np.float32
    np.testing.assert_array_equal(flat_scores[:1003], scores.ravel())
    np.testing.assert_array_equal(flat_labels, np.concatenate([labels.ravel(), np.full(21, 255, np.uint8)]))
    assert counts == {"num_positives": int((labels == 1).sum()), "num_negatives": int((labels == 0).sum()),
                      "num_void": int((labels == 255).sum())}


def test_float64_scores_keep_distinctions_float32_would_lose():
    scores = np.array([1.0, 1.0 + 1e-12, 0.5])
    labels = np.array([0, 1, 0], np.uint8)
    assert anomaly_metrics(scores, labels)["auroc"] == 1.0
    assert anomaly_metrics(scores.astype(np.float32), labels)["auroc"] == 0.75


def test_signed_zeros_tie_and_infinities_order():
    result = anomaly_metrics(np.array([-0.0, 0.0]), np.array([1, 0], np.uint8))
    assert result["auroc"] == 0.5 and result["num_thresholds"] == 1
    result = anomaly_metrics(np.array([np.inf, 1.0, -np.inf, 3e38]), np.array([1, 0, 1, 0], np.uint8))
    assert result["auroc"] == 0.5  # inf beats both negatives, -inf loses to both


def test_all_one_class_and_void_raise():
    scores = np.linspace(0, 1, 6)
    with pytest.raises(ValueError, match="no positive"):
        anomaly_metrics(scores, np.array([0, 0, 0, 255, 0, 0], np.uint8))
    with pytest.raises(ValueError, match="no negative"):
        anomaly_metrics(scores, np.array([1, 1, 255, 255, 1, 1], np.uint8))
    with pytest.raises(ValueError, match="no positive"):
        anomaly_metrics(scores, np.full(6, 255, np.uint8))


def test_bad_input_raises():
    scores = np.array([0.1, 0.2, 0.3])
    labels = np.array([0, 1, 0], np.uint8)
    with pytest.raises(ValueError, match="labels: expected values in"):
        anomaly_metrics(scores, np.array([0, 1, 2], np.uint8))
    with pytest.raises(ValueError, match="labels: expected the shape"):
        anomaly_metrics(scores, labels[:2])
    with pytest.raises(ValueError, match="scores: 1 NaN"):
        anomaly_metrics(np.array([0.1, np.nan, 0.3]), labels)
    with pytest.raises(ValueError, match="scores: expected a floating"):
        anomaly_metrics(np.array([1, 2, 3]), labels)
    with pytest.raises(ValueError, match="fpr_convention"):
        anomaly_metrics(scores, labels, fpr_convention="last")
    with pytest.raises(ValueError, match="ap_convention"):
        anomaly_metrics(scores, labels, ap_convention="11point")
    with pytest.raises(ValueError, match="tpr"):
        anomaly_metrics(scores, labels, tpr=0.0)
    # NaN on a void pixel is ignored.
    result = anomaly_metrics(np.array([0.1, 0.2, np.nan]), np.array([0, 1, 255], np.uint8))
    assert result["auroc"] == 1.0


def test_arrays_sharded_over_the_four_devices():
    import jax
    from jax.sharding import NamedSharding, PartitionSpec

    rng = np.random.default_rng(9)
    scores, labels = random_case(rng, 1000, 5)
    sharding = NamedSharding(jax.make_mesh((4,), ("data",)), PartitionSpec("data"))
    kept = labels != 255
    result = anomaly_metrics(jax.device_put(scores.astype(np.float32), sharding), jax.device_put(labels, sharding))
    np.testing.assert_allclose(result["auroc"], sk.roc_auc_score(labels[kept], scores[kept].astype(np.float32)),
                               rtol=1e-9)


def voc_all_point_ap(scores, labels):
    """VOC all-point interpolated AP (MMF Eq. 7) from the PR points, one per distinct score."""
    kept = labels != 255
    scores, labels = scores[kept], labels[kept]
    thresholds = np.unique(scores)[::-1]
    tp = np.array([np.sum((scores >= t) & (labels == 1)) for t in thresholds], float)
    fp = np.array([np.sum((scores >= t) & (labels == 0)) for t in thresholds], float)
    recall = np.concatenate([[0.0], tp / labels.sum(), [1.0]])
    precision = np.concatenate([[0.0], tp / (tp + fp), [0.0]])
    for i in range(len(precision) - 2, -1, -1):  # the upper envelope, from the right
        precision[i] = max(precision[i], precision[i + 1])
    steps = np.flatnonzero(recall[1:] != recall[:-1])
    return float(np.sum((recall[steps + 1] - recall[steps]) * precision[steps + 1]))


def test_envelope_ap_hand_example():
    # ranked labels 1, 0, 1, 1 (P = 3): (recall, precision) = (1/3, 1), (1/3, 1/2), (2/3, 2/3),
    # (1, 3/4). Step AP = 1/3 * 1 + 1/3 * 2/3 + 1/3 * 3/4 = 29/36; the envelope lifts the
    # precision at recall 2/3 to max(2/3, 3/4) = 3/4: 1/3 * 1 + 1/3 * 3/4 + 1/3 * 3/4 = 5/6.
    scores, labels = np.array([0.9, 0.8, 0.7, 0.6]), np.array([1, 0, 1, 1], np.uint8)
    assert anomaly_metrics(scores, labels, ap_convention="envelope")["ap"] == pytest.approx(5 / 6, abs=1e-12)
    assert anomaly_metrics(scores, labels)["ap"] == pytest.approx(29 / 36, abs=1e-12)


@pytest.mark.parametrize("size,levels", CASES)
def test_envelope_ap_matches_voc_reference_on_tied_data(size, levels):
    rng = np.random.default_rng(size + 7)
    scores, labels = random_case(rng, size, levels)
    got = anomaly_metrics(scores, labels, ap_convention="envelope")
    np.testing.assert_allclose(got["ap"], voc_all_point_ap(scores, labels), rtol=1e-12)
    assert got["ap"] >= anomaly_metrics(scores, labels)["ap"] - 1e-15  # the envelope only raises precision


def test_envelope_equals_step_when_precision_never_rises():
    # all positives above all negatives, then ties: precision is non-increasing along the curve
    scores = np.array([5.0, 4.0, 4.0, 3.0, 2.0, 2.0, 1.0])
    labels = np.array([1, 1, 1, 1, 0, 1, 0], np.uint8)
    step = anomaly_metrics(scores, labels)["ap"]
    assert anomaly_metrics(scores, labels, ap_convention="envelope")["ap"] == pytest.approx(step, abs=1e-15)


def test_conventions_flag_adds_every_convention_and_is_off_by_default():
    rng = np.random.default_rng(5)
    scores, labels = random_case(rng, 1000, 5)
    kept = labels != 255
    plain = anomaly_metrics(scores, labels)
    assert "ap_conventions" not in plain and "fpr_conventions" not in plain
    full = anomaly_metrics(scores, labels, conventions=True)
    assert set(full["ap_conventions"]) == {"step", "trapz", "envelope"}
    assert set(full["fpr_conventions"]) == {"first", "interp", "nearest", "strict"}
    np.testing.assert_allclose(full["ap_conventions"]["step"],
                               sk.average_precision_score(labels[kept], scores[kept]), rtol=1e-9)
    np.testing.assert_allclose(full["fpr_conventions"]["first"],
                               reference_fpr_first(labels[kept], scores[kept], 0.95), rtol=1e-12)
    for name in ("trapz", "envelope"):
        assert full["ap_conventions"][name] == anomaly_metrics(scores, labels, ap_convention=name)["ap"]


def test_index_and_count_dtypes_widen_to_int64_past_int32():
    """Shapes only (``eval_shape``): 2**31 entries would need gigabytes."""
    import jax
    import jax.numpy as jnp

    from jaxanom.metrics.anomaly import _pixel_weights
    from jaxanom.metrics.curve import entry_index

    last_int32 = int(np.iinfo(np.int32).max)
    with jax.enable_x64(True):
        for size, dtype in ((last_int32, jnp.int32), (last_int32 + 1, jnp.int64)):
            assert jax.eval_shape(lambda: entry_index(size)).dtype == dtype
            codes = jax.ShapeDtypeStruct((size,), jnp.uint8)
            weights = jax.eval_shape(lambda c: _pixel_weights(c, c.shape[0]), codes)
            assert [w.dtype for w in weights] == [dtype, dtype]
