"""SLIC (MMF Algorithm 1) and sRGB -> Lab against a NumPy loop, scikit-image and real frames."""
import cv2
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import ndimage
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
    # the caller's own vmap (the batch twin loops over images on CPU; accelerators vmap)
    np.testing.assert_array_equal(np.asarray(jax.vmap(lambda x: slic(x, 7, 5.0, 5))(lab)), batch)


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


def stray_fraction(labels):
    """Share of pixels outside their superpixel's largest 4-connected piece, and the number of split superpixels."""
    stray = split = 0
    for j in np.unique(labels):
        pieces, count = ndimage.label(labels == j)  # 4-connectivity (SciPy's default structure)
        if count > 1:
            sizes = np.bincount(pieces.ravel())[1:]
            stray, split = stray + sizes.sum() - sizes.max(), split + 1
    return stray / labels.size, split


def test_enforce_connectivity_hand_example():
    from jaxanom.superpixels import _enforce_connectivity

    # label 0 has pieces of 3 (left) and 1 (top right corner); label 1 one piece; label 2 a lone pixel
    # inside label 1 plus a larger piece: the corner joins label 1 (its only kept neighbour), the
    # lone 2 joins the least kept neighbour label (1); label 3 is never used and stays unused
    labels = np.array([[0, 1, 1, 0],
                       [0, 1, 2, 1],
                       [0, 1, 1, 1],
                       [2, 2, 2, 1]])
    expected = np.array([[0, 1, 1, 1],
                         [0, 1, 1, 1],
                         [0, 1, 1, 1],
                         [2, 2, 2, 1]])
    np.testing.assert_array_equal(np.asarray(_enforce_connectivity(jnp.asarray(labels), 4)), expected)


@pytest.mark.parametrize("height,width,step", [(31, 45, 6), (64, 128, 8), (17, 9, 3)])
def test_connectivity_makes_every_superpixel_connected(height, width, step):
    rng = np.random.default_rng(height)
    lab = random_lab(rng, height, width).astype(np.float32)
    plain = np.asarray(slic(lab, step, 10.0, 5))
    joined = np.asarray(slic(lab, step, 10.0, 5, connectivity=True))
    assert stray_fraction(joined) == (0.0, 0)
    assert joined.min() >= 0 and joined.max() < num_superpixels((height, width), step)
    # every superpixel's largest piece (ties: the first in raster order) keeps its label
    for j in np.unique(plain):
        pieces, _ = ndimage.label(plain == j)
        sizes = np.bincount(pieces.ravel())[1:]
        np.testing.assert_array_equal(joined[pieces == 1 + np.argmax(sizes)], j)
    assert set(np.unique(joined)) == set(np.unique(plain))


def test_connectivity_on_a_real_frame_against_scikit_image(road_anomaly_sample):
    path = sorted((road_anomaly_sample / "frames").glob("*.jpg"))[0]
    image = cv2.resize(cv2.cvtColor(cv2.imread(str(path)), cv2.COLOR_BGR2RGB), (128, 64), interpolation=cv2.INTER_AREA)
    plain = np.asarray(slic(rgb_to_lab(image), 8))
    joined = np.asarray(slic(rgb_to_lab(image), 8, connectivity=True))
    before, split = stray_fraction(plain)
    assert before > 0.05 and split > 30  # measured: 9.7% stray pixels, 71 of 128 superpixels split
    assert stray_fraction(joined) == (0.0, 0)
    theirs = skimage_slic(image, n_segments=128, compactness=10.0, max_num_iter=10, enforce_connectivity=True,
                          start_label=0)
    assert stray_fraction(theirs) == (0.0, 0)
    assert adjusted_rand_score(theirs.ravel(), joined.ravel()) >= 0.5


def test_one_channel_equals_three_with_zero_channels():
    # Algorithm 1 with a scalar feature: the two zero channels add exactly 0 to every distance
    rng = np.random.default_rng(8)
    value = (100 * ndimage.gaussian_filter(rng.random((23, 37)), 2)).astype(np.float32)
    padded = np.stack([value, np.zeros_like(value), np.zeros_like(value)], -1)
    for connectivity in (False, True):
        np.testing.assert_array_equal(np.asarray(slic(value[..., None], 5, 10.0, 4, connectivity=connectivity)),
                                      np.asarray(slic(padded, 5, 10.0, 4, connectivity=connectivity)))


@pytest.mark.parametrize("step", [4, 6])
def test_one_channel_agrees_with_scikit_image(step):
    # an anomaly-like map in [0, 100] (as the pipeline scales A); RGB frames reach ARI ~0.66,
    # a smooth one-channel map 0.45-0.57 at steps 4-8 (grid offsets and distance scaling differ)
    rng = np.random.default_rng(step)
    value = ndimage.gaussian_filter(rng.random((48, 80)), 4)
    value = (100 * (value - value.min()) / (value.max() - value.min())).astype(np.float32)
    ours = np.asarray(slic(value[..., None], step))
    theirs = skimage_slic(value, n_segments=num_superpixels(value.shape, step), compactness=10.0, max_num_iter=10,
                          enforce_connectivity=False, start_label=0, channel_axis=None, convert2lab=False)
    assert adjusted_rand_score(theirs.ravel(), ours.ravel()) >= 0.45


@pytest.mark.parametrize("shape,step", [((256, 512), 8), ((64, 128), 2), ((128, 256), 4), ((1080, 1920), 32),
                                        ((1024, 2048), 32), ((8, 8), 1), ((3, 100000), 3)])
def test_scaled_step(shape, step):
    from jaxanom.superpixels import scaled_step

    assert scaled_step(shape) == step
    if min(shape) >= 64:  # K stays near 2048 at every resolution
        assert 1800 <= num_superpixels(shape, step) <= 2200
