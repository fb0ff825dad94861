"""Confusion matrix and the scores derived from it, against NumPy references."""
import numpy as np
import pytest

from jaxanom.metrics import (class_accuracy, confusion_matrix, false_positive_rate, miou, per_class_iou,
                             pixel_accuracy, precision, recall)

C = 5


def random_pair(seed, shape=(3, 17, 23)):
    rng = np.random.default_rng(seed)
    label = rng.integers(0, C, shape).astype(np.uint8)
    label[rng.random(shape) < 0.2] = 255
    label[label == 3] = 0  # class 3 never occurs ...
    prediction = np.where(rng.random(shape) < 0.6, label, rng.integers(0, C, shape)).astype(np.int32)
    prediction[prediction == 255] = 1
    prediction[prediction == 4] = 2  # ... and class 4 is never predicted
    return prediction, label


def reference_matrix(prediction, label):
    kept = label != 255
    cells = label[kept].astype(np.int64) * C + prediction[kept]
    return np.bincount(cells, minlength=C * C).reshape(C, C)


def test_confusion_matrix_matches_bincount_with_ignore():
    prediction, label = random_pair(0)
    np.testing.assert_array_equal(confusion_matrix(prediction, label, C), reference_matrix(prediction, label))
    # one image at a time, summed, is the same as the stacked batch
    summed = sum(np.asarray(confusion_matrix(p, l, C)) for p, l in zip(prediction, label))
    np.testing.assert_array_equal(summed, reference_matrix(prediction, label))


def test_scores_from_the_matrix():
    prediction, label = random_pair(1)
    kept = label != 255
    p, t = prediction[kept], label[kept].astype(np.int64)
    matrix = confusion_matrix(prediction, label, C)
    iou, rec, prec, fpr = [], [], [], []
    for c in range(C):
        tp, fp, fn = np.sum((p == c) & (t == c)), np.sum((p == c) & (t != c)), np.sum((p != c) & (t == c))
        tn = np.sum((p != c) & (t != c))
        iou.append(tp / (tp + fp + fn) if tp + fp + fn else np.nan)
        rec.append(tp / (tp + fn) if tp + fn else np.nan)
        prec.append(tp / (tp + fp) if tp + fp else np.nan)
        fpr.append(fp / (fp + tn))
    np.testing.assert_allclose(per_class_iou(matrix), iou, rtol=1e-12)
    np.testing.assert_allclose(recall(matrix), rec, rtol=1e-12)
    np.testing.assert_allclose(precision(matrix), prec, rtol=1e-12)
    np.testing.assert_allclose(false_positive_rate(matrix), fpr, rtol=1e-12)
    assert np.isnan(recall(matrix)[3]) and np.isnan(precision(matrix)[4]) and not np.isnan(per_class_iou(matrix)[3])
    np.testing.assert_allclose(miou(matrix), np.nanmean(iou), rtol=1e-12)
    np.testing.assert_allclose(class_accuracy(matrix), np.nanmean(rec), rtol=1e-12)
    np.testing.assert_allclose(pixel_accuracy(matrix), np.mean(p == t), rtol=1e-12)


def test_all_ignored_gives_nan_not_a_number():
    label = np.full((4, 4), 255, np.uint8)
    matrix = confusion_matrix(np.zeros((4, 4), np.int32), label, C)
    assert np.asarray(matrix).sum() == 0
    assert np.isnan(miou(matrix)) and np.isnan(pixel_accuracy(matrix)) and np.isnan(class_accuracy(matrix))


def test_bad_input_raises():
    prediction, label = random_pair(2)
    with pytest.raises(ValueError, match="label: expected the shape"):
        confusion_matrix(prediction, label[:1], C)
    with pytest.raises(ValueError, match="prediction: expected class indices"):
        confusion_matrix(prediction + C, label, C)
    with pytest.raises(ValueError, match="label: expected class indices"):
        confusion_matrix(prediction, np.where(label == 1, 9, label).astype(np.uint8), C)
    with pytest.raises(ValueError, match="prediction: expected an integer"):
        confusion_matrix(prediction.astype(np.float32), label, C)
    with pytest.raises(ValueError, match="num_classes: expected a positive integer, got 0"):
        confusion_matrix(np.zeros((2, 2), np.int32), np.full((2, 2), 255, np.uint8), 0)


def test_arrays_sharded_over_the_four_devices():
    import jax
    from jax.sharding import NamedSharding, PartitionSpec

    prediction, label = random_pair(3, shape=(4, 9, 11))
    sharding = NamedSharding(jax.make_mesh((4,), ("data",)), PartitionSpec("data"))
    matrix = confusion_matrix(jax.device_put(prediction, sharding), jax.device_put(label, sharding), C)
    np.testing.assert_array_equal(matrix, reference_matrix(prediction, label))


def test_confusion_counts_inside_jit_skips_void_and_out_of_range_labels():
    import jax
    from sklearn.metrics import confusion_matrix as sk_confusion

    from jaxanom.metrics.segmentation import confusion_counts

    rng = np.random.default_rng(6)
    labels = rng.integers(0, 5, size=(3, 7, 9)).astype(np.int32)
    labels[rng.random(labels.shape) < 0.2] = 255
    prediction = rng.integers(0, 4, size=labels.shape).astype(np.int32)
    got = np.asarray(jax.jit(lambda p, l: confusion_counts(p, l, 4))(prediction, labels))
    keep = labels < 4
    np.testing.assert_array_equal(got, sk_confusion(labels[keep], prediction[keep], labels=[0, 1, 2, 3]))
