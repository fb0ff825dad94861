"""The patch encoder: shapes, unit embeddings, one compile per configuration, a falling InfoNCE loss."""
import jax
import numpy as np
import pytest

from jaxanom.offroad import encoder as enc
from jaxanom.offroad.encoder import EncoderConfig, embed, init_encoder, stack_annotations, train_encoder

CONFIG = EncoderConfig(size=8, widths=(4, 8, 8, 8, 8), hidden=8, dim=4, negatives=4, frames_per_step=2, steps=40, lr=3e-3)


def _two_texture_frames(count):
    """Frames whose left half is dark and smooth, right half bright and noisy; 3 patches per half."""
    rng = np.random.default_rng(0)
    images, annotations = [], []
    for f in range(count):
        image = np.zeros((24, 32, 3), np.uint8)
        image[:, :16] = 60 + rng.integers(0, 10, (24, 16, 3))
        image[:, 16:] = 150 + rng.integers(0, 100, (24, 16, 3))
        flip = f % 2  # ids renumbered per frame
        annotations.append({"centers": np.array([[5, 4], [12, 6], [18, 5], [5, 26], [12, 24], [18, 27]], np.int32),
                            "ids": np.array([flip] * 3 + [1 - flip] * 3, np.int32),
                            "reference": np.array([0] * 3 + [1] * 3, np.int32)})
        images.append(image)
    return stack_annotations(images, annotations, slots=8)


def test_embeddings_have_unit_norm_and_the_right_shape():
    params = init_encoder(jax.random.key(0), CONFIG)
    out = CONFIG.model().apply({"params": params}, np.random.default_rng(0).uniform(size=(5, 8, 8, 6)))
    assert out["embedding"].shape == (5, 4) and out["features"].shape == (5, 8)
    np.testing.assert_allclose(np.linalg.norm(out["embedding"], axis=-1), 1.0, rtol=1e-5)
    data = _two_texture_frames(3)
    z = embed(params, data.images, data.centers, CONFIG, chunk=2)
    assert z.shape == (3, 8, 4)


def test_training_lowers_the_loss_and_compiles_once():
    data = _two_texture_frames(4)
    params = init_encoder(jax.random.key(0), CONFIG)
    before = enc._train_step._cache_size()
    params, losses = train_encoder(jax.random.key(1), params, data, CONFIG)
    params, more = train_encoder(jax.random.key(2), params, data, CONFIG, steps=5)
    assert enc._train_step._cache_size() - before <= 1
    assert losses.shape == (40,) and np.isfinite(losses).all()
    assert losses[-10:].mean() < 0.7 * losses[:5].mean()
    z = embed(params, data.images, data.centers, CONFIG)
    left, right = z[:, :3].reshape(-1, 4), z[:, 3:6].reshape(-1, 4)
    assert (left @ left.T).mean() > (left @ right.T).mean() + 0.3


def test_empty_annotations_and_mismatched_inputs_raise():
    empty = {"centers": np.zeros((0, 2), np.int32), "ids": np.zeros(0, np.int32), "reference": np.zeros(0, np.int32)}
    with pytest.raises(ValueError, match="empty annotation set"):
        stack_annotations([np.zeros((24, 32, 3), np.uint8)], [empty], slots=4)
    with pytest.raises(ValueError, match="images, annotations"):
        stack_annotations([], [], slots=4)
    with pytest.raises(ValueError, match="images, centers"):
        embed(None, np.zeros((2, 8, 8, 3)), np.zeros((3, 1, 2)), CONFIG)


@pytest.mark.parametrize("field", ["lr", "temperature"])
def test_config_refuses_a_zero_rate_or_temperature(field):
    with pytest.raises(ValueError, match=rf"{field} must be a finite number in \(0.0, inf\], got 0.0"):
        EncoderConfig(**{field: 0.0})
    EncoderConfig(**{field: 1e-9})  # any positive value is accepted
