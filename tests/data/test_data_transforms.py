"""Augmentations against NumPy expectations written here; ImageNet normalisation."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxanom.data.transforms import Augment, color_jitter, hflip, normalize, pad_and_crop, rescale


def _record(h=7, w=11, seed=0):
    rng = np.random.default_rng(seed)
    return {"image": rng.integers(0, 256, (h, w, 3), dtype=np.uint8),
            "label": rng.choice(np.array([0, 3, 18, 255], np.uint8), (h, w)),
            "depth": rng.uniform(1, 100, (h, w)).astype(np.float32)}


def test_hflip_mirrors_every_pixel_map():
    record = _record()
    out = hflip(record)
    for key in ("image", "label", "depth"):
        np.testing.assert_array_equal(out[key], record[key][:, ::-1])


def test_pad_and_crop_pads_label_with_255_and_image_with_0():
    record = _record(5, 6)
    out = pad_and_crop(record, (8, 9), 0, 0)
    assert out["image"].shape == (8, 9, 3) and out["label"].shape == (8, 9)
    np.testing.assert_array_equal(out["label"][:5, :6], record["label"])
    assert np.all(out["label"][5:] == 255) and np.all(out["label"][:, 6:] == 255)
    assert np.all(out["image"][5:] == 0) and np.all(out["depth"][:, 6:] == 0)


def test_pad_and_crop_takes_the_window_at_top_left():
    record = _record(9, 12)
    out = pad_and_crop(record, (4, 5), 3, 6)
    np.testing.assert_array_equal(out["image"], record["image"][3:7, 6:11])
    np.testing.assert_array_equal(out["label"], record["label"][3:7, 6:11])


def test_rescale_by_two_repeats_labels_and_by_half_subsamples_them():
    record = _record(6, 8)
    up = rescale(record, 2.0)
    np.testing.assert_array_equal(up["label"], np.repeat(np.repeat(record["label"], 2, 0), 2, 1))
    np.testing.assert_array_equal(up["depth"], np.repeat(np.repeat(record["depth"], 2, 0), 2, 1))
    assert up["image"].shape == (12, 16, 3)
    down = rescale(record, 0.5)
    np.testing.assert_array_equal(down["label"], record["label"][::2, ::2])


def test_rescale_by_odd_factors_keeps_label_values_in_their_set():
    record = _record(13, 17, seed=3)
    for scale in (0.37, 0.71, 1.3, 1.93):
        out = rescale(record, scale)
        assert out["label"].shape == (round(13 * scale), round(17 * scale))
        assert set(np.unique(out["label"]).tolist()) <= {0, 3, 18, 255}


def test_color_jitter_matches_the_formula():
    image = np.random.default_rng(1).integers(0, 256, (5, 4, 3), dtype=np.uint8)
    np.testing.assert_array_equal(color_jitter(image, 1.0, 1.0, 1.0), image)
    expected = np.clip(np.rint(image.astype(np.float64) * 1.3), 0, 255)
    assert np.abs(color_jitter(image, 1.3, 1.0, 1.0).astype(int) - expected).max() <= 1  # float32 rounding
    grey = image.astype(np.float64) @ [0.299, 0.587, 0.114]
    desaturated = np.clip(np.rint(np.repeat(grey[..., None], 3, -1)), 0, 255)
    assert np.abs(color_jitter(image, 1.0, 1.0, 0.0).astype(int) - desaturated).max() <= 1
    contrast = np.clip(np.rint((image - grey.mean()) * 0.5 + grey.mean()), 0, 255)
    assert np.abs(color_jitter(image, 1.0, 0.5, 1.0).astype(int) - contrast).max() <= 1


def test_augment_gives_crop_sized_records_reproducible_from_the_generator():
    record = _record(20, 30, seed=2)
    augment = Augment(crop_hw=(16, 24), scale_range=(0.5, 2.0))
    for seed in range(8):
        a = augment(record, np.random.default_rng(seed))
        b = augment(record, np.random.default_rng(seed))
        assert a["image"].shape == (16, 24, 3) and a["label"].shape == (16, 24) and a["depth"].shape == (16, 24)
        assert set(np.unique(a["label"]).tolist()) <= {0, 3, 18, 255}
        for key in a:
            np.testing.assert_array_equal(a[key], b[key])


def test_augment_without_randomness_is_the_identity():
    record = _record(8, 8)
    augment = Augment(crop_hw=(8, 8), scale_range=(1.0, 1.0), flip_prob=0.0, jitter=0.0)
    out = augment(record, np.random.default_rng(0))
    for key in ("image", "label", "depth"):
        np.testing.assert_array_equal(out[key], record[key])


def test_augment_rejects_bad_settings():
    with pytest.raises(ValueError, match="crop_hw"):
        Augment(crop_hw=(0, 8))


def test_normalize_matches_imagenet_statistics_in_numpy_and_under_jit():
    image = np.random.default_rng(4).integers(0, 256, (3, 5, 3), dtype=np.uint8)
    expected = (image / 255.0 - np.array([0.485, 0.456, 0.406])) / np.array([0.229, 0.224, 0.225])
    np.testing.assert_allclose(normalize(image), expected, rtol=1e-6, atol=1e-6)
    assert normalize(image).dtype == np.float32
    out = jax.jit(normalize)(jnp.asarray(image))
    assert out.dtype == jnp.float32
    np.testing.assert_allclose(np.asarray(out), expected, rtol=1e-5, atol=1e-5)
