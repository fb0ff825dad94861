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


def test_a_score_panel_over_a_base_image_is_its_alpha_blend_with_a_colour_bar():
    image = np.zeros((36, 64, 3), np.uint8)  # black: the overlay shows alpha * heat-map colours
    score = np.linspace(-3.0, 5.0, 36 * 64).reshape(36, 64)
    picture = viz.render_panels([viz.Panel("frame", image), viz.Panel("msp", score, base=image, alpha=0.6)],
                                columns=2, min_width=256)
    assert picture.dtype == np.uint8 and picture.shape[1] > 2 * 256
    top = np.array(matplotlib.colormaps["inferno"](1.0, bytes=True)[:3], int)
    pixels = picture.reshape(-1, 3).astype(int)
    nearest = lambda colour: np.abs(pixels - colour).max(axis=1).min()  # noqa: E731
    assert nearest(np.rint(0.6 * top)) <= 1  # the score's maximum over the (black) image
    assert nearest(top) <= 20  # the top of the colour bar (drawn in 256 steps)
    with pytest.raises(ValueError, match="base"):
        viz.render_panels([viz.Panel("msp", score, base=image[:, :10])])


def _pixel_box(axes, rendered):
    """(top, bottom, left, right) rows / columns of ``axes`` in the rendered RGB array."""
    box = axes.get_window_extent()
    height = rendered.shape[0]
    return (int(round(height - box.y1)), int(round(height - box.y0)), int(round(box.x0)), int(round(box.x1)))


def _draw(figure):
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    canvas = FigureCanvasAgg(figure)
    canvas.draw()
    return np.asarray(canvas.buffer_rgba())[..., :3].copy()


def test_small_frames_are_repeated_pixel_for_pixel_under_a_drawn_title():
    rng = np.random.default_rng(2)
    frame = rng.integers(0, 256, (12, 20, 3), dtype=np.uint8)
    figure = viz.panel_figure([viz.Panel("a known title", frame)], min_width=256)
    rendered = _draw(figure)
    (axes,) = figure.axes
    assert axes.get_title() == "a known title"
    top, bottom, left, right = _pixel_box(axes, rendered)
    factor = -(-256 // 20)  # the smallest integer factor reaching 256 px: 13
    assert (bottom - top, right - left) == (12 * factor, 20 * factor)
    assert rendered.shape[1] >= 20 * factor and rendered.shape[0] >= 12 * factor
    rows, cols = np.arange(top + 2, bottom - 2), np.arange(left + 2, right - 2)  # inside the frame line
    expected = frame[(rows - top) // factor][:, (cols - left) // factor]  # nearest neighbour, from its definition
    np.testing.assert_array_equal(rendered[rows][:, cols], expected)
    band = rendered[:top - 1, left:right]  # between the figure's top and the picture: the title
    assert (band < 200).any(axis=-1).sum() > 50
    blank = _draw(viz.panel_figure([viz.Panel("", frame)], min_width=256))
    assert blank.shape == rendered.shape and (blank[:top - 1, left:right] == 255).all()


def test_score_maps_get_a_colour_bar_over_their_range_and_the_colour_map():
    score = np.array([[0.0, 2.0, np.nan], [4.0, 8.0, 8.0]])
    figure = viz.panel_figure([viz.Panel("score", score, cmap="viridis", label="anomaly score")], min_width=30)
    rendered = _draw(figure)
    picture, bar = figure.axes
    assert bar.get_ylim() == pytest.approx((0.0, 8.0)) and bar.get_ylabel() == "anomaly score"
    top, bottom, left, right = _pixel_box(picture, rendered)
    factor = (bottom - top) // 2
    assert factor == 10 and right - left == 30  # ceil(30 / 3) = 10
    table = matplotlib.colormaps["viridis"]
    for (r, c), value in np.ndenumerate(score):
        want = table(0.0 if np.isnan(value) else value / 8.0, bytes=True)[:3]
        np.testing.assert_array_equal(rendered[top + r * factor + factor // 2, left + c * factor + factor // 2], want)
    fixed = viz.panel_figure([viz.Panel("score", score, vmin=-1.0, vmax=3.0)], min_width=30)
    assert fixed.axes[1].get_ylim() == pytest.approx((-1.0, 3.0))


def test_label_panels_list_the_classes_they_show_and_void():
    labels = np.array([[2, 2, 0], [255, 2, 0]])
    panel = viz.label_panel("labels", labels, ["a", "b", "c"], [(1, 2, 3), (4, 5, 6), (7, 8, 9)], void=("none", (9, 9, 9)))
    assert panel.legend == (("a", (1, 2, 3)), ("c", (7, 8, 9)), ("none", (9, 9, 9)))
    np.testing.assert_array_equal(panel.image[1], [[9, 9, 9], [7, 8, 9], [1, 2, 3]])
    figure = viz.panel_figure([panel, viz.anomaly_label_panel(np.array([[0, 1]]))], min_width=64)
    legends = [[t.get_text() for t in legend.get_texts()] for legend in figure.legends]
    assert legends == [["a", "c", "none"], ["in-distribution", "anomaly"]]
    with pytest.raises(ValueError, match="names, palette"):
        viz.label_panel("labels", labels, ["a"], [(1, 2, 3), (4, 5, 6)])


def test_rows_of_columns_large_frames_shrink_and_bad_panels_are_value_errors(tmp_path):
    frames = [viz.Panel(f"p{i}", np.full((10, 40, 3), 10 * i, np.uint8)) for i in range(5)]
    figure = viz.panel_figure(frames, columns=2, min_width=160)
    rows = sorted({round(a.get_position().y0, 6) for a in figure.axes})
    cols = sorted({round(a.get_position().x0, 6) for a in figure.axes})
    assert len(rows) == 3 and len(cols) == 2
    assert [a.get_title() for a in figure.axes] == [f"p{i}" for i in range(5)]
    big = viz.panel_figure([viz.Panel("big", np.zeros((300, 2000, 3), np.uint8))], max_width=1000)
    rendered = _draw(big)
    top, bottom, left, right = _pixel_box(big.axes[0], rendered)
    assert (bottom - top, right - left) == (150, 1000)
    viz.write_panels(tmp_path / "p.png", frames[:1])
    assert cv2.imread(str(tmp_path / "p.png")).shape[1] >= 256
    with pytest.raises(ValueError, match="panel 'x'"):
        viz.panel_figure([viz.Panel("x", np.zeros((4, 4, 3), np.float32))])
    with pytest.raises(ValueError, match="panels"):
        viz.panel_figure([])
    with pytest.raises(ValueError, match="columns"):
        viz.panel_figure(frames, columns=0)
