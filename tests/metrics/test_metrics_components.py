"""SMIYC component metrics on a hand-drawn scene and against a set-based reference."""
import cv2
import numpy as np
import pytest
from scipy import ndimage

from jaxanom.metrics import component_metrics
from jaxanom.metrics.components import component_summary, frame_components
from component_scenes import one_predicted_component_over_two_objects, small_object_under_a_prediction


def hand_drawn_scene():
    """30 x 40 scene, obstacle track (predicted components >= 50 px, ground truth >= 10 px).

    Ground truth: A rows 2-9 x cols 2-9 (64 px), B rows 2-9 x cols 20-27 (64 px),
    C rows 20-22 x cols 2-4 (9 px: too small, becomes void), D rows 14-19 x cols 30-37 (48 px);
    void rows 23-24 x cols 0-9.
    Predicted: P1 rows 2-9 x cols 2-23 (176 px: all of A, 80 background px, 32 px of B);
    P2 rows 15-24 x cols 0-9, cut to rows 15-22 by the void (80 px, 71 once C is void);
    P3 rows 27-29 x cols 30-39 (30 px: dropped); P4 rows 13-19 x cols 30-37 (D + 8 px).
    """
    labels = np.zeros((30, 40), np.uint8)
    scores = np.zeros((30, 40), np.float32)
    labels[2:10, 2:10] = labels[2:10, 20:28] = labels[20:23, 2:5] = labels[14:20, 30:38] = 1
    labels[23:25, 0:10] = 255
    scores[2:10, 2:24] = scores[15:25, 0:10] = scores[27:30, 30:40] = scores[13:20, 30:38] = 0.9
    return scores, labels


def test_hand_drawn_scene():
    scores, labels = hand_drawn_scene()
    result = component_metrics([scores], [labels], track="obstacle", threshold=0.5)
    # sIoU = |k ∩ K(k)| / (|k| + background pixels of K(k)):
    # A 64 / (64 + 80), B 32 / (64 + 80), D 48 / (48 + 8).
    np.testing.assert_allclose(np.sort(result["siou"]), np.sort([64 / 144, 32 / 144, 48 / 56]))
    # PPV = ground-truth pixels / pixels: P1 96 / 176, P2 0 / 71, P4 48 / 56.
    np.testing.assert_allclose(np.sort(result["ppv"]), np.sort([96 / 176, 0.0, 48 / 56]))
    # t = .25-.40: TP 2 (A .444, D .857), FN 1, FP 1 (P2) -> F1 4/6;
    # t = .45-.50: TP 1, FN 2, FP 1 -> 2/5; t = .55-.75: TP 1, FN 2, FP 2 (P1 .545 too) -> 1/3.
    expected_f1 = [4 / 6] * 4 + [2 / 5] * 2 + [1 / 3] * 5
    np.testing.assert_allclose(result["f1"], expected_f1)
    np.testing.assert_array_equal(result["tp"], [2] * 4 + [1] * 7)
    np.testing.assert_array_equal(result["fp"], [1] * 6 + [2] * 5)
    np.testing.assert_allclose(result["f1_mean"], 7 / 15)
    np.testing.assert_allclose(result["mean_siou"], (64 / 144 + 32 / 144 + 48 / 56) / 3)
    # The best pixel-F1 threshold is the 0.9 of the painted pixels: the same components.
    automatic = component_metrics([scores], [labels], track="obstacle")
    assert automatic["threshold"] == pytest.approx(0.9, rel=1e-7)
    np.testing.assert_allclose(automatic["f1"], expected_f1)
    # Anomaly track: every predicted component is under 500 px, every GT component under 100 px.
    anomaly = component_metrics([scores], [labels], track="anomaly", threshold=0.5)
    assert anomaly["siou"].size == 0 and anomaly["ppv"].size == 0 and np.isnan(anomaly["f1_mean"])


def reference_components(prediction, labels, min_predicted, min_truth):
    """sIoU / PPV straight from the SMIYC set definitions, with SciPy's 8-connected labelling."""
    eight = np.ones((3, 3), int)
    void = labels == 255
    truth_ids, num_truth = ndimage.label(labels == 1, eight)
    predicted_ids, num_predicted = ndimage.label(prediction & ~void, eight)
    region = ~void
    truths = []
    for k in range(1, num_truth + 1):
        component = truth_ids == k
        if component.sum() < min_truth:
            region &= ~component
        else:
            truths.append(component)
    predictions = [predicted_ids == p for p in range(1, num_predicted + 1)]
    predictions = [p & region for p in predictions if p.sum() >= min_predicted]
    predictions = [p for p in predictions if p.any()]
    all_truth = np.any(truths, axis=0) if truths else np.zeros_like(void)
    siou = []
    for k in truths:
        matched = np.any([p for p in predictions if (p & k).any()] or [np.zeros_like(k)], axis=0)
        adjustment = matched & all_truth & ~k
        siou.append((k & matched).sum() / ((k | matched) & ~adjustment).sum())
    ppv = [(p & all_truth).sum() / p.sum() for p in predictions]
    return np.sort(siou), np.sort(ppv)


def blobs(rng, shape, fraction):
    noise = cv2.GaussianBlur(rng.random(shape).astype(np.float32), (0, 0), 2.5)
    return noise > np.quantile(noise, 1 - fraction)


def test_against_set_definitions_on_random_blobs():
    rng = np.random.default_rng(0)
    for _ in range(4):
        labels = blobs(rng, (60, 70), 0.2).astype(np.uint8)
        labels[blobs(rng, (60, 70), 0.1)] = 255
        prediction = blobs(rng, (60, 70), 0.25) | (labels == 1) & (rng.random((60, 70)) < 0.7)
        scores = prediction.astype(np.float32)
        result = component_metrics([scores], [labels], track="obstacle", threshold=1.0)
        siou, ppv = reference_components(prediction, labels, 50, 10)
        assert siou.size and ppv.size
        np.testing.assert_allclose(np.sort(result["siou"]), siou, rtol=1e-12)
        np.testing.assert_allclose(np.sort(result["ppv"]), ppv, rtol=1e-12)


def test_best_f1_threshold_against_brute_force():
    rng = np.random.default_rng(1)
    scores = [np.round(rng.random((20, 25)), 1).astype(np.float32) for _ in range(2)]
    labels = [(rng.random((20, 25)) < 0.3).astype(np.uint8) for _ in range(2)]
    all_scores = np.concatenate([s.ravel() for s in scores])
    all_labels = np.concatenate([l.ravel() for l in labels])
    best, best_f1 = None, -1.0
    for threshold in np.unique(all_scores)[::-1]:
        predicted = all_scores >= threshold
        tp = np.sum(predicted & (all_labels == 1))
        f1 = 2 * tp / (np.sum(predicted) + np.sum(all_labels == 1))
        if f1 > best_f1:
            best, best_f1 = threshold, f1
    assert component_metrics(scores, labels, track="obstacle")["threshold"] == best


def test_bad_input_raises():
    scores, labels = hand_drawn_scene()
    with pytest.raises(ValueError, match="track"):
        component_metrics([scores], [labels], track="road")
    with pytest.raises(ValueError, match="labels_per_image"):
        component_metrics([scores, scores], [labels])
    with pytest.raises(ValueError, match=r"\(H, W\)"):
        component_metrics([scores[None]], [labels[None]])
    with pytest.raises(ValueError, match="labels: expected values"):
        component_metrics([scores], [labels + 2])
    nan = np.where(labels == 1, np.nan, scores)  # refused with a threshold given too
    with pytest.raises(ValueError, match="NaN values on non-void pixels"):
        component_metrics([nan], [labels], threshold=0.5)


def test_hand_worked_two_objects_under_one_prediction():
    scores, labels = one_predicted_component_over_two_objects()
    result = component_metrics([scores], [labels], track="obstacle", threshold=0.5)
    # sIoU(G) = |G ∩ P1| / (|G| + background pixels of P1): the other object's 25 px are not counted
    np.testing.assert_allclose(np.sort(result["siou"]), [25 / 60, 35 / 60])
    np.testing.assert_allclose(np.sort(result["ppv"]), [0.0, 60 / 85])  # P2, P1
    # TP: t <= .40 both (.417, .583), t = .45-.55 G1 only, t >= .60 none; FP: P2 always, P1 (.706) at t = .75
    np.testing.assert_array_equal(result["tp"], [2] * 4 + [1] * 3 + [0] * 4)
    np.testing.assert_array_equal(result["fn"], [0] * 4 + [1] * 3 + [2] * 4)
    np.testing.assert_array_equal(result["fp"], [1] * 10 + [2])
    expected = [4 / 5] * 4 + [2 / 4] * 3 + [0.0] * 4  # 2 TP / (2 TP + FN + FP)
    np.testing.assert_allclose(result["f1"], expected)
    np.testing.assert_allclose(result["f1_mean"], (4 * 0.8 + 3 * 0.5) / 11)
    assert (result["num_truth"], result["num_predicted"]) == (2, 2)


def test_hand_worked_small_object_rules():
    scores, labels = small_object_under_a_prediction()
    siou, ppv = frame_components(scores, labels, 0.5, track="obstacle")
    # P1 keeps its 54 >= 50 px (sizes are counted before S turns void) but has 48 px left, none on B
    np.testing.assert_allclose(siou, [25 / 60])
    np.testing.assert_allclose(np.sort(ppv), [0.0, 25 / 60])
    summary = component_summary(siou, ppv)
    np.testing.assert_array_equal(summary["fp"], [1] * 4 + [2] * 7)
    np.testing.assert_allclose(summary["f1"], [2 / 3] * 4 + [0.0] * 7)
    np.testing.assert_allclose(summary["f1_mean"], 8 / 33)
    # the anomaly track's rules (500 / 100 px) leave no component: F1 undefined
    siou, ppv = frame_components(scores, labels, 0.5, track="anomaly")
    assert siou.size == ppv.size == 0 and np.isnan(component_summary(siou, ppv)["f1_mean"])


def test_pooled_counts_are_the_sum_of_the_frames():
    frames = [one_predicted_component_over_two_objects(), small_object_under_a_prediction()]
    pooled = component_metrics([s for s, _ in frames], [l for _, l in frames], track="obstacle", threshold=0.5)
    # t = .25: TP 2 + 1, FN 0 + 0, FP 1 + 1 -> 6 / 8 (not the mean of 4/5 and 2/3)
    assert pooled["f1"][0] == pytest.approx(6 / 8)
    np.testing.assert_allclose(pooled["mean_siou"], (25 / 60 + 35 / 60 + 25 / 60) / 3)
    np.testing.assert_allclose(pooled["mean_ppv"], (0 + 60 / 85 + 0 + 25 / 60) / 4)


def test_frame_components_refuses_bad_input():
    scores, labels = small_object_under_a_prediction()
    with pytest.raises(ValueError, match="labels"):
        frame_components(scores, labels[:5], 0.5)
    with pytest.raises(ValueError, match="labels"):
        frame_components(scores, labels + 3, 0.5)
    with pytest.raises(ValueError, match="threshold"):
        frame_components(scores, labels, float("nan"))
    with pytest.raises(ValueError, match="track"):
        frame_components(scores, labels, 0.5, track="lane")
