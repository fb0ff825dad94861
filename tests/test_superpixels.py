"""SLIC (MMF Algorithm 1) and sRGB -> Lab against a NumPy loop, scikit-image and real frames."""
import cv2
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from skimage.color import rgb2lab
from skimage.segmentation import slic as skimage_slic
from sklearn.metrics import adjusted_rand_score

from jaxanom.superpixels import grid_shape, num_superpixels, rgb_to_lab, slic, slic_batch


def reference_slic(lab, step, compactness, iterations, tol=None):
    """Algorithm 1 as written: a loop over centres in index order, strict ``D < d(i)``."""
    lab = np.asarray(lab, np.float64)
    height, width, _ = lab.shape
    padded = np.pad(lab, ((1, 1), (1, 1), (0, 0)), mode="edge")

    def gradient(y, x):  # |I(y, x+1) - I(y, x-1)|^2 + |I(y+1, x) - I(y-1, x)|^2, edge-replicated
        horizontal = padded[y + 1, x + 2] - padded[y + 1, x]
        vertical = padded[y + 2, x + 1] - padded[y, x + 1]
        return np.sum(horizontal**2) + np.sum(vertical**2)

    centres = []
    for grid_y in range(step // 2, height, step):
        for grid_x in range(step // 2, width, step):
            best = None
            for dy in (-1, 0, 1):
                for dx in (-1, 0, 1):
                    y, x = min(max(grid_y + dy, 0), height - 1), min(max(grid_x + dx, 0), width - 1)
                    if best is None or gradient(y, x) < best[0]:
                        best = (gradient(y, x), y, x)
            _, y, x = best
            centres.append([*lab[y, x], y, x])
    centres = np.array(centres)
    rows, cols = len(range(step // 2, height, step)), len(range(step // 2, width, step))
    ys, xs = np.mgrid[:height, :width]
    for iteration in range(iterations + 1):
        distance = np.full((height, width), np.inf)
        label = np.full((height, width), -1)
        for k, centre in enumerate(centres):
            top, left = int(np.round(centre[3])), int(np.round(centre[4]))
            window = (slice(max(top - step, 0), max(min(top + step, height), 0)),
                      slice(max(left - step, 0), max(min(left + step, width), 0)))
            d_lab = np.sum((lab[window] - centre[:3]) ** 2, axis=-1)
            d_xy = (ys[window] - centre[3]) ** 2 + (xs[window] - centre[4]) ** 2
            d = d_lab + (compactness / step) ** 2 * d_xy
            closer = d < distance[window]
            distance[window] = np.where(closer, d, distance[window])
            label[window] = np.where(closer, k, label[window])
        cell = np.minimum(ys // step, rows - 1) * cols + np.minimum(xs // step, cols - 1)
        label = np.where(label < 0, cell, label)
        if iteration == iterations:
            return label
        features = np.concatenate([lab, ys[..., None], xs[..., None]], -1)
        previous = centres.copy()
        for k in range(len(centres)):
            members = features[label == k]
            if len(members):
                centres[k] = members.mean(axis=0)
        if tol is not None and np.sum(np.abs(centres[:, 3:] - previous[:, 3:])) <= tol:  # residual error E
            iterations = iteration + 1  # one more assignment to the final centres, then stop


def random_lab(rng, height, width):
    """Lab of a blocky random image with noise: clusters worth finding, no exact ties."""
    blocks = rng.random((-(-height // 9), -(-width // 9), 3))
    image = np.repeat(np.repeat(blocks, 9, 0), 9, 1)[:height, :width]
    image = np.clip(image + 0.05 * rng.normal(size=image.shape), 0, 1)
    return rgb2lab(image)


@pytest.mark.parametrize("height,width,step,compactness,iterations", [
    (37, 53, 8, 10.0, 10),  # odd sizes, S divides neither
    (29, 31, 5, 3.0, 3),
    (16, 24, 8, 20.0, 1),
    (11, 7, 3, 10.0, 0),   # assignment of the perturbed grid only
    (9, 12, 9, 10.0, 2),   # a single grid row
])
def test_slic_equals_algorithm_1_loop(height, width, step, compactness, iterations):
    lab = random_lab(np.random.default_rng(height * width), height, width)
    expected = reference_slic(lab, step, compactness, iterations)
    with jax.enable_x64(True):  # float64 on both sides: the same arithmetic, exactly equal labels
        got = np.asarray(slic(jnp.asarray(lab), step, compactness, iterations))
    np.testing.assert_array_equal(got, expected)
    assert got.dtype == np.int32 and got.min() >= 0 and got.max() < num_superpixels((height, width), step)


@pytest.mark.parametrize("tol", [0.0, 20.0, 1e9])
def test_slic_stops_at_the_residual_error_like_the_loop(tol):
    lab = random_lab(np.random.default_rng(11), 27, 35)
    expected = reference_slic(lab, 6, 10.0, 10, tol)
    with jax.enable_x64(True):
        got = np.asarray(slic(jnp.asarray(lab), 6, 10.0, 10, tol=tol))
        batch = np.asarray(slic_batch(jnp.asarray(np.stack([lab, lab[::-1]])), 6, 10.0, 10, tol=tol))
    np.testing.assert_array_equal(got, expected)
    np.testing.assert_array_equal(batch[0], expected)
    np.testing.assert_array_equal(batch[1], reference_slic(lab[::-1], 6, 10.0, 10, tol))
    if tol == 1e9:  # stops after the first update
        np.testing.assert_array_equal(got, reference_slic(lab, 6, 10.0, 1))


def test_slic_float32_agrees_with_the_loop():
    lab = random_lab(np.random.default_rng(1), 33, 45)
    got = np.asarray(slic(lab.astype(np.float32), 6))
    assert np.mean(got == reference_slic(lab, 6, 10.0, 10)) > 0.99


def test_constant_image_gives_the_grid_cells_voronoi():
    lab = np.zeros((21, 26, 3), np.float32)
    lab[..., 0] = 50.0
    got = np.asarray(slic(lab, 5, iterations=4))
    np.testing.assert_array_equal(got, reference_slic(lab, 5, 10.0, 4))
    # no colour: each pixel joins the nearest centre (ties to the smaller index); G is 0
    # everywhere, so every grid centre (2 + 5a, 2 + 5b) moves to its first offset (-1, -1)
    rows, cols = grid_shape((21, 26), 5)
    centres = np.stack(np.meshgrid(1 + 5 * np.arange(rows), 1 + 5 * np.arange(cols), indexing="ij"), -1).reshape(-1, 2)
    ys, xs = np.mgrid[:21, :26]
    nearest = np.argmin((ys[..., None] - centres[:, 0]) ** 2 + (xs[..., None] - centres[:, 1]) ** 2, axis=-1)
    np.testing.assert_array_equal(np.asarray(slic(lab, 5, iterations=0)), nearest)


def test_every_pixel_labelled_and_batch_matches_single():
    rng = np.random.default_rng(3)
    lab = np.stack([random_lab(rng, 30, 41) for _ in range(3)]).astype(np.float32)
    batch = np.asarray(slic_batch(lab, 7, 5.0, 5))
    assert batch.shape == (3, 30, 41) and batch.dtype == np.int32
    assert batch.min() >= 0 and batch.max() < num_superpixels((30, 41), 7)
    for image, labels in zip(lab, batch):
        np.testing.assert_array_equal(labels, np.asarray(slic(image, 7, 5.0, 5)))


def test_slic_inside_the_callers_jit():
    lab = random_lab(np.random.default_rng(4), 20, 20).astype(np.float32)
    wrapped = jax.jit(lambda x: slic(x, 5, 10.0, 3))
    np.testing.assert_array_equal(np.asarray(wrapped(lab)), np.asarray(slic(lab, 5, 10.0, 3)))
    traced_compactness = jax.jit(lambda m: slic(lab, 5, m, 3))  # lab closed over, m traced
    np.testing.assert_array_equal(np.asarray(traced_compactness(10.0)), np.asarray(slic(lab, 5, 10.0, 3)))


def test_slic_agrees_with_scikit_image_on_a_real_frame(road_anomaly_sample):
    path = sorted((road_anomaly_sample / "frames").glob("*.jpg"))[0]
    image = cv2.cvtColor(cv2.imread(str(path)), cv2.COLOR_BGR2RGB)
    image = cv2.resize(image, (256, 128), interpolation=cv2.INTER_AREA)
    ours = np.asarray(slic(rgb_to_lab(image), 8, 10.0, 10))
    theirs = skimage_slic(image, n_segments=num_superpixels((128, 256), 8), compactness=10.0, max_num_iter=10,
                          enforce_connectivity=False, start_label=0, convert2lab=True)
    assert adjusted_rand_score(theirs.ravel(), ours.ravel()) >= 0.5


@pytest.mark.parametrize("dtype", [np.uint8, np.float32, np.float64])
def test_rgb_to_lab_matches_scikit_image(dtype):
    rng = np.random.default_rng(5)
    image = rng.random((13, 17, 3))
    image[0, :3] = [[0, 0, 0], [1, 1, 1], [0.04045, 0.0031, 0.5]]  # black, white, gamma knees
    image = (image * 255).round().astype(np.uint8) if dtype == np.uint8 else image.astype(dtype)
    np.testing.assert_allclose(np.asarray(rgb_to_lab(image)), rgb2lab(image), atol=1e-3)


@pytest.mark.parametrize("call,message", [
    (lambda: slic(np.zeros((8, 8)), 2), "lab must have rank 3"),
    (lambda: slic(np.zeros((8, 8, 4)), 2), "lab must have 3 channels"),
    (lambda: slic(np.zeros((8, 8, 3), np.int32), 2), "lab must be a float"),
    (lambda: slic(np.zeros((8, 12, 3)), 9), "step must be an integer in"),
    (lambda: slic(np.zeros((8, 12, 3)), 0), "step must be an integer in"),
    (lambda: slic(np.zeros((8, 12, 3)), 2.0), "step must be an integer in"),
    (lambda: slic(np.zeros((8, 12, 3)), 2, iterations=-1), "iterations must be"),
    (lambda: slic(np.zeros((8, 12, 3)), 2, compactness=0.0), "compactness must be"),
    (lambda: slic(np.full((8, 12, 3), np.nan), 2), "lab must be finite"),
    (lambda: slic(np.zeros((8, 12, 3)), 2, tol=-1.0), "tol must be None or"),
    (lambda: slic_batch(np.zeros((8, 12, 3)), 2), "lab must have rank 4"),
    (lambda: rgb_to_lab(np.zeros((4, 4))), "image must have 3 channels"),
    (lambda: rgb_to_lab(np.full((4, 4, 3), 1.5)), "image must hold floats in"),
    (lambda: rgb_to_lab(np.full((4, 4, 3), np.nan)), "image must hold floats in"),
    (lambda: rgb_to_lab(np.zeros((4, 4, 3), np.int64)), "image must be uint8 or float"),
])
def test_bad_input_raises_naming_the_argument(call, message):
    with pytest.raises(ValueError, match=message):
        call()


def test_nan_found_in_a_large_image():
    lab = np.zeros((128, 256, 3), np.float32)
    lab[77, 201, 1] = np.nan
    with pytest.raises(ValueError, match="lab must be finite"):
        slic(lab, 8)
