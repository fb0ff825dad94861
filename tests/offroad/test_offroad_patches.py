"""Six-channel patches, neighbours, augmentation, sliding windows and InfoNCE pairs."""
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxanom.offroad.pairs import contrastive_batch, gather_pairs
from jaxanom.offroad.patches import _colour_jitter, augment, neighbour_centers, patches, sliding_centers


def _reference_patch(image, center, size, context):
    pad = context * size
    padded = np.pad(image, ((pad, pad), (pad, pad), (0, 0)), mode="reflect")
    r, c = center[0] + pad, center[1] + pad
    fg = padded[r - size // 2:r - size // 2 + size, c - size // 2:c - size // 2 + size]
    big = context * size
    crop = padded[r - big // 2:r - big // 2 + big, c - big // 2:c - big // 2 + big]
    bg = np.zeros((size, size, image.shape[2]))
    for i in range(size):
        for j in range(size):
            bg[i, j] = crop[i * context:(i + 1) * context, j * context:(j + 1) * context].mean(axis=(0, 1))
    return fg, bg


@pytest.mark.parametrize("size,context", [(8, 2), (7, 3), (6, 1)])
def test_patches_are_numpy_crops_and_pooled_context_including_corners(size, context):
    rng = np.random.default_rng(size)
    image = rng.uniform(size=(23, 31, 3)).astype(np.float32)
    centers = np.array([[0, 0], [22, 30], [0, 30], [11, 15], [5, 29]], np.int32)
    out = np.asarray(patches(image, centers, size, context))
    assert out.shape == (len(centers), size, size, 6)
    for got, center in zip(out, centers):
        fg, bg = _reference_patch(image, center, size, context)
        np.testing.assert_array_equal(got[..., :3], fg)
        np.testing.assert_allclose(got[..., 3:], bg, rtol=1e-6, atol=1e-6)


def test_patches_reject_bad_centres():
    with pytest.raises(ValueError, match="centers"):
        patches(np.zeros((8, 8, 3)), np.zeros((2, 2)), 4)
    with pytest.raises(ValueError, match="centers"):
        patches(np.zeros((8, 8, 3)), np.zeros((2, 3), np.int32), 4)
    with pytest.raises(ValueError, match="image"):
        patches(np.zeros((8, 8)), np.zeros((2, 2), np.int32), 4)


@pytest.mark.parametrize("size", [7, 8])
def test_neighbours_stay_inside_the_original_window_and_the_image(size):
    centers = jnp.array([[10, 10], [0, 0], [19, 29]])
    near = np.asarray(neighbour_centers(jax.random.key(0), centers, size, 500, 20, 30))
    offsets = near - np.asarray(centers)[:, None]
    assert near.shape == (3, 500, 2)
    assert offsets[0].min() == -(size // 2) and offsets[0].max() == (size + 1) // 2 - 1
    assert (near >= 0).all() and (near[..., 0] < 20).all() and (near[..., 1] < 30).all()


def test_augment_is_deterministic_shares_parameters_and_flips_or_not():
    rng = np.random.default_rng(0)
    half = rng.uniform(size=(6, 6, 3)).astype(np.float32)
    x = jnp.asarray(np.concatenate([half, half], -1))
    a, b = augment(jax.random.key(3), x), augment(jax.random.key(3), x)
    np.testing.assert_array_equal(a, b)
    for k in range(20):  # fg and bg equal in, equal out: the same parameters apply to both
        out = np.asarray(augment(jax.random.key(k), x))
        np.testing.assert_allclose(out[..., :3], out[..., 3:], atol=1e-6)
    grey = jnp.asarray(np.repeat(rng.uniform(size=(6, 6, 1)), 6, -1).astype(np.float32))
    seen = set()
    for k in range(30):  # strength 0 on a grey patch: only the flip can act
        out = np.asarray(augment(jax.random.key(k), grey, strength=0.0))
        flipped = np.allclose(out, np.asarray(grey)[:, ::-1], atol=1e-6)
        assert flipped or np.allclose(out, grey, atol=1e-6)
        seen.add(flipped)
    assert seen == {True, False}


def test_greyscale_gives_equal_channels_with_itu_601_weights():
    rgb = jnp.asarray(np.random.default_rng(1).uniform(size=(4, 5, 3)).astype(np.float32))
    out = np.asarray(_colour_jitter(rgb, 1.0, 1.0, 1.0, True))
    np.testing.assert_allclose(out[..., 0], np.asarray(rgb) @ np.array([0.299, 0.587, 0.114]), rtol=1e-5)
    np.testing.assert_array_equal(out[..., 0], out[..., 2])


def numpy_colour_jitter(rgb, brightness, contrast, saturation, to_grey):
    """The augment docstring's recipe: scale; blend with the mean grey; blend with each pixel's grey."""
    grey = lambda x: x @ np.array([0.299, 0.587, 0.114])  # noqa: E731
    x = np.clip(rgb * brightness, 0, 1)
    x = np.clip(contrast * x + (1 - contrast) * grey(x).mean(), 0, 1)
    x = np.clip(saturation * x + (1 - saturation) * grey(x)[..., None], 0, 1)
    return np.repeat(grey(x)[..., None], 3, -1) if to_grey else x


@pytest.mark.parametrize("factors", [(1.3, 0.7, 1.4, False), (0.6, 1.3, 0.8, True), (1.0, 1.0, 1.0, False)])
def test_colour_jitter_matches_numpy(factors):
    rgb = np.random.default_rng(2).uniform(size=(5, 6, 3)).astype(np.float32)
    got = np.asarray(_colour_jitter(jnp.asarray(rgb), *factors))
    np.testing.assert_allclose(got, numpy_colour_jitter(rgb.astype(np.float64), *factors), atol=1e-6)


@pytest.mark.parametrize("h,w,size,stride", [(128, 256, 32, 8), (37, 50, 8, 5), (8, 9, 8, 3)])
def test_sliding_windows_cover_the_image_and_touch_the_borders(h, w, size, stride):
    centers = sliding_centers(h, w, size, stride)
    covered = np.zeros((h, w), int)
    for r, c in centers:
        top, left = r - size // 2, c - size // 2
        assert top >= 0 and left >= 0 and top + size <= h and left + size <= w
        covered[top:top + size, left:left + size] += 1
    assert covered.min() >= 1
    per_dim = lambda dim: math.ceil((dim - size) / stride) + 1  # noqa: E731  (the grid, plus a flush last window)
    assert len(centers) == len({tuple(c) for c in centers}) == per_dim(h) * per_dim(w)
    with pytest.raises(ValueError, match="size"):
        sliding_centers(4, 40, 8, 2)


def _batch(ids, valid, negatives=5):
    f, a = ids.shape
    images = jnp.asarray(np.random.default_rng(0).uniform(size=(f, 20, 24, 3)).astype(np.float32))
    centers = jnp.asarray(np.random.default_rng(1).integers(0, 20, (f, a, 2)).astype(np.int32))
    return contrastive_batch(jax.random.key(0), images, centers, jnp.asarray(ids), jnp.asarray(valid), size=6,
                             negatives=negatives)


def test_positives_share_the_label_and_negatives_never_do():
    ids = np.array([[0, 1, 0, 2, 1, 2], [5, 5, 3, 3, 3, 9]], np.int32)
    valid = np.array([[1, 1, 1, 1, 1, 0], [1, 1, 1, 1, 1, 1]], bool)
    out = _batch(ids, valid)
    assert out["query"].shape == (2, 6, 6, 6, 6) and out["near"].shape == (2, 6, 6, 6, 6)
    pos, neg, mask = map(np.asarray, (out["positive_index"], out["negative_index"], out["mask"]))
    for f in range(2):
        for i in range(6):
            if not mask[f, i]:
                continue
            j = pos[f, i]
            singleton = not any(ids[f, k] == ids[f, i] and valid[f, k] and k != i for k in range(6))
            assert j == i if singleton else (j != i and ids[f, j] == ids[f, i] and valid[f, j])
            assert all(ids[f, k] != ids[f, i] and valid[f, k] for k in neg[f, i])
    assert mask.tolist() == [[True] * 5 + [False], [True] * 6]  # frame 0: anchor 3 (id 2) is a singleton among valid
    assert pos[0, 3] == 3
    z = jnp.ones((2, 6, 4))
    zq, zp, zn, m = gather_pairs(z, z, out)
    assert zq.shape == (12, 4) and zp.shape == (12, 4) and zn.shape == (12, 5, 4) and m.shape == (12,)


def test_a_frame_with_a_single_label_has_no_valid_query():
    out = _batch(np.zeros((1, 4), np.int32), np.ones((1, 4), bool))
    assert not np.asarray(out["mask"]).any()
