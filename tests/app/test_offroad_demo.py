"""``jaxanom demo offroad``: the quick path end to end, the config file, one-line errors."""
import dataclasses
import json

import pytest

from jaxanom.cli import main
from jaxanom.app.configs import encode, load_config
from jaxanom.app.demos.offroad import OffroadDemoConfig
from jaxanom.data.image_io import read_rgb


@pytest.fixture(scope="module")
def demo_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("offroad_demo")
    assert main(["demo", "offroad", "--quick", "--out", str(out), "--overwrite", "--no-progress"]) == 0
    return out


def test_quick_offroad_demo_writes_results_pictures_and_hard_frames(demo_dir):
    results = json.loads((demo_dir / "results.json").read_text())
    assert results["clusters_bic"] in (2, 3)
    assert len(results["active_sequence"]["hard_frames"]) == 2
    for tag in ("test_before", "test_after"):
        for name in ("votes", "crf"):
            assert 0 <= results[tag][name]["pixel_accuracy"] <= 1
        assert 0 <= results[tag]["mflr"] <= 1 and 0 <= results[tag]["coverage"] <= 1
    for name in ("frame_0_before.png", "frame_0_after.png"):  # 2 rows of 3 panels, 48 x 64 frames x 4
        picture = read_rgb(demo_dir / name)
        assert picture.shape[1] >= 3 * 256 and picture.shape[0] >= 2 * 192, (name, picture.shape)
    assert read_rgb(demo_dir / "hard_frames.png").shape[1] >= 2 * 256  # the two chosen frames side by side
    assert load_config(demo_dir / "results.json", OffroadDemoConfig) == OffroadDemoConfig.quick()  # a config file


def test_a_config_file_round_trips_to_the_same_config(tmp_path):
    quick = OffroadDemoConfig.quick()
    path = tmp_path / "offroad.json"
    path.write_text(json.dumps(encode(quick)))
    assert load_config(path, OffroadDemoConfig) == quick
    path.write_text(json.dumps({"test": {"domain": "E", "sequence": 1, "frames": 9}, "pipeline": {"budget": 3}}))
    loaded = load_config(path, OffroadDemoConfig)
    assert loaded.test.domain == "E" and loaded.pipeline.budget == 3 and loaded.train == OffroadDemoConfig().train


def test_bad_config_and_arguments_are_one_line_errors(tmp_path, capsys):
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"frames_per_second": 3}))
    assert main(["demo", "offroad", "--config", str(bad), "--out", str(tmp_path / "o1")]) == 2
    assert "unknown field" in capsys.readouterr().err
    assert main(["demo", "offroad", "--config", str(tmp_path / "missing.json"), "--out", str(tmp_path / "o2")]) == 2
    assert "no such file" in capsys.readouterr().err
    assert main(["demo", "offroad", "--config", str(bad), "--quick", "--out", str(tmp_path / "o3")]) == 2
    assert "give one of them" in capsys.readouterr().err


def test_an_unknown_nested_field_is_a_value_error(tmp_path):
    path = tmp_path / "nested.json"
    path.write_text(json.dumps({"pipeline": {"encoder": {"depth": 3}}}))
    with pytest.raises(ValueError, match="pipeline.encoder.depth: unknown field of EncoderConfig"):
        load_config(path, OffroadDemoConfig)


def test_a_deepscene_source_gives_resized_frames_and_five_classes(tmp_path):
    import cv2
    import numpy as np

    from jaxanom.app.offroad_experiment import Source, num_classes, source_frames

    for i in range(3):
        for folder, name, value in (("rgb", f"b{i}-1_Clipped.jpg", (90, 90, 90)), ("GT_color", f"b{i}-1_mask.png", (0, 255, 0))):
            (tmp_path / "train" / folder).mkdir(parents=True, exist_ok=True)
            cv2.imwrite(str(tmp_path / "train" / folder / name), np.full((40, 60, 3), value[::-1], np.uint8))
    source = Source(reader="deepscene", root=str(tmp_path), name="train", frames=2, start=1)
    config = dataclasses.replace(OffroadDemoConfig.quick(), train=(source,))
    frames = source_frames(source, config)
    assert len(frames) == 2 and num_classes(config) == 5
    assert frames[0]["image"].shape == (48, 64, 3) and frames[0]["label"].shape == (48, 64)
    assert (frames[0]["label"] == 1).all()  # grass
    with pytest.raises(ValueError, match="reader"):
        Source(reader="kitti")
