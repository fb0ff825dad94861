"""The evaluator contract: one pass == parts merged; each evaluator against an independent reference."""
import dataclasses

import numpy as np
import pytest
from sklearn.metrics import average_precision_score, confusion_matrix as sk_confusion, jaccard_score, roc_auc_score

from jaxanom.metrics import component_metrics, confusion_scores, smiyc_component_metrics, smiyc_pixel_metrics
from jaxanom.metrics.evaluator import (Components, ConfusionSum, PixelAnomaly, Segmentation, SmiycPixels,
                                       run_evaluators, update_keyed)

SHAPE = (2, 23, 29)  # odd sizes
C = 9  # over 8 classes, so that a mean's summation order could matter


def anomaly_batches(seed, count=3):
    """Frames with ties (scores on 40 levels), void, a blob per frame and one frame without anomaly."""
    rng = np.random.default_rng(seed)
    batches = []
    for b in range(count):
        scores = np.round(rng.random(SHAPE) * 40).astype(np.float32) / 40
        label = (rng.random(SHAPE) < 0.05).astype(np.uint8)
        label[:, 4:15, 6:17] = 1
        scores[:, 4:15, 6:17] += 0.3
        label[rng.random(SHAPE) < 0.1] = 255
        if b == 1:
            label[0] = np.where(label[0] == 1, 0, label[0])
        batches.append({"scores": {"s": scores}, "label": label})
    return batches


def segmentation_batches(seed, count=3):
    rng = np.random.default_rng(seed)
    batches = []
    for _ in range(count):
        label = rng.integers(0, C, SHAPE).astype(np.uint8)
        label[label == 3] = 0  # class 3 never occurs
        label[rng.random(SHAPE) < 0.1] = 255
        logits = rng.normal(size=(*SHAPE, C)).astype(np.float32)
        logits[..., 5] -= 10  # class 5 never predicted
        batches.append({"logits": logits, "label": label})
    return batches


def confusion_batches(seed, count=3):
    """``segmentation_batches`` with the confusion matrix of each (scikit-learn's) as a device array."""
    import jax.numpy as jnp

    batches = segmentation_batches(seed, count)
    for batch in batches:
        keep = batch["label"] != 255
        batch["confusion"] = jnp.asarray(sk_confusion(batch["label"][keep], np.argmax(batch["logits"], -1)[keep],
                                                      labels=range(C)), jnp.int32)
    return batches


def fold(evaluator, batches):
    state = evaluator.init()
    for batch in batches:
        state = evaluator.update(state, batch)
    return state


def frames_of(batches, key="s"):
    scores = [s for b in batches for s in b["scores"][key]]
    return scores, [l for b in batches for l in b["label"]]


def frame_arrays(state: tuple) -> list:
    """The arrays of a per-frame state (``FrameBins`` or (sIoU, PPV) per frame), in order."""
    return [list(dataclasses.astuple(frame)) if dataclasses.is_dataclass(frame) else list(frame) for frame in state]


EVALUATORS = [
    (PixelAnomaly("s", conventions=True), anomaly_batches),
    (PixelAnomaly("s", mode="binned", score_range=(0.0, 1.5), ap_convention="envelope"), anomaly_batches),
    (SmiycPixels("s"), anomaly_batches),
    (Components("s", 0.55, "obstacle"), anomaly_batches),
    (Components("s", 0.55, "obstacle", convention="smiyc"), anomaly_batches),
    (Segmentation(C), segmentation_batches),
    (Segmentation(C, scored=C - 1), segmentation_batches),
    (ConfusionSum(), confusion_batches),
]


@pytest.mark.parametrize("evaluator,make", EVALUATORS, ids=lambda x: getattr(x, "__name__", type(x).__name__))
def test_parts_merged_equal_one_pass(evaluator, make):
    batches = make(0)
    one_pass = evaluator.finalize(fold(evaluator, batches))
    first, second = fold(evaluator, batches[:1]), fold(evaluator, batches[1:])
    merged = evaluator.merge(first, second)
    np.testing.assert_equal(evaluator.finalize(merged), one_pass)  # bitwise, NaN == NaN
    if isinstance(merged, tuple):  # per-frame states: the first part's frames first, as one pass orders them
        np.testing.assert_equal(frame_arrays(merged), frame_arrays(fold(evaluator, batches)))
    # merging left both parts as they were
    np.testing.assert_equal(evaluator.finalize(first), evaluator.finalize(fold(evaluator, batches[:1])))
    assert run_evaluators({"x": evaluator}, iter(batches))["x"].keys() == one_pass.keys()


def test_pixel_anomaly_against_sklearn():
    batches = anomaly_batches(1)
    scores, labels = (np.concatenate([x.ravel() for x in xs]) for xs in frames_of(batches))
    keep = labels != 255
    got = run_evaluators({"p": PixelAnomaly("s")}, batches)["p"]
    np.testing.assert_allclose(got["ap"], average_precision_score(labels[keep], scores[keep]), rtol=1e-12)
    np.testing.assert_allclose(got["auroc"], roc_auc_score(labels[keep], scores[keep]), rtol=1e-12)


def test_smiyc_and_component_evaluators_equal_the_dataset_functions():
    scores, labels = frames_of(anomaly_batches(2))
    batches = anomaly_batches(2)
    pixels = run_evaluators({"p": SmiycPixels("s")}, batches)["p"]
    assert pixels == smiyc_pixel_metrics(scores, labels)
    for convention, reference in (("exact", component_metrics), ("smiyc", smiyc_component_metrics)):
        expected = reference(scores, labels, track="obstacle", threshold=0.55)
        got = run_evaluators({"c": Components("s", 0.55, "obstacle", convention)}, batches)["c"]
        np.testing.assert_equal(got, {k: v for k, v in expected.items() if k not in ("threshold", "track")})
        assert got["num_truth"] > 0 and got["num_predicted"] > 0


def test_segmentation_against_sklearn_with_an_always_wrong_output():
    batches = segmentation_batches(3)
    for batch in batches:  # the last output (a void channel, say) is never a label
        batch["label"][batch["label"] == C - 1] = 1
    label = np.concatenate([b["label"].ravel() for b in batches])
    prediction = np.concatenate([b["logits"].argmax(-1).ravel() for b in batches])
    keep = label != 255
    y, p = label[keep], prediction[keep]
    got = run_evaluators({"s": Segmentation(C, scored=C - 1)}, batches)["s"]
    np.testing.assert_array_equal(fold(Segmentation(C), batches), sk_confusion(y, p, labels=np.arange(C)))
    classes = np.arange(C - 1)  # the last output scored as always wrong
    present = np.union1d(np.unique(y), np.intersect1d(np.unique(p), classes))
    reference = jaccard_score(y, p, labels=present, average=None)
    np.testing.assert_allclose(got["iou"][present], reference, rtol=1e-12)
    assert np.isnan(got["iou"][[c for c in classes if c not in present]]).all()
    np.testing.assert_allclose(got["miou"], reference.mean(), rtol=1e-12)
    np.testing.assert_allclose(got["pixel_accuracy"], np.mean(y == p), rtol=1e-12)


def test_frame_states_sum_to_the_batch_update():
    evaluator = Segmentation(C)
    batch = segmentation_batches(4, count=1)[0]
    frames = evaluator.frame_states(batch)
    assert frames.shape == (SHAPE[0], C, C) and frames.dtype == np.int64
    np.testing.assert_array_equal(frames.sum(0), evaluator.update(evaluator.init(), batch))
    for frame, logits, label in zip(frames, batch["logits"], batch["label"]):
        keep = label != 255
        np.testing.assert_array_equal(frame, sk_confusion(label[keep], logits.argmax(-1)[keep], labels=np.arange(C)))


def test_batched_confusion_scores_equal_one_matrix_at_a_time_bitwise():
    rng = np.random.default_rng(5)
    matrices = rng.integers(0, 50, (30, C, C))
    matrices[:, 2, :] = 0  # class 2 never occurs ...
    matrices[::3, :, 2] = 0  # ... and, in a third of them, is never predicted: NaN IoU inside the mean
    matrices[4] = 0  # nothing counted: every score NaN
    batched = confusion_scores(matrices, C - 1)
    for i, matrix in enumerate(matrices):
        single = confusion_scores(matrix, C - 1)
        for key, value in single.items():
            np.testing.assert_equal(batched[key][i], value, err_msg=key)
        # the mean sums exactly the defined IoUs in class order (what the earlier one-matrix mIoU summed)
        m = matrix.astype(np.float64)
        with np.errstate(invalid="ignore"):
            iou = (np.diag(m) / (m.sum(0) + m.sum(1) - np.diag(m)))[:C - 1]
        if not np.isnan(iou).all():
            assert batched["miou"][i] == iou[~np.isnan(iou)].mean()
    assert np.isnan(batched["miou"][4]) and np.isnan(batched["pixel_accuracy"][4])


def test_update_keyed_makes_one_evaluator_per_key():
    evaluated, made = {}, []
    for batch in anomaly_batches(6):
        for name in ("s", "t"):
            update_keyed(evaluated, name, lambda: made.append(name) or PixelAnomaly("s"), batch)
    assert made == ["s", "t"] and list(evaluated) == ["s", "t"]
    assert evaluated["s"][0].finalize(evaluated["s"][1]) == run_evaluators({"p": PixelAnomaly("s")},
                                                                            anomaly_batches(6))["p"]


def test_bad_input_names_the_argument():
    with pytest.raises(ValueError, match="convention: expected 'exact' or 'smiyc', got 'kit'"):
        Components("s", 0.5, convention="kit")
    exact, binned = PixelAnomaly("s"), PixelAnomaly("s", mode="binned", score_range=(0, 1))
    with pytest.raises(ValueError, match="other: expected an accumulator of mode 'exact'"):
        exact.merge(exact.init(), binned.init())
    with pytest.raises(ValueError, match=r"matrix: expected square \(..., K, K\)"):
        confusion_scores(np.zeros((3, 4)))
    with pytest.raises(ValueError, match="num_classes: expected 1 to 4"):
        confusion_scores(np.zeros((4, 4)), 5)


def test_confusion_sum_of_device_matrices_equals_segmentation_of_the_logits():
    batches = confusion_batches(3)
    got = run_evaluators({"sum": ConfusionSum(scored=C - 1), "logits": Segmentation(C, scored=C - 1)}, batches)
    np.testing.assert_equal(got["sum"], got["logits"])
    with pytest.raises(ValueError, match="batches: expected at least one batch"):
        run_evaluators({"sum": ConfusionSum()}, [])
