import cv2
import matplotlib
import numpy as np
import pytest

from jaxanom import viz
from jaxanom.io import write_json_atomic, write_png_atomic


def test_heatmap_ends_of_the_range_take_the_colormap_ends():
    score = np.array([[0.0, 5.0], [10.0, np.nan]])
    rgb = viz.heatmap(score, cmap="viridis")
    table = matplotlib.colormaps["viridis"]
    assert rgb.dtype == np.uint8 and rgb.shape == (2, 2, 3)
    np.testing.assert_array_equal(rgb[0, 0], np.array(table(0.0, bytes=True)[:3]))
    np.testing.assert_array_equal(rgb[1, 0], np.array(table(1.0, bytes=True)[:3]))
    np.testing.assert_array_equal(rgb[1, 1], rgb[0, 0])  # NaN drawn as the low end


def test_heatmap_constant_map_and_explicit_range():
    rgb = viz.heatmap(np.full((3, 4), 7.0))
    assert (rgb == rgb[0, 0]).all()
    clipped = viz.heatmap(np.array([[-5.0, 0.5, 5.0]]), vmin=0.0, vmax=1.0)
    table = matplotlib.colormaps["inferno"]
    np.testing.assert_array_equal(clipped[0, 0], np.array(table(0.0, bytes=True)[:3]))
    np.testing.assert_array_equal(clipped[0, 2], np.array(table(1.0, bytes=True)[:3]))


def test_overlay_is_the_alpha_blend_and_respects_the_mask():
    rng = np.random.default_rng(0)
    image = rng.integers(0, 256, (5, 7, 3), dtype=np.uint8)
    colours = rng.integers(0, 256, (5, 7, 3), dtype=np.uint8)
    mask = rng.random((5, 7)) < 0.5
    out = viz.overlay(image, colours, alpha=0.25, mask=mask)
    expected = np.rint(0.75 * image + 0.25 * colours.astype(float)).astype(np.uint8)
    np.testing.assert_array_equal(out[mask], expected[mask])
    np.testing.assert_array_equal(out[~mask], image[~mask])
    with pytest.raises(ValueError, match="alpha"):
        viz.overlay(image, colours, alpha=1.5)
    with pytest.raises(ValueError, match="image/colours"):
        viz.overlay(image, colours[:4])


def test_colorize_uses_the_palette_and_void_colour():
    palette = [(10, 20, 30), (40, 50, 60)]
    out = viz.colorize(np.array([[0, 1, 255]]), palette, void_colour=(1, 2, 3))
    np.testing.assert_array_equal(out[0], [[10, 20, 30], [40, 50, 60], [1, 2, 3]])


def test_png_round_trip_and_curves(tmp_path):
    rgb = np.random.default_rng(1).integers(0, 256, (6, 9, 3), dtype=np.uint8)
    write_png_atomic(tmp_path / "a.png", rgb)
    back = cv2.imread(str(tmp_path / "a.png"), cv2.IMREAD_COLOR)[..., ::-1]
    np.testing.assert_array_equal(back, rgb)
    viz.plot_curves(tmp_path / "roc.png", {"m": ([0, 0.5, 1], [0, 0.9, 1])}, kind="roc")
    assert cv2.imread(str(tmp_path / "roc.png")) is not None
    with pytest.raises(ValueError, match="kind"):
        viz.plot_curves(tmp_path / "x.png", {}, kind="det")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.png", "roc.png"]  # no temp files left


def test_json_is_atomic_and_readable(tmp_path):
    import json

    write_json_atomic(tmp_path / "r.json", {"ap": 0.5})
    assert json.loads((tmp_path / "r.json").read_text()) == {"ap": 0.5}
    with pytest.raises(ValueError, match="rgb"):
        write_png_atomic(tmp_path / "bad.png", np.zeros((2, 2), np.float32))


def test_score_figure_is_a_readable_picture():
    image = np.zeros((36, 64, 3), np.uint8)  # black: the overlay shows alpha * heat-map colours
    score = np.linspace(-3.0, 5.0, 36 * 64).reshape(36, 64)
    picture = viz.score_figure(image, score, title="frame: msp", width=800, alpha=0.6)
    assert picture.dtype == np.uint8 and picture.shape[1] == 800 and picture.shape[2] == 3
    assert picture.shape[0] > 36 * 800 / 64 / 2.3  # two panels of the image's aspect ratio, titles above
    top = np.array(matplotlib.colormaps["inferno"](1.0, bytes=True)[:3], int)
    pixels = picture.reshape(-1, 3).astype(int)
    nearest = lambda colour: np.abs(pixels - colour).max(axis=1).min()  # noqa: E731
    assert nearest(np.rint(0.6 * top)) <= 3  # the score's maximum over the (black) image
    assert nearest(top) <= 12  # the top of the colour bar
    with pytest.raises(ValueError, match="image, score"):
        viz.score_figure(image, score[:, :10], title="x")
