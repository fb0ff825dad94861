"""The three stages end to end on a few small synthetic frames, and the evaluation helpers."""
import dataclasses

import jax
import numpy as np
import pytest

from jaxanom.data.offroad import generate_frame
from jaxanom.data.patch_annotations import annotate
from jaxanom.mixture import GaussianMixture
from jaxanom.offroad.encoder import EncoderConfig, stack_annotations
from jaxanom.app.offroad_pipeline import (OffroadConfig, OffroadModel, active_round, learn, majority_class, segment,
                                      segmentation_scores, sequence_risk_sweep, to_classes)

H, W = 48, 64
CONFIG = OffroadConfig(encoder=EncoderConfig(size=16, widths=(4, 8, 8, 8, 8), hidden=8, dim=3, negatives=4,
                                             frames_per_step=2, steps=4),
                       neighbours=2, components=(2, 3), gmm_inits=1, stride=8, risk_stride=16, budget=2, gap=1,
                       crf_iters=1)


def _annotated(domain, indices):
    frames = [generate_frame(domain, 0, i, height=H, width=W) for i in indices]
    anns = [annotate(f["label"], np.random.default_rng(i), k=6, size=16) for i, f in zip(indices, frames)]
    return frames, stack_annotations([f["image"] for f in frames], anns, slots=6)


def test_four_frame_smoke_run_of_all_three_stages():
    _, data = _annotated("A", [0, 4])
    model = learn(jax.random.key(0), data, CONFIG)
    assert model.num_clusters in (2, 3) and set(model.bics) == {2, 3}
    assert 0 <= model.r_sigma <= 1 and model.cluster_class.shape == (model.num_clusters,)
    frames, _ = _annotated("B", [0, 1, 2, 3])
    images = np.stack([f["image"] for f in frames]).astype(np.float32) / 255
    flr = sequence_risk_sweep(model, images, CONFIG, chunk=3)
    assert flr.shape == (4,) and ((flr >= 0) & (flr <= 1)).all()
    seg = segment(model, images[:1], CONFIG, crf=True)
    assert seg["labels"].shape == (1, H, W) and seg["crf_labels"].shape == (1, H, W)
    assert seg["labels"].max() <= model.num_clusters and seg["crf_labels"].max() < model.num_clusters
    assert seg["votes"].shape == (1, H, W, model.num_clusters + 1)

    def annotate_frames(indices):
        return _annotated("B", list(indices))[1]

    result = active_round(jax.random.key(1), model, data, images, annotate_frames, CONFIG, flr=flr, force=True)
    assert result["triggered"] and len(result["chosen"]) == 2 and abs(np.diff(result["chosen"])).min() > CONFIG.gap
    assert result["model"] is not model
    calm = active_round(jax.random.key(1), model, data, images, annotate_frames,
                        dataclasses.replace(CONFIG, trigger=1.0), flr=flr)
    assert not calm["triggered"] and calm["model"] is model and calm["chosen"].size == 0
    # Unforced, the trigger fires when Phi^s (frames with FLR > epsilon) exceeds it: 3 of 4 frames > 0.5.
    risky = np.array([0.9, 0.2, 0.8, 0.7])
    fired = active_round(jax.random.key(1), model, data, images, annotate_frames, CONFIG, flr=risky)
    assert fired["triggered"] and fired["sequence_risk"] == 0.75 and fired["model"] is not model
    assert sorted(fired["chosen"].tolist()) == [0, 2]  # the DP's best pair more than gap 1 apart (0.9 + 0.8)
    quiet = active_round(jax.random.key(1), model, data, images, annotate_frames, CONFIG,
                         flr=np.array([0.9, 0.2, 0.3, 0.7]))
    assert not quiet["triggered"] and quiet["sequence_risk"] == 0.5  # Phi^s = trigger: not above it


def test_majority_class_and_class_mapping():
    clusters = np.array([0, 0, 1, 1, 1, 2])
    reference = np.array([3, 3, 1, 2, 2, 5])
    assert majority_class(clusters, reference, 4).tolist() == [3, 2, 5, -1]
    model = OffroadModel(None, GaussianMixture(np.ones(4), np.zeros((4, 2)), np.zeros((4, 2, 2))), 0.5, np.zeros(3),
                         np.array([3, 2, 5, -1]), {})
    labels = np.array([[0, 1, 2, 3, 4, 255]])  # 4 = unknown, cluster 3 has no class
    assert to_classes(labels, model, 6).tolist() == [[3, 2, 5, 6, 6, 255]]


def test_segmentation_scores_count_unknown_as_wrong_against_a_numpy_reference():
    rng = np.random.default_rng(0)
    truth = rng.integers(0, 4, (9, 11))
    truth[0, :3] = 255
    predicted = rng.integers(0, 5, (9, 11))  # 4 = unknown
    out = segmentation_scores(predicted, truth, 4)
    kept = truth != 255
    assert out["pixel_accuracy"] == pytest.approx(np.mean(predicted[kept] == truth[kept]))
    ious = []
    for c in range(4):
        inter = np.sum((predicted == c) & (truth == c) & kept)
        union = np.sum(((predicted == c) | (truth == c)) & kept)
        ious.append(inter / union)
    assert out["miou"] == pytest.approx(np.mean(ious))


def four_cluster_patches(seed, per=30, dim=4, neighbours=8, spread=0.05):
    """P^train as the pipeline lays it out: each anchor followed by ``neighbours`` near-duplicates."""
    rng = np.random.default_rng(seed)
    classes = np.repeat(np.arange(4), per)
    anchors = (rng.normal(size=(4, dim)) * 10)[classes] + rng.normal(size=(4 * per, dim))
    offsets = np.concatenate([np.zeros((1, dim)), rng.normal(size=(neighbours, dim)) * spread])
    z = (anchors[:, None] + offsets[None]).reshape(-1, dim)
    return z, np.repeat(classes, neighbours + 1), np.arange(len(z)) % (neighbours + 1) == 0


@pytest.mark.parametrize("seed", [1, 2])
def test_bic_on_anchors_recovers_four_separated_clusters(seed):
    from jaxanom.mixture import select_components
    from jaxanom.app.offroad_pipeline import category_model

    # BIC on anchors + 8 near-duplicates each chose 9 here (N counted 9 times)
    z, reference, anchor = four_cluster_patches(seed)
    config = OffroadConfig(components=(2, 3, 4, 5, 6), gmm_inits=2)
    model = category_model(jax.random.key(seed), None, z, anchor, reference, config)
    assert model.num_clusters == 4 and sorted(model.cluster_class) == [0, 1, 2, 3]
    assert len(model.train_raw) == len(z)  # r_sigma is still calibrated on all of P^train
    on_all, _, _ = select_components(jax.random.key(seed), z, (2, 3, 4, 5, 6), n_init=2)  # no extension: 9 costs 4 compiles
    assert on_all > 4  # the duplicates' effect this guards against


def test_bic_scan_extends_until_the_minimum_is_interior():
    from jaxanom.mixture import select_components

    z, _, anchor = four_cluster_patches(1)
    m, _, bics = select_components(jax.random.key(1), z[anchor], (2, 3), n_init=2, max_count=8)
    assert m == 4 and max(bics) >= 5  # the scan 2..3 fell at its top; it went on past 4
    m, _, bics = select_components(jax.random.key(1), z[anchor], (2, 3), n_init=2)
    assert m == 3 and sorted(bics) == [2, 3]  # no extension without max_count


def test_segmentation_scores_precision_recall_fpr_against_sklearn():
    from sklearn.metrics import confusion_matrix, precision_score, recall_score

    rng = np.random.default_rng(3)
    truth = rng.integers(0, 4, (13, 7))
    truth[2, :4] = 255
    truth[truth == 2] = 1  # class 2 never occurs: its recall is undefined
    predicted = rng.integers(0, 5, (13, 7))  # 4 = unknown (wrong, never a class)
    predicted[predicted == 3] = 0  # class 3 never predicted: its precision is undefined
    out = segmentation_scores(predicted, truth, 4)
    kept = truth != 255
    y, p = truth[kept], predicted[kept]
    occurs, predicted_classes = np.unique(y), np.intersect1d(np.unique(p), np.arange(4))
    assert out["recall"] == pytest.approx(recall_score(y, p, labels=occurs, average="macro", zero_division=0))
    assert out["precision"] == pytest.approx(precision_score(y, p, labels=predicted_classes, average="macro"))
    m = confusion_matrix(y, p, labels=np.arange(5))
    fpr = [(m[:, c].sum() - m[c, c]) / (m.sum() - m[c].sum()) for c in range(4)]
    assert out["fpr"] == pytest.approx(np.mean(fpr))


def test_confusion_scores_of_summed_frame_matrices_equal_the_pooled_scores():
    from jaxanom.app.offroad_pipeline import OFFROAD_SCORES
    from jaxanom.metrics import confusion_scores

    rng = np.random.default_rng(5)
    truth = rng.integers(0, 3, (4, 6, 9))
    truth[1] = 255  # an all-void frame
    truth[2, :2] = 2
    predicted = rng.integers(0, 4, (4, 6, 9))  # 3 = unknown
    per_frame = np.stack([segmentation_scores(p, t, 3)["confusion"] for p, t in zip(predicted, truth)])
    weights = np.array([[1, 0, 2, 1], [0, 1, 0, 0], [3, 3, 0, 1]])  # bootstrap multiplicities; row 2: void only
    batched = confusion_scores(np.tensordot(weights, per_frame, axes=1), 3)
    for r, w in enumerate(weights):
        index = np.repeat(np.arange(4), w)
        if w[1] == w.sum():  # only void pixels: every score undefined
            assert all(np.isnan(batched[key][r]) for key in OFFROAD_SCORES.values())
            continue
        expected = segmentation_scores(predicted[index], truth[index], 3)
        for name, key in OFFROAD_SCORES.items():
            assert batched[key][r] == pytest.approx(expected[name]), name
    with pytest.raises(ValueError, match="num_classes: expected 1 to 4"):
        confusion_scores(per_frame, 5)
