"""Library inputs refused at the public boundary instead of a wrong number."""
import jax
import numpy as np
import pytest

from jaxanom import sml
from jaxanom.metrics.segmentation import miou
from jaxanom.mixture import fit_gmm, log_gaussian
from jaxanom.offroad.crf import dense_crf
from jaxanom.app.offroad_pipeline import OffroadModel, majority_class, segmentation_scores, to_classes
from jaxanom.offroad.risk import frame_risk, frame_risk_batch, scene_coverage, sequence_risk
from jaxanom.superpixels import num_superpixels


def test_dense_crf_refuses_8_bit_images():
    rng = np.random.default_rng(0)
    probs = rng.random((6, 7, 3)).astype(np.float32)
    image = rng.random((6, 7, 3)).astype(np.float32)
    dense_crf(probs / probs.sum(-1, keepdims=True), image, method="exact")  # [0, 1] is fine
    with pytest.raises(ValueError, match=r"image must lie in \[0.0, 1.0\].*255"):
        dense_crf(probs, image * 255, method="exact")


@pytest.mark.parametrize("labels", [[0, 1, 5], [0, -1, 2], [3, 0, 0]])
def test_frame_risk_refuses_labels_outside_the_clusters_and_unknown(labels):
    with pytest.raises(ValueError, match=r"labels must hold values in \[0, 2\]"):
        frame_risk(np.array(labels), 2)
    with pytest.raises(ValueError, match=r"labels must hold values in \[0, 2\]"):
        frame_risk_batch(np.array([labels, [0, 1, 2]]), 2)
    assert float(frame_risk(np.array([0, 2, 2, 1]), 2)) == 0.5  # m = 2 is the unknown label


def test_frame_risk_under_jit_is_math_only():
    assert float(jax.jit(lambda x: frame_risk(x, 2))(np.array([2, 0]))) == 0.5


def test_offroad_label_mappings_refuse_labels_outside_their_range():
    model = OffroadModel(None, None, 0.0, np.zeros(1), np.array([0, 1]), {})
    model.mixture = type("M", (), {"means": np.zeros((2, 3))})()
    assert to_classes(np.array([0, 1, 2, 255]), model, 2).tolist() == [0, 1, 2, 255]
    with pytest.raises(ValueError, match=r"labels must hold values in \[0, 2\] or 255"):
        to_classes(np.array([0, 3]), model, 2)
    with pytest.raises(ValueError, match="predicted"):
        segmentation_scores(np.array([[0, 4]]), np.array([[0, 1]]), 3)
    with pytest.raises(ValueError, match="truth"):
        segmentation_scores(np.array([[0, 1]]), np.array([[0, 3]]), 3)
    with pytest.raises(ValueError, match="clusters"):
        majority_class(np.array([0, 2]), np.array([1, 1]), 2)
    with pytest.raises(ValueError, match="reference"):
        majority_class(np.array([0, 1]), np.array([1, -1]), 2)


def test_shrinkage_that_overflows_is_refused_where_it_is_made():
    stats = sml.stats_init(2)
    logits = np.random.default_rng(0).normal(size=(8, 8, 2)).astype(np.float32)
    stats = sml.stats_update(stats, logits)
    final = sml.stats_finalize_report(stats, policy="shrink", strength=10.0)
    assert np.isfinite(final.std).all()
    with pytest.raises(ValueError, match="not a finite float32.*smaller strength"):
        sml.stats_finalize_report(stats, policy="shrink", strength=1e308)


@pytest.mark.parametrize("call, message", [
    (lambda: fit_gmm(jax.random.key(0), np.random.default_rng(0).normal(size=(20, 2)), 2.5), "m must be an integer"),
    (lambda: fit_gmm(jax.random.key(0), np.random.default_rng(0).normal(size=(20, 2)), 2, max_iter=1e12),
     "max_iter must be an integer"),
    (lambda: fit_gmm(jax.random.key(0), np.random.default_rng(0).normal(size=(20, 2)), 2, max_iter=10**12),
     "max_iter must be <= 2147483647"),
    (lambda: log_gaussian(np.zeros((3, 2)), np.zeros((2, 2)), np.zeros((2, 3, 3))), "covariances must have shapes"),
    (lambda: num_superpixels((8, 8), 0), "step must be >= 1"),
    (lambda: miou(np.ones((3, 4))), r"square \(C, C\)"),
    (lambda: scene_coverage([0.1, 0.9], float("nan")), "epsilon must be a finite number"),
    (lambda: sequence_risk([0.1, 0.9], 2.0), "epsilon"),
])
def test_cryptic_errors_and_silent_numbers_become_named_errors(call, message):
    with pytest.raises(ValueError, match=message):
        call()
