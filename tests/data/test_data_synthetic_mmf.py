"""Synthetic scenes' MMF options: disparity, void clutter, road ROI; off by default."""
import numpy as np
import pytest

from jaxanom.data.synthetic import BASELINE, SyntheticScenes, generate

H, W = 48, 96
SKY, ROAD = 10, 0


@pytest.mark.parametrize("split", ["train", "anomaly"])
def test_options_off_leave_every_output_byte_identical(split):
    plain = generate(split, 2, seed=3, height=H, width=W)
    explicit = generate(split, 2, seed=3, height=H, width=W, disparity=False, disparity_noise=(0.0, 0.0),
                        void_objects=0, roi=False)
    assert set(plain) == set(explicit) == {"image", "label", "semantic", "depth", "name"}
    for key in ("image", "label", "semantic", "depth"):
        assert plain[key].tobytes() == explicit[key].tobytes()


def test_disparity_times_depth_is_focal_times_baseline_and_zero_on_sky():
    frame = generate("train", 1, height=H, width=W, disparity=True)
    disparity, depth, camera = frame["disparity"], frame["depth"], frame["camera"]
    assert disparity.dtype == np.float32 and disparity.shape == (H, W)
    sky = frame["semantic"] == SKY
    assert sky.any() and np.all(disparity[sky] == 0)
    np.testing.assert_allclose(disparity[~sky] * depth[~sky], camera["fx"] * BASELINE, rtol=1e-5)
    assert camera["baseline"] == BASELINE and 0 < camera["u0"] < W and 0 < camera["v0"] < H
    # the image and labels are those of the plain frame
    plain = generate("train", 1, height=H, width=W)
    assert plain["image"].tobytes() == frame["image"].tobytes()


def test_disparity_noise_is_deterministic_and_makes_holes_of_about_the_asked_fraction():
    a = generate("val", 0, height=96, width=192, disparity=True, disparity_noise=(0.05, 0.2))
    b = generate("val", 0, height=96, width=192, disparity=True, disparity_noise=(0.05, 0.2))
    clean = generate("val", 0, height=96, width=192, disparity=True)["disparity"]
    assert a["disparity"].tobytes() == b["disparity"].tobytes()
    holes = (a["disparity"] == 0) & (clean > 0)
    assert 0.15 < holes.sum() / (clean > 0).sum() < 0.25
    kept = (a["disparity"] > 0) & (clean > 0)
    ratio = a["disparity"][kept] / clean[kept]
    assert 0.03 < ratio.std() < 0.07 and abs(ratio.mean() - 1) < 0.01


def test_void_objects_are_void_in_the_labels_and_only_where_enabled():
    found = 0
    for index in range(8):
        plain = generate("train", index, height=H, width=W)
        frame = generate("train", index, height=H, width=W, void_objects=3)
        void = frame["void"]
        assert void.dtype == bool and np.all(frame["label"][void] == 255) and np.all(frame["semantic"][void] == 255)
        # outside the clutter the labels are the plain frame's, and the plain frame has no void
        np.testing.assert_array_equal(frame["label"][~void], plain["label"][~void])
        assert not np.any(plain["label"] == 255)
        found += void.sum()
    assert found > 0
    anomaly = generate("anomaly", 0, height=H, width=W, void_objects=3)
    assert not anomaly["void"].any()  # clutter only in training-like splits


def test_roi_is_the_road_with_what_stands_on_it():
    frame = generate("anomaly", 4, height=H, width=W, roi=True, off_road_void=True, void_band=0)
    roi = frame["roi"]
    # off_road_void (no band) voids exactly the pixels that are neither road nor anomaly
    np.testing.assert_array_equal(~roi, frame["label"] == 255)
    assert (frame["semantic"][roi] == ROAD).any() and (frame["label"][roi] == 1).any()


def test_scenes_pass_the_options_and_reject_bad_ones():
    scenes = SyntheticScenes("train", 2, height=H, width=W, disparity=True, void_objects=2, roi=True)
    assert {"disparity", "camera", "void", "roi"} <= set(scenes[1])
    assert "disparity" not in repr(SyntheticScenes("train", 2, height=H, width=W))
    with pytest.raises(ValueError, match="void_objects"):
        generate("train", 0, height=H, width=W, void_objects=-1)
    with pytest.raises(ValueError, match="disparity_noise"):
        SyntheticScenes("train", 2, disparity=True, disparity_noise=(0.1, 1.5))
