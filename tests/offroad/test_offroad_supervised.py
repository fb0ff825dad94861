"""The supervised patch classifier (Table III's fully supervised baseline): targets, loss, training, segmentation."""
import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import torch

from jaxanom.app.offroad_pipeline import OffroadConfig, segment_supervised
from jaxanom.offroad.encoder import EncoderConfig, embed, init_encoder
from jaxanom.offroad.supervised import classifier_config, masked_cross_entropy, patch_targets, train_classifier

ENCODER = EncoderConfig(size=8, widths=(4, 8, 8, 8, 8), hidden=8, dim=4, frames_per_step=2, steps=60, lr=1e-2)


def test_classifier_config_gives_raw_logits_of_the_same_trunk():
    config = classifier_config(ENCODER, 3)
    assert (config.dim, config.unit, config.widths, config.size) == (3, False, ENCODER.widths, ENCODER.size)
    params = init_encoder(jax.random.key(0), config)
    x = np.random.default_rng(0).uniform(size=(5, 8, 8, 6)).astype(np.float32)
    logits = config.model().apply({"params": params}, x)["embedding"]
    unit = dataclasses.replace(config, unit=True).model().apply({"params": params}, x)["embedding"]
    assert logits.shape == (5, 3) and not np.allclose(np.linalg.norm(logits, axis=-1), 1.0)
    np.testing.assert_allclose(unit, logits / np.linalg.norm(logits, axis=-1, keepdims=True), rtol=1e-5)
    with pytest.raises(ValueError, match="classes"):
        classifier_config(ENCODER, 0)
    with pytest.raises(ValueError, match="unit"):
        EncoderConfig(unit=1)


def test_patch_targets_are_the_centre_pixels_classes():
    labels = np.random.default_rng(1).integers(0, 5, (2, 7, 9))
    centers = np.array([[[0, 0], [6, 8], [3, 4]], [[1, 2], [5, 0], [6, 8]]])
    expected = np.array([[labels[f, r, c] for r, c in centers[f]] for f in range(2)])
    np.testing.assert_array_equal(patch_targets(jnp.asarray(labels), jnp.asarray(centers)), expected)


@pytest.mark.parametrize("void_fraction", [0.0, 0.3])
def test_masked_cross_entropy_matches_torch_ignore_index(void_fraction):
    rng = np.random.default_rng(2)
    logits = rng.normal(size=(40, 5)).astype(np.float32) * np.array([1, 1, 1, 1, 1e3], np.float32)  # huge logits too
    targets = np.where(rng.uniform(size=40) < void_fraction, 255, rng.integers(0, 5, 40))
    expected = torch.nn.functional.cross_entropy(torch.tensor(logits), torch.tensor(targets), ignore_index=255)
    np.testing.assert_allclose(masked_cross_entropy(jnp.asarray(logits), jnp.asarray(targets)), expected.item(),
                               rtol=1e-5)


def test_masked_cross_entropy_of_all_void_targets_is_zero_with_a_zero_gradient():
    logits = jnp.ones((3, 2))
    targets = jnp.full(3, 255)
    assert float(masked_cross_entropy(logits, targets)) == 0.0
    assert not np.any(jax.grad(lambda x: masked_cross_entropy(x, targets))(logits))


def _halves(count):
    """Frames whose left half is dark (class 0) and right half bright (class 1); the top rows void."""
    rng = np.random.default_rng(3)
    images = np.zeros((count, 16, 24, 3), np.float32)
    images[:, :, :12] = 0.2 + 0.05 * rng.uniform(size=(count, 16, 12, 3))
    images[:, :, 12:] = 0.7 + 0.3 * rng.uniform(size=(count, 16, 12, 3))
    labels = np.zeros((count, 16, 24), np.int32)
    labels[:, :, 12:] = 1
    labels[:, :2] = 255
    return images, labels


def test_training_on_dense_labels_segments_two_textures():
    images, labels = _halves(3)
    config = classifier_config(ENCODER, 2)
    params, losses = train_classifier(jax.random.key(0), images, labels, config, steps=60, patches_per_frame=8)
    assert losses.shape == (60,) and losses[-10:].mean() < 0.5 * losses[:5].mean()
    pipe = OffroadConfig(encoder=ENCODER, stride=4, crf_iters=1, components=(2, 3))
    seg = segment_supervised(params, images[:1], pipe, 2, crf=True)
    assert seg["labels"].shape == (1, 16, 24) and seg["votes"].shape == (1, 16, 24, 2)
    assert seg["crf_labels"].shape == (1, 16, 24)
    truth = labels[:1, 2:]
    assert (seg["labels"][:, 2:] == truth).mean() > 0.9 and (seg["crf_labels"][:, 2:] == truth).mean() > 0.9
    # The voted labels are the windows' argmax classes: one window's logits, embedded directly.
    logits = embed(params, images[:1], np.array([[[8, 6]]]), config)[0, 0]
    assert logits.shape == (2,) and int(np.argmax(logits)) == 0


def test_bad_training_inputs_raise_naming_the_argument():
    images, labels = _halves(2)
    config = classifier_config(ENCODER, 2)
    with pytest.raises(ValueError, match="unit"):
        train_classifier(jax.random.key(0), images, labels, ENCODER, steps=1, patches_per_frame=2)
    with pytest.raises(ValueError, match="labels"):
        train_classifier(jax.random.key(0), images, labels[:, :5], config, steps=1, patches_per_frame=2)
    with pytest.raises(ValueError, match="labels"):
        train_classifier(jax.random.key(0), images, np.where(labels == 1, 2, labels), config, steps=1,
                         patches_per_frame=2)
    with pytest.raises(ValueError, match="images"):
        train_classifier(jax.random.key(0), images * 255, labels, config, steps=1, patches_per_frame=2)
    with pytest.raises(ValueError, match="steps"):
        train_classifier(jax.random.key(0), images, labels, config, steps=0, patches_per_frame=2)
    with pytest.raises(ValueError, match="patches_per_frame"):
        train_classifier(jax.random.key(0), images, labels, config, steps=1, patches_per_frame=0)
