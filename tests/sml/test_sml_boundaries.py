"""find_boundaries / boundary_distance against scipy.ndimage with explicit padding."""
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import ndimage

import sml_reference as ref
from jaxanom import sml


def label_maps():
    rng = np.random.default_rng(0)
    yield "random-odd", rng.integers(0, 5, (13, 17))
    yield "blocks", np.kron(rng.integers(0, 19, (4, 5)), np.ones((5, 3), int))[:19, :14]
    stripes = np.zeros((9, 12), int)
    stripes[:, 3] = 7  # a 1-pixel-wide region
    stripes[4, :] = 2
    yield "one-pixel-wide", stripes
    yield "single-class-0", np.zeros((6, 7), int)
    yield "single-class-5", np.full((6, 7), 5)
    yield "checkerboard", (np.indices((8, 9)).sum(0) % 2) * 3  # every pixel a boundary
    yield "one-row", rng.integers(0, 3, (1, 10))
    yield "one-pixel", np.array([[4]])


MAPS = list(label_maps())


@pytest.mark.parametrize("border", sml.BORDERS)
@pytest.mark.parametrize("name,label", MAPS, ids=[m[0] for m in MAPS])
def test_find_boundaries_matches_scipy(name, label, border):
    got = np.asarray(sml.find_boundaries(jnp.asarray(label, jnp.int32), border=border))
    np.testing.assert_array_equal(got, ref.boundaries(label, border))


def test_single_class_edges_depend_on_border():
    label = np.full((5, 6), 3)
    assert not np.asarray(sml.find_boundaries(label)).any()
    official = np.asarray(sml.find_boundaries(label, border="sml_official"))
    edge = np.ones_like(official)
    edge[1:-1, 1:-1] = False
    np.testing.assert_array_equal(official, edge)  # classes >= 2 light up the image edge


def test_checkerboard_is_all_boundary():
    label = np.indices((7, 8)).sum(0) % 2
    assert np.asarray(sml.find_boundaries(label)).all()


@pytest.mark.parametrize("max_radius", [0, 3, 5])
@pytest.mark.parametrize("name,label", [MAPS[0], MAPS[2]], ids=[MAPS[0][0], MAPS[2][0]])
def test_boundary_distance_thresholds_are_diamond_dilations(name, label, max_radius):
    b = ref.boundaries(label, "geodesic")
    dist = np.asarray(sml.boundary_distance(jnp.asarray(b), max_radius))
    for r in range(max_radius + 1):
        np.testing.assert_array_equal(dist <= r, ref.expand(b, r))
    exact = ndimage.distance_transform_cdt(~b, metric="taxicab")
    np.testing.assert_array_equal(dist, np.minimum(exact, max_radius + 1))


def test_boundary_distance_without_boundaries_is_far():
    dist = np.asarray(sml.boundary_distance(jnp.zeros((4, 5), bool), 3))
    np.testing.assert_array_equal(dist, 4)


@pytest.mark.parametrize(
    "prediction,border,match",
    [
        (np.zeros((3, 4, 1), int), "geodesic", "prediction must have rank 2"),
        (np.zeros((3, 4), np.float32), "geodesic", "prediction must hold integer"),
        (np.zeros((3, 4), int), "inner", "border must be one of"),
    ],
)
def test_find_boundaries_rejects_bad_input(prediction, border, match):
    with pytest.raises(ValueError, match=match):
        sml.find_boundaries(prediction, border=border)
