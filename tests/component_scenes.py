"""Hand-drawn SegmentMeIfYouCan scenes whose component metrics are worked out by hand in the tests."""
import numpy as np


def one_predicted_component_over_two_objects():
    """20 x 30, obstacle track. Ground truth G1 rows 0-4 x cols 0-6 (35 px), G2 rows 0-6 x
    cols 10-14 (35 px). Predicted P1 rows 0-4 x cols 0-16 (85 px: G1 35, G2 25, background 25),
    P2 rows 10-17 x cols 0-9 (80 px of background)."""
    labels = np.zeros((20, 30), np.uint8)
    labels[0:5, 0:7] = labels[0:7, 10:15] = 1
    scores = np.zeros((20, 30), np.float32)
    scores[0:5, 0:17] = scores[10:18, 0:10] = 1.0
    return scores, labels


def small_object_under_a_prediction():
    """20 x 20, obstacle track. Ground truth S rows 0-1 x cols 0-2 (6 px < 10: becomes void),
    B rows 10-14 x cols 10-14 (25 px). Predicted P1 rows 0-5 x cols 0-8 (54 px, 6 of them on S),
    P2 rows 10-14 x cols 8-19 (60 px: B 25, background 35)."""
    labels = np.zeros((20, 20), np.uint8)
    labels[0:2, 0:3] = labels[10:15, 10:15] = 1
    scores = np.zeros((20, 20), np.float32)
    scores[0:6, 0:9] = scores[10:15, 8:20] = 1.0
    return scores, labels
