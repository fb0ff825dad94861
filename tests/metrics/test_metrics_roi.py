"""Evaluation inside a region of interest: off-ROI pixels become void, metrics ignore them."""
import numpy as np
import pytest
from sklearn.metrics import average_precision_score

from jaxanom.app.evaluate import anomaly_results
from jaxanom.metrics import restrict_to_roi


def test_off_roi_pixels_become_void():
    labels = np.array([[0, 1, 255], [1, 0, 0]], np.uint8)
    roi = np.array([[True, False, True], [False, True, False]])
    np.testing.assert_array_equal(restrict_to_roi(labels, roi), [[0, 255, 255], [255, 0, 255]])
    np.testing.assert_array_equal(restrict_to_roi(labels.astype(np.int32), roi.astype(np.uint8)),
                                  restrict_to_roi(labels, roi))
    assert restrict_to_roi(labels, roi).dtype == np.uint8
    np.testing.assert_array_equal(restrict_to_roi(labels, np.zeros_like(roi)), 255)  # all void


def test_anomaly_results_evaluate_inside_the_roi():
    rng = np.random.default_rng(0)
    logits = rng.normal(size=(2, 6, 9, 4)).astype(np.float32)
    labels = rng.choice(np.array([0, 1, 255], np.uint8), size=(2, 6, 9), p=[0.5, 0.4, 0.1])
    roi = rng.random((2, 6, 9)) < 0.6
    batches = [{"logits": logits[b:b + 1], "label": labels[b:b + 1], "roi": roi[b:b + 1]} for b in range(2)]
    metrics, _ = anomaly_results(batches, ["max_logit"])
    kept = roi & (labels != 255)
    expected = average_precision_score(labels[kept], -logits.max(-1)[kept])
    assert metrics["max_logit"]["ap"] == pytest.approx(expected, rel=1e-6)
    assert metrics["max_logit"]["num_void"] == np.sum(~kept)


@pytest.mark.parametrize("labels,roi,message", [
    (np.zeros((2, 3), np.uint8), np.ones((3, 2), bool), "roi must have the shape of labels"),
    (np.zeros((2, 3), np.float32), np.ones((2, 3), bool), "labels must hold integers"),
    (np.zeros((2, 3), np.uint8), np.full((2, 3), 2), "roi must be a bool mask"),
    (np.zeros((2, 3), np.uint8), np.full((2, 3), 0.5), "roi must be a bool mask"),
    (np.full((2, 3), 7, np.uint8), np.ones((2, 3), bool), "labels must hold 0, 1 or 255"),
    (np.zeros((2, 3), np.uint8), np.array([[0, 1, 1], [1, 0, 2]]), "roi must be a bool mask"),  # one bad value
    (np.array([[0, 1, 255], [1, 0, 7]], np.uint8), np.ones((2, 3), bool), "labels must hold 0, 1 or 255"),
])
def test_bad_input_raises(labels, roi, message):
    with pytest.raises(ValueError, match=message):
        restrict_to_roi(labels, roi)
