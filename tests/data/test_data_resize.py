"""PIL-convention resizing (``jaxanom.data.resize``) against PIL itself."""
import numpy as np
import pytest
from PIL import Image

from jaxanom.data.resize import resize_image_antialiased, resize_labels_nearest


@pytest.mark.parametrize("shape, size", [((72, 128, 3), (51, 102)),    # shrink by 1.4 / 1.25 (antialiased)
                                         ((37, 53, 3), (64, 96)),      # grow, odd sizes
                                         ((90, 40, 3), (30, 77)),      # shrink one axis, grow the other
                                         ((1, 7, 3), (3, 1)),          # single row / column
                                         ((720, 1280, 3), (512, 1024))])  # the ERFNet protocol's
def test_image_equals_pil_bilinear(shape, size):
    image = np.random.default_rng(sum(shape)).integers(0, 256, shape, dtype=np.uint8)
    image[0, 0] = (0, 255, 0)  # extremes survive rounding
    reference = np.asarray(Image.fromarray(image).resize(size[::-1], Image.BILINEAR)).reshape(*size, 3)
    ours = resize_image_antialiased(image, size)
    assert ours.dtype == np.uint8 and ours.shape == (*size, 3)
    np.testing.assert_array_equal(ours, reference)


def test_image_bands_are_resized_alone():
    """A fourth band does not premultiply the others (PIL's RGBA resize would); one band works."""
    image = np.random.default_rng(1).integers(0, 256, (30, 50, 4), dtype=np.uint8)
    ours = resize_image_antialiased(image, (17, 23))
    reference = np.asarray(Image.fromarray(image[..., :3]).resize((23, 17), Image.BILINEAR))
    np.testing.assert_array_equal(ours[..., :3], reference)
    np.testing.assert_array_equal(resize_image_antialiased(image[..., 3:], (17, 23))[..., 0], ours[..., 3])


def test_image_shrink_is_antialiased_not_sampled():
    """A 1-pixel stripe pattern shrunk 4x averages to grey; a non-antialiased bilinear samples it."""
    stripes = np.zeros((8, 64, 3), np.uint8)
    stripes[:, ::2] = 255
    interior = resize_image_antialiased(stripes, (8, 16))[:, 1:-1]  # the borders renormalise a cut filter
    assert np.abs(interior.astype(int) - 128).max() <= 1


def test_labels_equal_pil_nearest_on_random_size_pairs():
    rng = np.random.default_rng(0)
    for _ in range(200):
        height, width = (int(x) for x in rng.integers(1, 400, 2))
        size = tuple(int(x) for x in rng.integers(1, 400, 2))
        labels = rng.integers(0, 256, (height, width), dtype=np.uint8)
        reference = np.asarray(Image.fromarray(labels).resize(size[::-1], Image.NEAREST))
        np.testing.assert_array_equal(resize_labels_nearest(labels, size), reference)


def test_labels_keep_trailing_axes():
    labels = np.arange(6 * 4 * 2).reshape(6, 4, 2)
    out = resize_labels_nearest(labels, (3, 8))
    assert out.shape == (3, 8, 2)
    np.testing.assert_array_equal(out[..., 0], resize_labels_nearest(labels[..., 0], (3, 8)))


@pytest.mark.parametrize("size", [(0, 4), (4,), (2.0, 3), (True, 3)])
def test_bad_size_names_the_argument(size):
    with pytest.raises(ValueError, match="size: expected"):
        resize_labels_nearest(np.zeros((4, 4), np.uint8), size)


def test_bad_image_names_the_argument():
    with pytest.raises(ValueError, match="image: expected uint8"):
        resize_image_antialiased(np.zeros((4, 4, 3), np.float32), (2, 2))
